// Loader tests (node --test web/test/loader.test.mjs; run by tests/browser.rs).
//
// The normative test vector of format-spec/README.md §8 is read from the spec
// itself — the hex dump and the decoded field list — so the loader is checked
// against whatever the spec currently says, not a copy. Then corrupted
// variants of it must be rejected with messages that name the problem.

import test from 'node:test';
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { load, crc32, KNOWN_VERSIONS } from '../svpack.js';

const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
const spec = fs.readFileSync(path.join(root, 'format-spec/README.md'), 'utf8');
const vector = spec.slice(spec.indexOf('<!-- test-vector:begin -->'), spec.indexOf('<!-- test-vector:end -->'));

// "00000010: ad ea b7 45 ...  ascii" lines -> bytes.
function vectorBytes() {
  const bytes = [];
  for (const line of vector.split('\n')) {
    const m = line.match(/^[0-9a-f]{8}: ((?:[0-9a-f]{2} ?)+)/);
    if (m) bytes.push(...m[1].trim().split(/\s+/).map((h) => parseInt(h, 16)));
  }
  return new Uint8Array(bytes);
}

// "key = value" lines of the decoded list.
function vectorFields() {
  const out = new Map();
  for (const line of vector.split('\n')) {
    const m = line.match(/^([a-z_0-9.[\]]+) = (.*)$/);
    if (m) out.set(m[1], m[2]);
  }
  return out;
}

const fresh = () => vectorBytes().slice().buffer;
const vec = (v) => `[${v.map((x) => x.toFixed(1)).join(', ')}]`;
const hex = (v) => `0x${v.toString(16).padStart(8, '0')}`;

test('spec test vector decodes to the listed fields', () => {
  const bytes = vectorBytes();
  assert.ok(bytes.length > 24, 'the spec has a hex dump');
  const f = load(bytes.buffer);
  const want = vectorFields();
  const m = f.meshes[0];
  const got = {
    version_major: String(f.versionMajor),
    version_minor: String(f.versionMinor),
    header_len: String(f.headerLen),
    header_crc32: hex(f.headerCrc32),
    flags: String(f.flags),
    payload_offset: String(f.payloadOffset),
    payload_len: String(f.payloadLen),
    payload_crc32: hex(f.payloadCrc32),
    generator: JSON.stringify(f.generator),
    'input.file_name': JSON.stringify(f.input.fileName),
    'input.format': JSON.stringify(f.input.format),
    'input.bytes': String(f.input.bytes),
    'input.sha256': f.input.sha256,
    'options.max_mult': String(f.options.maxMult),
    'options.compress': String(Number(f.options.compress)),
    'options.positions': String(f.options.positions),
    bounds_min: vec(f.boundsMin),
    bounds_max: vec(f.boundsMax),
    meshes: String(f.meshes.length),
    'meshes[0].name': JSON.stringify(m.name),
    'meshes[0].bounds_min': vec(m.boundsMin),
    'meshes[0].bounds_max': vec(m.boundsMax),
    'meshes[0].position_offset': vec(m.positionOffset),
    'meshes[0].position_scale': vec(m.positionScale),
    'meshes[0].stats.histogram': `[${m.stats.histogram.map((h) => `${h.opposites}:${h.edges}`).join(', ')}]`,
    'meshes[0].caps': `offset ${m.caps.offset}, length ${m.caps.length}, count ${m.caps.count}`,
    reserved: String(f.reserved),
  };
  for (const [k, v] of Object.entries(m.stats)) if (k !== 'histogram') got[`meshes[0].stats.${k}`] = String(v);
  for (const b of m.buckets) got[`meshes[0].bucket k=${b.k}`] = `instances ${b.instances}, offset ${b.offset}, length ${b.length}`;
  // Records, as the spec prints them: "(x, y, z, w) (x, y, z, w) …".
  const rec = (data, n, i) => Array.from({ length: n }, (_, j) => `(${Array.from(data.subarray(4 * (n * i + j), 4 * (n * i + j) + 4), (x) => x.toFixed(1)).join(', ')})`).join(' ');
  for (let i = 0; i < m.caps.count; i++) got[`caps record ${i}`] = rec(m.caps.data, 3, i);
  for (const b of m.buckets) for (let i = 0; i < b.instances; i++) got[`sides k=${b.k} record ${i}`] = rec(b.data, 2 + b.k, i);
  // The decoded list uses "caps record 0: …" (colon); normalise to "=".
  for (const line of vector.split('\n')) {
    const r = line.match(/^((?:caps|sides k=\d+) record \d+): (.*)$/);
    if (r) want.set(r[1], r[2]);
  }
  let checked = 0;
  for (const [k, v] of want) {
    if (!(k in got)) continue;
    assert.equal(got[k], v, `field ${k}`);
    checked++;
  }
  assert.ok(checked >= 40, `only ${checked} fields compared`);
  // Views, not copies: the sections share the caller's buffer.
  assert.equal(m.caps.data.buffer, f.meshes[0].buckets[0].data.buffer);
  assert.ok(m.caps.data instanceof Float32Array);
});

