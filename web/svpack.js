// svpack .svpk loader (format-spec/README.md is normative).
//
// Plain ES module, no dependencies. `load(arrayBuffer)` validates the whole
// container and returns typed-array views over the caller's buffer: the
// payload is never copied, so a renderer can hand the views straight to
// gl.bufferData.

/** zstd frame magic: `svpack build --compress` wraps whole files in one frame. */
const ZSTD_MAGIC = [0x28, 0xb5, 0x2f, 0xfd];
/** "SVPK\r\n\x1a\n": the line-ending and EOF bytes catch text-mode transfers. */
const MAGIC = [0x53, 0x56, 0x50, 0x4b, 0x0d, 0x0a, 0x1a, 0x0a];
const PREAMBLE_LEN = 24;
const ALIGN = 16;
const HEADER_LIMIT = 16 << 20;

/**
 * Majors this reader knows, with the newest minor it knows for each. A file of
 * a known major and a newer minor may carry header fields appended after the
 * ones read here (format-spec §7); they are skipped.
 */
export const KNOWN_VERSIONS = { 2: 1 };

/** Position encodings (BuildOptions.positions, format 2.x). */
export const ENCODINGS = {
  0: { name: 'f32', vec4Bytes: 16 },
  1: { name: 'unorm16', vec4Bytes: 8 },
};

// ---------------------------------------------------------------- CRC-32

let crcTable = null;

