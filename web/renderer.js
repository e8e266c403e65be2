// svpack WebGL 1 reference renderer: silhouette shadow volumes drawn with
// z-fail two-sided stencil (format-spec/README.md §4.3 and §6), using the
// normative shaders of format-spec/shaders/ verbatim.
//
// Plain ES module, no dependencies. Needs WebGL 1 with ANGLE_instanced_arrays
// and a stencil buffer (create the context with { stencil: true }).

// ---------------------------------------------------------------- shaders

/**
 * Fetches the reference shader sources (common.glsl, sides.vert, caps.vert).
 * The renderer compiles exactly these texts, so it cannot drift from the
 * spec; `base` defaults to format-spec/shaders/ next to web/.
 */
export async function fetchShaderSources(base = new URL('../format-spec/shaders/', import.meta.url)) {
  const get = async (name) => {
    const url = new URL(name, base);
    const res = await fetch(url);
    if (!res.ok) throw new Error(`cannot fetch reference shader ${url}: HTTP ${res.status}`);
    return res.text();
  };
  const [common, sides, caps] = await Promise.all([get('common.glsl'), get('sides.vert'), get('caps.vert')]);
  return { common, sides, caps };
}

/** The spec's program texts (§6 "Reference shaders"). */
export function sidesSource(src, k) {
  return `#define SVPK_K ${k}\nprecision highp float;\n${src.common}${src.sides}`;
}
export function capsSource(src) {
  return `precision highp float;\n${src.common}${src.caps}`;
}

// The stencil passes write no colour: "the fragment shader is free".
const STENCIL_FS = 'precision mediump float;\nvoid main() { gl_FragColor = vec4(0.0); }\n';

// Scene (model and ground). The ambient and the lit pass use this same
// program with the same inputs so that depthFunc(EQUAL) in the lit pass
// matches the depth written by the first pass bit for bit.
const SCENE_VS = `precision highp float;
attribute vec4 aPos;
attribute vec3 aNormal;
uniform mat4 uViewProj;   // record space -> clip (model transform folded in)
uniform mat4 uModel;      // record space -> world
varying vec3 vWorld;
varying vec3 vNormal;
void main() {
  vec4 p = vec4(aPos.xyz, 1.0);
  vWorld = (uModel * p).xyz;
  vNormal = aNormal;
  gl_Position = uViewProj * p;
}
`;
const SCENE_FS = `precision highp float;
varying vec3 vWorld;
varying vec3 vNormal;
uniform vec3 uAlbedo;
uniform vec4 uLightWorld;  // w = 1 point, w = 0 directional
uniform vec3 uEye;
uniform float uMode;       // 0 flat colour (uAlbedo), 1 ambient, 2 direct light
void main() {
  if (uMode < 0.5) { gl_FragColor = vec4(uAlbedo, 1.0); return; }
  if (uMode < 1.5) { gl_FragColor = vec4(0.25 * uAlbedo, 1.0); return; }
  // Two-sided: files may be open or inconsistently wound, so light the side
  // the camera sees.
  vec3 n = normalize(vNormal);
  if (dot(n, uEye - vWorld) < 0.0) n = -n;
  vec3 l = normalize(uLightWorld.xyz - vWorld * uLightWorld.w);
  gl_FragColor = vec4(0.75 * max(dot(n, l), 0.0) * uAlbedo, 1.0);
}
`;

// Full-screen pass used to turn stencil values into colours (tests, debug).
const QUAD_VS = 'attribute vec2 aCorner;\nvoid main() { gl_Position = vec4(aCorner, 0.0, 1.0); }\n';
const QUAD_FS = 'precision mediump float;\nuniform vec4 uColor;\nvoid main() { gl_FragColor = uColor; }\n';

// ---------------------------------------------------------------- matrices
// Column-major 4x4 in plain (f64) arrays; rounded to f32 only on upload.

/** Perspective projection with the far plane at infinity (spec §6). */
export function perspectiveInfinite(fovyRadians, aspect, near) {
  const f = 1 / Math.tan(fovyRadians / 2);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, -1, -1, 0, 0, -2 * near, 0];
}