test('CRC-32 matches zlib', () => {
  assert.equal(crc32(new TextEncoder().encode('123456789')), 0xcbf43926);
});

// Corruptions, each with the words its error must contain.
function patched(fn) {
  const b = new Uint8Array(fresh());
  fn(b, new DataView(b.buffer));
  return b.buffer;
}
// Rewrites the header CRC so that a header edit reaches the later checks.
function fixHeaderCrc(b, dv) {
  dv.setUint32(16, crc32(b, 24, 24 + dv.getUint32(12, true)), true);
}

test('corrupt files are rejected with a reason', () => {
  const cases = [
    ['bad magic', patched((b) => { b[0] = 0x54; }), /bad magic/],
    ['zstd', patched((b) => { b.set([0x28, 0xb5, 0x2f, 0xfd]); }), /zstd -d/],
    ['unknown major', patched((b, dv) => { dv.setUint16(8, 9, true); }), new RegExp(`9\\.\\d+.*${Object.keys(KNOWN_VERSIONS).at(-1)}\\.${Object.values(KNOWN_VERSIONS).at(-1)}`)],
    ['header bit flip', patched((b) => { b[40] ^= 1; }), /header checksum mismatch/],
    ['payload bit flip', patched((b, dv) => { b[b.length - 3] ^= 1; }), /payload checksum mismatch/],
    ['truncated', fresh().slice(0, 700), /truncated/],
    ['truncated header', fresh().slice(0, 100), /truncated/],
    ['trailing byte', (() => { const b = new Uint8Array(fresh().byteLength + 1); b.set(vectorBytes()); return b.buffer; })(), /trailing/],
    ['short preamble', fresh().slice(0, 10), /preamble/],
  ];
  // A section offset moved by 16 (and the header CRC fixed): tiling error.
  const f = load(fresh());
  const capsAt = findU64(new Uint8Array(fresh()), f.meshes[0].caps.offset, f.meshes[0].caps.length);
  cases.push(['section gap', patched((b, dv) => { dv.setBigUint64(capsAt, BigInt(f.meshes[0].caps.offset + 16), true); fixHeaderCrc(b, dv); }), /tile/]);
  if (f.versionMajor >= 2) {
    // BuildOptions = max_mult u32, compress u8, positions u8, right after
    // InputInfo (§3); strings are a u64 length and their UTF-8 bytes.
    const len = (s) => 8 + new TextEncoder().encode(s).length;
    const optionsAt = 24 + 8 + 8 + 4 + len(f.generator) + len(f.input.fileName) + len(f.input.format) + 8 + 32;
    assert.equal(new DataView(fresh()).getUint32(optionsAt, true), f.options.maxMult);
    cases.push(['unknown encoding', patched((b, dv) => { b[optionsAt + 5] = 7; fixHeaderCrc(b, dv); }), /unknown position encoding 7/]);
  }
  if (f.versionMajor === 2 && f.versionMinor >= 1) {
    // §3.1: the room's count is the header's last 8 bytes. One room byte
    // more, taken from the padding before the payload: a zero loads, a
    // nonzero is rejected.
    const hl = new DataView(fresh()).getUint32(12, true);
    assert.ok(24 + hl < f.payloadOffset, 'the vector has padding after its header');
    const room = (byte) => patched((b, dv) => {
      dv.setUint32(12, hl + 1, true);
      dv.setBigUint64(24 + hl - 8, 1n, true);
      b[24 + hl] = byte;
      fixHeaderCrc(b, dv);
    });
    assert.equal(load(room(0)).reserved, 1);
    cases.push(['nonzero room', room(1), /reserved room is not zero/]);
  }
  for (const [name, buf, re] of cases) {
    assert.throws(() => load(buf), re, name);
  }
});

// Offset of the caps Section {offset u64, length u64} in the header bytes.
function findU64(b, offset, length) {
  const dv = new DataView(b.buffer);
  for (let i = 24; i + 16 <= b.length; i++) {
    if (dv.getBigUint64(i, true) === BigInt(offset) && dv.getBigUint64(i + 8, true) === BigInt(length)) return i;
  }
  throw new Error('caps section not found in the header');
}