/** CRC-32 (IEEE polynomial, reflected, as zlib/PNG) of bytes[start, end). */
export function crc32(bytes, start = 0, end = bytes.length) {
  if (crcTable === null) {
    crcTable = new Uint32Array(256);
    for (let n = 0; n < 256; n++) {
      let c = n;
      for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
      crcTable[n] = c >>> 0;
    }
  }
  let c = 0xffffffff;
  for (let i = start; i < end; i++) c = crcTable[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}

// ---------------------------------------------------------------- header

/**
 * Little-endian bincode (legacy configuration) cursor over the header bytes.
 * Every read checks the bounds so that a corrupt count cannot run past the
 * header into the payload.
 */
class Reader {
  constructor(bytes, start, end) {
    this.view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
    this.bytes = bytes;
    this.at = start;
    this.end = end;
  }
  need(n, what) {
    if (n > this.end - this.at) {
      throw new Error(`header truncated: ${what} needs ${n} bytes at header offset ${this.at - PREAMBLE_LEN}, ${this.end - this.at} left`);
    }
  }
  u8(what) { this.need(1, what); return this.view.getUint8(this.at++); }
  bool(what) {
    const v = this.u8(what);
    if (v > 1) throw new Error(`header: ${what} is ${v}, not a bool (0 or 1)`);
    return v === 1;
  }
  u32(what) { this.need(4, what); const v = this.view.getUint32(this.at, true); this.at += 4; return v; }
  f32(what) { this.need(4, what); const v = this.view.getFloat32(this.at, true); this.at += 4; return v; }
  // u64 as a Number: every quantity in a file (offsets, counts) must stay
  // below 2^53 to be addressable from JavaScript at all.
  u64(what) {
    this.need(8, what);
    const v = this.view.getBigUint64(this.at, true);
    this.at += 8;
    if (v > BigInt(Number.MAX_SAFE_INTEGER)) throw new Error(`header: ${what} = ${v} is too large`);
    return Number(v);
  }
  vec3(what) { return [this.f32(what), this.f32(what), this.f32(what)]; }
  // A list count can be checked against the bytes left before allocating.
  count(what, minElementBytes) {
    const n = this.u64(`${what} count`);
    if (n * minElementBytes > this.end - this.at) {
      throw new Error(`header: ${what} count ${n} does not fit in the ${this.end - this.at} header bytes left`);
    }
    return n;
  }
  string(what) {
    const n = this.count(what, 1);
    const s = this.bytes.subarray(this.at, this.at + n);
    this.at += n;
    try {
      return new TextDecoder('utf-8', { fatal: true }).decode(s);
    } catch {
      throw new Error(`header: ${what} is not valid UTF-8`);
    }
  }
}

/**
 * Decodes the bincode header (format-spec §3) of a file with version
 * `major.minor`, from bytes[start, end). Kept apart from the container checks
 * because this is the part that changes between majors.
 */
export function parseHeader(bytes, start, end, major, minor) {
  const r = new Reader(bytes, start, end);
  const h = {};
  h.payloadOffset = r.u64('payload_offset');
  h.payloadLen = r.u64('payload_len');
  h.payloadCrc32 = r.u32('payload_crc32');
  h.generator = r.string('generator');
  h.input = {
    fileName: r.string('input.file_name'),
    format: r.string('input.format'),
    bytes: r.u64('input.bytes'),
    sha256: Array.from(bytes.subarray(r.at, r.at + 32), (b) => b.toString(16).padStart(2, '0')).join(''),
  };
  r.need(32, 'input.sha256');
  r.at += 32;
  h.options = { maxMult: r.u32('options.max_mult'), compress: r.bool('options.compress') };
  h.options.positions = r.u8('options.positions');
  h.boundsMin = r.vec3('bounds_min');
  h.boundsMax = r.vec3('bounds_max');
  const meshCount = r.count('meshes', 8);
  h.meshes = [];
  for (let i = 0; i < meshCount; i++) {
    const m = { name: r.string(`meshes[${i}].name`) };
    m.boundsMin = r.vec3('mesh bounds_min');
    m.boundsMax = r.vec3('mesh bounds_max');
    // Record space -> world space: world = offset + record * scale (per axis).
    m.positionOffset = r.vec3('mesh position_offset');
    m.positionScale = r.vec3('mesh position_scale');
    const s = {};
    for (const f of ['primitives', 'input_triangles', 'input_vertices', 'welded_vertices',
      'degenerate_triangles', 'skipped_points', 'skipped_lines', 'triangles', 'edges',
      'edge_instances', 'open_edges', 'non_manifold_edges']) {
      s[f] = r.u64(`meshes[${i}].stats.${f}`);
    }
    s.max_fan = r.u32('stats.max_fan');
    const hn = r.count('stats.histogram', 12);
    s.histogram = [];
    for (let j = 0; j < hn; j++) s.histogram.push({ opposites: r.u32('histogram opposites'), edges: r.u64('histogram edges') });
    m.stats = s;
    m.caps = { offset: r.u64('caps.offset'), length: r.u64('caps.length'), count: r.u64('caps.count') };
    const bn = r.count('buckets', 28);
    m.buckets = [];
    for (let j = 0; j < bn; j++) {
      m.buckets.push({ k: r.u32('bucket k'), instances: r.u64('bucket instances'), offset: r.u64('bucket offset'), length: r.u64('bucket length') });
    }
    h.meshes.push(m);
  }
  // 2.1 (§3.1): the header room, a count and that many zero bytes.
  h.reserved = 0;
  if (minor >= 1) {
    const n = r.count('reserved', 1);
    for (let j = 0; j < n; j++) {
      if (r.u8('reserved room') !== 0) throw new Error('header: reserved room is not zero');
    }
    h.reserved = n;
  }
  // §7: a reader of minor m must find exactly header_len bytes of known fields
  // in a file of minor <= m; a newer minor may append fields, which we skip.
  if (minor <= KNOWN_VERSIONS[major] && r.at !== end) {
    throw new Error(`header: ${end - r.at} unexpected bytes after the known fields (header_len says ${end - start}, fields end at ${r.at - start})`);
  }
  return h;
}

// ---------------------------------------------------------------- container

const alignUp = (v) => Math.ceil(v / ALIGN) * ALIGN;

/**
 * Parses and validates a .svpk file. `data` is an ArrayBuffer (or a typed
 * array over one). Returns
 * `{ versionMajor, versionMinor, flags, headerLen, headerCrc32, header fields…,
 *    encoding: {name, vec4Bytes}, meshes: [{ …, caps: {…, data}, buckets: [{…, data}] }] }`
 * where every `data` is a Float32Array (f32 encoding) or Uint16Array (unorm16)
 * view over the same buffer, never a copy. Throws Error with the reason.
 */
export function load(data) {
  let bytes;
  if (data instanceof ArrayBuffer) bytes = new Uint8Array(data);
  else if (ArrayBuffer.isView(data)) bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  else throw new Error('svpack.load expects an ArrayBuffer');
  if (bytes.byteOffset % ALIGN !== 0) {
    // Typed-array views need aligned offsets; this is the only copy we ever make.
    bytes = bytes.slice();
  }
  if (bytes.length >= 4 && ZSTD_MAGIC.every((b, i) => bytes[i] === b)) {
    throw new Error('this .svpk is zstd-compressed (svpack build --compress); decompress it first, e.g. `zstd -d file.svpk -o plain.svpk`');
  }
  if (bytes.length < PREAMBLE_LEN) {
    throw new Error(`truncated file: ${bytes.length} bytes, shorter than the ${PREAMBLE_LEN}-byte preamble`);
  }
  if (!MAGIC.every((b, i) => bytes[i] === b)) throw new Error('not an .svpk file (bad magic)');
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const versionMajor = dv.getUint16(8, true);
  const versionMinor = dv.getUint16(10, true);
  if (!(versionMajor in KNOWN_VERSIONS)) {
    const known = Object.keys(KNOWN_VERSIONS).map((m) => `${m}.${KNOWN_VERSIONS[m]}`).join(', ');
    throw new Error(`unsupported .svpk version ${versionMajor}.${versionMinor}: this reader knows version ${known}`);
  }
  const headerLen = dv.getUint32(12, true);
  const headerCrc32 = dv.getUint32(16, true);
  const flags = dv.getUint32(20, true);
  if (headerLen > HEADER_LIMIT) throw new Error(`header length ${headerLen} exceeds the 16 MiB limit`);
  const headerEnd = PREAMBLE_LEN + headerLen;
  if (headerEnd > bytes.length) {
    throw new Error(`truncated file: header needs ${headerLen} bytes, only ${bytes.length - PREAMBLE_LEN} present`);
  }
  const gotHeaderCrc = crc32(bytes, PREAMBLE_LEN, headerEnd);
  if (gotHeaderCrc !== headerCrc32) {
    throw new Error(`header checksum mismatch: stored 0x${hex(headerCrc32)}, computed 0x${hex(gotHeaderCrc)}`);
  }
  const h = parseHeader(bytes, PREAMBLE_LEN, headerEnd, versionMajor, versionMinor);

  const encoding = ENCODINGS[h.options.positions];
  if (!encoding) throw new Error(`unknown position encoding ${h.options.positions} (known: 0 = f32, 1 = unorm16)`);
  if (h.options.maxMult < 1 || h.options.maxMult > 13) throw new Error(`max_mult ${h.options.maxMult} out of range 1..13`);
  if (h.payloadOffset !== alignUp(headerEnd)) {
    throw new Error(`payload_offset ${h.payloadOffset} should be ${alignUp(headerEnd)} (header end rounded up to 16)`);
  }
  const payloadEnd = h.payloadOffset + h.payloadLen;
  if (bytes.length < payloadEnd) throw new Error(`truncated file: ${bytes.length} bytes, the header says ${payloadEnd}`);
  if (bytes.length > payloadEnd) throw new Error(`${bytes.length - payloadEnd} trailing bytes after the payload`);
  const gotPayloadCrc = crc32(bytes, h.payloadOffset, payloadEnd);
  if (gotPayloadCrc !== h.payloadCrc32) {
    throw new Error(`payload checksum mismatch: stored 0x${hex(h.payloadCrc32)}, computed 0x${hex(gotPayloadCrc)}`);
  }

  // Sections must tile the payload in order: per mesh its caps, then its
  // buckets by increasing k. 1.x sections are multiples of 16 bytes; 2.x pads
  // each to 16 (unorm16 records are 8 bytes per vec4).
  const vec4 = encoding.vec4Bytes;
  const View = vec4 === 16 ? Float32Array : Uint16Array;
  const view = (off, len) => new View(bytes.buffer, bytes.byteOffset + off, len / View.BYTES_PER_ELEMENT);
  let at = h.payloadOffset;
  const place = (what, sec, expected) => {
    if (sec.offset !== at) throw new Error(`${what}: offset ${sec.offset}, expected ${at} (sections must tile the payload in order)`);
    if (sec.length !== expected) throw new Error(`${what}: length ${sec.length}, expected ${expected}`);
    at = versionMajor >= 2 ? alignUp(at + sec.length) : at + sec.length;
    if (at > payloadEnd) throw new Error(`${what}: runs past the payload end ${payloadEnd}`);
  };
  h.meshes.forEach((m, i) => {
    if (!m.positionScale.every((s) => s > 0 && Number.isFinite(s)) || !m.positionOffset.every(Number.isFinite)) {
      throw new Error(`mesh ${i} ("${m.name}"): position transform must be finite with positive scale`);
    }
    place(`mesh ${i} caps`, m.caps, 3 * vec4 * m.caps.count);
    m.caps.data = view(m.caps.offset, m.caps.length);
    let prevK = 0;
    for (const b of m.buckets) {
      if (b.k <= prevK) throw new Error(`mesh ${i}: bucket k=${b.k} after k=${prevK} (must increase)`);
      if (b.k > h.options.maxMult) throw new Error(`mesh ${i}: bucket k=${b.k} exceeds max_mult ${h.options.maxMult}`);
      if (b.instances === 0) throw new Error(`mesh ${i}: bucket k=${b.k} is empty`);
      place(`mesh ${i} bucket k=${b.k}`, b, (2 + b.k) * vec4 * b.instances);
      b.data = view(b.offset, b.length);
      prevK = b.k;
    }
  });
  if (at !== payloadEnd) throw new Error(`sections end at ${at}, payload ends at ${payloadEnd}`);

  return { versionMajor, versionMinor, flags, headerLen, headerCrc32, encoding, ...h };
}

function hex(v) {
  return v.toString(16).padStart(8, '0');
}