/** View matrix looking from `eye` at `target`. */
export function lookAt(eye, target, up) {
  const z = normalize(sub(eye, target));
  const x = normalize(cross(up, z));
  const y = cross(z, x);
  return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
    -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
}

export function multiply(a, b) {
  const o = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      let s = 0;
      for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
      o[c * 4 + r] = s;
    }
  }
  return o;
}

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const normalize = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

// ---------------------------------------------------------------- GL helpers

function compile(gl, type, source, label) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
    throw new Error(`${label}: shader compile failed: ${gl.getShaderInfoLog(s)}`);
  }
  return s;
}

/**
 * Links a program. `attribs` lists attribute names in location order: the
 * first one gets location 0, which some GL backends require to be an
 * enabled, non-instanced array (aVertexId or a position).
 */
function program(gl, vs, fs, attribs, label) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vs, label));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fs, label));
  attribs.forEach((name, i) => gl.bindAttribLocation(p, i, name));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) {
    throw new Error(`${label}: program link failed: ${gl.getProgramInfoLog(p)}`);
  }
  const u = {};
  const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const info = gl.getActiveUniform(p, i);
    u[info.name] = gl.getUniformLocation(p, info.name);
  }
  return { p, u, attribs, label };
}

// ---------------------------------------------------------------- renderer

/**
 * Per-mesh record space -> world transform: world = offset + record * scale
 * per axis (format-spec §4.5; the identity for f32 files).
 */
function modelMatrix(mesh) {
  const o = mesh.positionOffset;
  const s = mesh.positionScale;
  return [s[0], 0, 0, 0, 0, s[1], 0, 0, 0, 0, s[2], 0, o[0], o[1], o[2], 1];
}

/**
 * The light in a mesh's record space, in f32, the way the CPU evaluator
 * must compute it too: a point light is moved by the inverse of the
 * mesh transform, a direction is only scaled. For f32 files (identity
 * transform) this is the world light unchanged.
 */
export function recordLight(mesh, light) {
  const o = mesh.positionOffset;
  const s = mesh.positionScale;
  const f = Math.fround;
  const L = light.map(f); // the world light is an f32 vector (multiplicity.md §1)
  if (L[3] !== 0 && L[3] !== 1) throw new Error(`light w must be exactly 1 (point) or 0 (directional), got ${L[3]}`);
  // format-spec §4.5: xyz' = (L.xyz - o * L.w) / s in f64, rounded once to f32.
  return [0, 1, 2].map((i) => f((L[i] - o[i] * L[3]) / s[i])).concat([L[3]]);
}

export class ShadowRenderer {
  /**
   * @param gl      WebGL 1 context created with { stencil: true }
   * @param sources {common, sides, caps} from fetchShaderSources()
   */
  constructor(gl, sources) {
    this.gl = gl;
    this.sources = sources;
    this.ext = gl.getExtension('ANGLE_instanced_arrays');
    if (!this.ext) throw new Error('WebGL 1 extension ANGLE_instanced_arrays is not available');
    this.stencilBits = gl.getParameter(gl.STENCIL_BITS);
    if (this.stencilBits < 8) throw new Error(`need an 8-bit stencil buffer, got ${this.stencilBits} bits (create the context with { stencil: true })`);
    this.maxAttribs = gl.getParameter(gl.MAX_VERTEX_ATTRIBS);

    this.scene = program(gl, SCENE_VS, SCENE_FS, ['aPos', 'aNormal'], 'scene');
    this.quad = program(gl, QUAD_VS, QUAD_FS, ['aCorner'], 'full-screen quad');
    this.caps = program(gl, capsSource(sources), STENCIL_FS, ['aVertexId', 'aP0', 'aP1', 'aP2'], 'caps.vert');
    this.sidesPrograms = new Map(); // k -> program, compiled on demand

    // §4.3: the per-vertex id buffer 0..5 (WebGL 1 has no gl_VertexID).
    this.vertexIds = this.buffer(new Float32Array([0, 1, 2, 3, 4, 5]));
    this.quadBuffer = this.buffer(new Float32Array([-1, -1, 1, -1, -1, 1, 1, 1]));
    this.enabled = [];
    this.meshes = [];
    this.ground = null;
  }

