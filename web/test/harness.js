// Browser side of the render test (driven by render.mjs through playwright):
// renders a scene with the reference renderer and returns read-backs the Rust
// test compares with svpack's CPU predictions.

import { load } from '../svpack.js';
import { ShadowRenderer, fetchShaderSources, perspectiveInfinite, lookAt, multiply, recordLight } from '../renderer.js';

let sources = null;

function toBase64(bytes) {
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

// Probe: computes, per record, what the reference shaders compute (m for
// sides, c for caps) with the reference common.glsl and the same svTriSign
// calls in the same slot order as sides.vert / caps.vert, and writes it as a
// colour, (v + 128) / 255, into one pixel per record (index from a divisor-1
// attribute). 256 columns: a power of two keeps mod() and floor() exact.
const PROBE_WIDTH = 256;
const PROBE_FS = 'precision mediump float;\nvarying float vValue;\nvoid main() { gl_FragColor = vec4(vValue, 0.0, 0.0, 1.0); }\n';

function probeSource(src, k) {
  const attrs = k === 0 ? ['aP0', 'aP1', 'aP2'] : ['aA', 'aB', ...Array.from({ length: k }, (_, j) => `aO${j}`)];
  let body;
  if (k === 0) {
    body = '  float v = svTriSign(aP0.xyz, aP1.xyz, aP2.xyz, uLight);\n';
  } else {
    body = '  vec3 a = aA.xyz;\n  vec3 b = aB.xyz;\n  float v = svTriSign(a, b, aO0.xyz, uLight);\n';
    for (let j = 1; j < k; j++) body += `  v += svTriSign(a, b, aO${j}.xyz, uLight);\n`;
  }
  const vs = `${k ? `#define SVPK_K ${k}\n` : ''}precision highp float;\n${src.common}
attribute float aVertexId;
attribute float aIndex;
${attrs.map((a) => `attribute vec4 ${a};`).join('\n')}
uniform vec4 uLight;
uniform vec2 uGrid;
varying float vValue;
void main() {
${body}  vValue = (v + 128.0) / 255.0;
  float col = mod(aIndex, uGrid.x);
  float row = floor(aIndex / uGrid.x);
  // min(aVertexId, 0.0) is 0 but keeps the divisor-0 attribute active, which
  // drawArraysInstancedANGLE requires.
  gl_Position = vec4((col + 0.5) / uGrid.x * 2.0 - 1.0, (row + 0.5) / uGrid.y * 2.0 - 1.0, min(aVertexId, 0.0), 1.0);
  gl_PointSize = 1.0;
}
`;
  return { vs, attribs: ['aVertexId', 'aIndex', ...attrs] };
}

function compileProbe(gl, src, k) {
  const { vs, attribs } = probeSource(src, k);
  const p = gl.createProgram();
  for (const [type, text] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, PROBE_FS]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, text);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`probe k=${k}: ${gl.getShaderInfoLog(s)}`);
    gl.attachShader(p, s);
  }
  attribs.forEach((a, i) => gl.bindAttribLocation(p, i, a));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`probe k=${k}: ${gl.getProgramInfoLog(p)}`);
  return { p, uLight: gl.getUniformLocation(p, 'uLight'), uGrid: gl.getUniformLocation(p, 'uGrid') };
}

/** Per mesh: caps c values, then each bucket's m values, as one Int8Array. */
function probeMultiplicities(r, file, light) {
  const gl = r.gl;
  const v4 = r.vec4Bytes;
  const total = file.meshes.reduce((n, m) => n + m.caps.count + m.buckets.reduce((a, b) => a + b.instances, 0), 0);
  const out = new Int8Array(total);
  const maxRecords = Math.max(1, ...file.meshes.flatMap((m) => [m.caps.count, ...m.buckets.map((b) => b.instances)]));
  const rows = Math.ceil(maxRecords / PROBE_WIDTH);
  const tex = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA, PROBE_WIDTH, rows, 0, gl.RGBA, gl.UNSIGNED_BYTE, null);
  const fb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
  if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error('probe framebuffer incomplete');
  gl.viewport(0, 0, PROBE_WIDTH, rows);
  gl.disable(gl.DEPTH_TEST);
  gl.disable(gl.STENCIL_TEST);
  gl.disable(gl.BLEND);
  const index = r.buffer(new Float32Array(Array.from({ length: maxRecords }, (_, i) => i)));
  const pixels = new Uint8Array(PROBE_WIDTH * rows * 4);
  let at = 0;
  const run = (k, buffer, count, l) => {
    const prog = compileProbe(gl, r.sources, k);
    gl.useProgram(prog.p);
    gl.uniform4fv(prog.uLight, l);
    gl.uniform2f(prog.uGrid, PROBE_WIDTH, rows);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    r.attrib(0, r.vertexIds, 1, gl.FLOAT, false, 0, 0, 0);
    r.attrib(1, index, 1, gl.FLOAT, false, 0, 0, 1);
    const slots = k === 0 ? 3 : 2 + k;
    for (let i = 0; i < slots; i++) r.recordAttrib(2 + i, buffer, slots * v4, i * v4, 1);
    r.ext.drawArraysInstancedANGLE(gl.POINTS, 0, 1, count);
    r.releaseAttribs();
    gl.readPixels(0, 0, PROBE_WIDTH, rows, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
    for (let i = 0; i < count; i++) {
      // Alpha 0 means the point was never drawn: report an impossible value.
      out[at++] = pixels[4 * i + 3] === 255 ? pixels[4 * i] - 128 : -128;
    }
  };
  file.meshes.forEach((m, mi) => {
    const l = recordLight(m, light);
    run(0, r.meshes[mi].caps, m.caps.count, l);
    m.buckets.forEach((b, bi) => run(b.k, r.meshes[mi].buckets[bi].buffer, b.instances, l));
  });
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.deleteFramebuffer(fb);
  gl.deleteTexture(tex);
  gl.deleteBuffer(index);
  return out;
}

// Colour picture of the stencil read-back (for humans; the test uses the raw bytes).
function maskPng(rgba, w, h) {
  const c = document.createElement('canvas');
  c.width = w;
  c.height = h;
  const ctx = c.getContext('2d');
  const img = ctx.createImageData(w, h);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const s = 4 * ((h - 1 - y) * w + x); // readPixels rows are bottom-up
      const d = 4 * (y * w + x);
      const kind = rgba[s];
      const shadow = rgba[s + 1] !== 0;
      const col = kind === 255 ? (shadow ? [110, 60, 30] : [240, 160, 90])
        : kind === 128 ? (shadow ? [70, 70, 80] : [210, 210, 215]) : [0, 0, 0];
      img.data.set([...col, 255], d);
    }
  }
  ctx.putImageData(img, 0, 0);
  return c.toDataURL('image/png');
}

export const harness = {
  /**
   * scene = { name, url, width, height, eye, target, up, fovy, near, light, ground }
   * Returns { info, rgba (base64, bottom-up rows), mult (base64 Int8), png, maskPng }.
   */
  async run(scene) {
    if (!sources) sources = await fetchShaderSources();
    const res = await fetch(scene.url);
    if (!res.ok) throw new Error(`cannot fetch ${scene.url}: HTTP ${res.status}`);
    const file = load(await res.arrayBuffer());
    const canvas = document.createElement('canvas');
    canvas.width = scene.width;
    canvas.height = scene.height;
    // No antialiasing: every pixel must be one sample at its centre, as the
    // CPU prediction assumes.
    const gl = canvas.getContext('webgl', { stencil: true, depth: true, antialias: false, alpha: false, preserveDrawingBuffer: true });
    if (!gl) throw new Error('WebGL 1 is not available');
    const r = new ShadowRenderer(gl, sources);
    r.setFile(file);
    if (scene.ground) r.setGround(scene.ground);
    const proj = perspectiveInfinite(scene.fovy, scene.width / scene.height, scene.near);
    const view = { viewProj: multiply(proj, lookAt(scene.eye, scene.target, scene.up)), eye: scene.eye, light: scene.light };

    r.render(view);
    const png = canvas.toDataURL('image/png');
    r.renderStencilImage(view);
    const rgba = new Uint8Array(scene.width * scene.height * 4);
    gl.readPixels(0, 0, scene.width, scene.height, gl.RGBA, gl.UNSIGNED_BYTE, rgba);
    const mult = probeMultiplicities(r, file, scene.light);
    const info = {
      version: `${file.versionMajor}.${file.versionMinor}`,
      encoding: file.encoding.name,
      renderer: gl.getParameter(gl.RENDERER),
      maxVertexAttribs: r.maxAttribs,
      stencilBits: r.stencilBits,
      glError: gl.getError(),
    };
    const out = { info, rgba: toBase64(rgba), mult: toBase64(new Uint8Array(mult.buffer)), png, maskPng: maskPng(rgba, scene.width, scene.height) };
    gl.getExtension('WEBGL_lose_context')?.loseContext();
    return out;
  },
};