  buffer(data) {
    const gl = this.gl;
    const b = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, b);
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    return b;
  }

  sidesProgram(k) {
    if (!this.sidesPrograms.has(k)) {
      const attribs = ['aVertexId', 'aA', 'aB'];
      for (let j = 0; j < k; j++) attribs.push(`aO${j}`);
      this.sidesPrograms.set(k, program(this.gl, sidesSource(this.sources, k), STENCIL_FS, attribs, `sides.vert k=${k}`));
    }
    return this.sidesPrograms.get(k);
  }

  /** Uploads a file returned by svpack.load(); replaces the previous one. */
  setFile(file) {
    const gl = this.gl;
    // §4.4: the sides program of bucket k reads 3 + k attributes.
    const need = 3 + file.options.maxMult;
    if (this.maxAttribs < need) {
      throw new Error(`this file was built with max_mult ${file.options.maxMult} and needs ${need} vertex attributes; this GPU has MAX_VERTEX_ATTRIBS = ${this.maxAttribs}`);
    }
    for (const m of this.meshes) {
      gl.deleteBuffer(m.caps);
      gl.deleteBuffer(m.normals);
      m.buckets.forEach((b) => gl.deleteBuffer(b.buffer));
    }
    this.file = file;
    const vec4 = file.encoding.vec4Bytes;
    this.attribType = vec4 === 16 ? gl.FLOAT : gl.UNSIGNED_SHORT;
    this.vec4Bytes = vec4;
    this.meshes = file.meshes.map((m) => {
      for (const b of m.buckets) this.sidesProgram(b.k);
      return {
        header: m,
        model: modelMatrix(m),
        count: m.caps.count,
        // The typed-array views go to the GPU as they are: no copy in JS.
        caps: this.buffer(m.caps.data),
        normals: this.buffer(flatNormals(m, vec4)),
        buckets: m.buckets.map((b) => ({ k: b.k, instances: b.instances, buffer: this.buffer(b.data) })),
      };
    });
  }

  /**
   * Ground quad y = `y`, centred on (cx, cz), half-size `half` (world space);
   * null removes it. It receives shadows but is not part of the file, so it
   * casts none.
   */
  setGround(ground) {
    const gl = this.gl;
    if (this.ground) { gl.deleteBuffer(this.ground.pos); gl.deleteBuffer(this.ground.nrm); }
    this.ground = null;
    if (!ground) return;
    const { y, cx, cz, half } = ground;
    const p = [[cx - half, cz - half], [cx - half, cz + half], [cx + half, cz + half], [cx + half, cz - half]];
    const tri = [0, 1, 2, 0, 2, 3]; // counter-clockwise seen from above
    const pos = new Float32Array(tri.flatMap((i) => [p[i][0], y, p[i][1], 1]));
    const nrm = new Float32Array(tri.flatMap(() => [0, 1, 0]));
    this.ground = { pos: this.buffer(pos), nrm: this.buffer(nrm) };
  }

  // Attribute state without vertex array objects: enable what a draw needs,
  // disable (and reset the divisor of) everything else afterwards, so one
  // draw's instanced arrays never leak into the next.
  attrib(loc, buffer, size, type, normalized, stride, offset, divisor) {
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, size, type, normalized, stride, offset);
    this.ext.vertexAttribDivisorANGLE(loc, divisor);
    this.enabled.push(loc);
  }
  releaseAttribs() {
    for (const loc of this.enabled) {
      this.ext.vertexAttribDivisorANGLE(loc, 0);
      this.gl.disableVertexAttribArray(loc);
    }
    this.enabled = [];
  }
  // A record vec4 attribute: f32, or (format 2) normalized UNSIGNED_SHORT.
  recordAttrib(loc, buffer, stride, offset, divisor) {
    this.attrib(loc, buffer, 4, this.attribType, this.attribType !== this.gl.FLOAT, stride, offset, divisor);
  }

  /** Draws model and ground with the scene program (`mode` 0 flat, 1 ambient, 2 lit). */
  drawScene(view, mode, colors = {}) {
    const gl = this.gl;
    const s = this.scene;
    gl.useProgram(s.p);
    gl.uniform1f(s.u.uMode, mode);
    gl.uniform4fv(s.u.uLightWorld, view.light);
    gl.uniform3fv(s.u.uEye, view.eye);
    for (const m of this.meshes) {
      gl.uniformMatrix4fv(s.u.uViewProj, false, new Float32Array(multiply(view.viewProj, m.model)));
      gl.uniformMatrix4fv(s.u.uModel, false, new Float32Array(m.model));
      gl.uniform3fv(s.u.uAlbedo, colors.model || [0.85, 0.55, 0.3]);
      this.recordAttrib(0, m.caps, this.vec4Bytes, 0, 0);
      this.attrib(1, m.normals, 3, gl.FLOAT, false, 0, 0, 0);
      gl.drawArrays(gl.TRIANGLES, 0, 3 * m.count);
      this.releaseAttribs();
    }
    if (this.ground) {
      gl.uniformMatrix4fv(s.u.uViewProj, false, new Float32Array(view.viewProj));
      gl.uniformMatrix4fv(s.u.uModel, false, new Float32Array(modelMatrix({ positionOffset: [0, 0, 0], positionScale: [1, 1, 1] })));
      gl.uniform3fv(s.u.uAlbedo, colors.ground || [0.8, 0.8, 0.8]);
      this.attrib(0, this.ground.pos, 4, gl.FLOAT, false, 0, 0, 0);
      this.attrib(1, this.ground.nrm, 3, gl.FLOAT, false, 0, 0, 0);
      gl.drawArrays(gl.TRIANGLES, 0, 6);
      this.releaseAttribs();
    }
  }

  /**
   * §6 step 2: stencil := number of triangles between each visible point and
   * the light (mod 256). Depth must already hold the scene.
   */
  stencilPass(view) {
    const gl = this.gl;
    const ext = this.ext;
    gl.clearStencil(0);
    gl.clear(gl.STENCIL_BUFFER_BIT);
    gl.depthMask(false);
    gl.colorMask(false, false, false, false);
    gl.disable(gl.CULL_FACE);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
    gl.enable(gl.STENCIL_TEST);
    gl.stencilFunc(gl.ALWAYS, 0, 0xff);
    gl.stencilOpSeparate(gl.BACK, gl.KEEP, gl.INCR_WRAP, gl.KEEP);
    gl.stencilOpSeparate(gl.FRONT, gl.KEEP, gl.DECR_WRAP, gl.KEEP);
    gl.frontFace(gl.CCW);
    const v4 = this.vec4Bytes;
    for (const m of this.meshes) {
      const viewProj = new Float32Array(multiply(view.viewProj, m.model));
      const light = recordLight(m.header, view.light);
      // Caps: one draw, six vertices per triangle.
      const c = this.caps;
      gl.useProgram(c.p);
      gl.uniformMatrix4fv(c.u.uViewProj, false, viewProj);
      gl.uniform4fv(c.u.uLight, light);
      this.attrib(0, this.vertexIds, 1, gl.FLOAT, false, 0, 0, 0);
      for (let i = 0; i < 3; i++) this.recordAttrib(1 + i, m.caps, 3 * v4, i * v4, 1);
      ext.drawArraysInstancedANGLE(gl.TRIANGLES, 0, 6, m.count);
      this.releaseAttribs();
      // Sides: per bucket k, k draws with uSide = 0..k-1 (paper Algorithm 1).
      for (const b of m.buckets) {
        const s = this.sidesProgram(b.k);
        gl.useProgram(s.p);
        gl.uniformMatrix4fv(s.u.uViewProj, false, viewProj);
        gl.uniform4fv(s.u.uLight, light);
        const stride = (2 + b.k) * v4;
        this.attrib(0, this.vertexIds, 1, gl.FLOAT, false, 0, 0, 0);
        for (let i = 0; i < 2 + b.k; i++) this.recordAttrib(1 + i, b.buffer, stride, i * v4, 1);
        for (let side = 0; side < b.k; side++) {
          gl.uniform1f(s.u.uSide, side);
          ext.drawArraysInstancedANGLE(gl.TRIANGLES, 0, 6, b.instances);
        }
        this.releaseAttribs();
      }
    }
    gl.depthMask(true);
    gl.colorMask(true, true, true, true);
  }

  /**
   * Renders one frame: depth + ambient, stencil, lit where stencil == 0.
   * `view` = { viewProj (column-major, f64 ok), eye [3], light [x, y, z, w] }.
   */
  render(view, colors) {
    const gl = this.gl;
    this.beginFrame(colors?.background || [0.12, 0.13, 0.16, 1]);
    this.drawScene(view, 1, colors);
    this.stencilPass(view);
    // Lit pass: only where no triangle lies between the point and the light.
    gl.stencilFunc(gl.EQUAL, 0, 0xff);
    gl.stencilOp(gl.KEEP, gl.KEEP, gl.KEEP);
    gl.depthFunc(gl.EQUAL);
    gl.depthMask(false);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE);
    this.drawScene(view, 2, colors);
    gl.disable(gl.BLEND);
    gl.disable(gl.STENCIL_TEST);
    gl.depthFunc(gl.LESS);
    gl.depthMask(true);
  }

  /** Clears colour (to `background`), depth and stencil; depth test LESS, no blending. */
  beginFrame(background) {
    const gl = this.gl;
    gl.viewport(0, 0, gl.drawingBufferWidth, gl.drawingBufferHeight);
    gl.clearColor(...background);
    gl.clearDepth(1);
    gl.clearStencil(0);
    gl.depthMask(true);
    gl.colorMask(true, true, true, true);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT | gl.STENCIL_BUFFER_BIT);
    gl.disable(gl.BLEND);
    gl.disable(gl.STENCIL_TEST);
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
  }

  /**
   * Test/debug frame whose pixels encode, per pixel: R = 255 model, 128
   * ground, 0 nothing; G = 255 where stencil != 0 (shadow); B = the stencil
   * value itself (mod 256). Read it back with readPixels.
   */
  renderStencilImage(view) {
    const gl = this.gl;
    this.beginFrame([0, 0, 0, 0]);
    this.drawScene(view, 0, { model: [1, 0, 0], ground: [128 / 255, 0, 0] });
    this.stencilPass(view);
    const q = this.quad;
    gl.useProgram(q.p);
    gl.disable(gl.DEPTH_TEST);
    this.attrib(0, this.quadBuffer, 2, gl.FLOAT, false, 0, 0, 0);
    gl.stencilOp(gl.KEEP, gl.KEEP, gl.KEEP);
    gl.colorMask(false, true, false, false);
    gl.stencilFunc(gl.NOTEQUAL, 0, 0xff);
    gl.uniform4f(q.u.uColor, 0, 1, 0, 0);
    gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
    // One pass per stencil bit, added into B: 2^b / 255 converts to exactly
    // 2^b in an 8-bit channel, so B ends up equal to the stencil value.
    gl.colorMask(false, false, true, false);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE, gl.ONE);
    for (let bit = 0; bit < 8; bit++) {
      gl.stencilFunc(gl.EQUAL, 1 << bit, 1 << bit);
      gl.uniform4f(q.u.uColor, 0, 0, (1 << bit) / 255, 0);
      gl.drawArrays(gl.TRIANGLE_STRIP, 0, 4);
    }
    this.releaseAttribs();
    gl.disable(gl.BLEND);
    gl.disable(gl.STENCIL_TEST);
    gl.enable(gl.DEPTH_TEST);
    gl.colorMask(true, true, true, true);
  }
}

/**
 * Flat per-vertex normals for drawing the caps records as plain triangles
 * (world space). Only the normals are computed here; positions stay in the
 * file's buffer.
 */
function flatNormals(mesh, vec4Bytes) {
  const d = mesh.caps.data;
  const n = new Float32Array(mesh.caps.count * 9);
  const o = mesh.positionOffset;
  const s = mesh.positionScale;
  const unorm = vec4Bytes === 8;
  const p = (t, c) => [0, 1, 2].map((i) => o[i] + (unorm ? d[12 * t + 4 * c + i] / 65535 : d[12 * t + 4 * c + i]) * s[i]);
  for (let t = 0; t < mesh.caps.count; t++) {
    const a = p(t, 0);
    const nn = normalize(cross(sub(p(t, 1), a), sub(p(t, 2), a)));
    for (let c = 0; c < 3; c++) n.set(nn, 9 * t + 3 * c);
  }
  return n;
}
