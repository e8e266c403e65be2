//! The `.svpk` container: read and write (format-spec/README.md is normative).
//!
//! ```text
//! 0   8  magic  "SVPK\r\n\x1a\n"
//! 8   2  u16    version major (2)
//! 10  2  u16    version minor (0)
//! 12  4  u32    header length H
//! 16  4  u32    CRC-32 of the header bytes
//! 20  4  u32    flags (0)
//! 24  H         header: bincode 2 legacy config (fixed-width little-endian integers)
//! ..            zero padding to a multiple of 16 = payload_offset
//! ..            payload: sections, each 16-byte aligned, absolute offsets
//! ```
//!
//! A whole file may be wrapped in one standard zstd frame (`--compress`);
//! readers recognise the zstd magic and unwrap it first.

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::Path;

/// File magic: "SVPK" then the PNG-style line-ending/EOF guard.
pub const MAGIC: [u8; 8] = *b"SVPK\r\n\x1a\n";
/// Major version: readers reject any other major. 2.0 added the position
/// encoding (f32 or 16-bit quantised) and the per-mesh record-space transform.
pub const VERSION_MAJOR: u16 = 2;
/// Minor version: readers accept any minor of their major (fields are only
/// ever appended to the header, and the header length lets old readers skip them).
/// 2.1 appended [`Header::reserved`].
pub const VERSION_MINOR: u16 = 1;
/// Bytes before the header.
pub const PREAMBLE_LEN: usize = 24;
/// Payload and section alignment.
pub const ALIGN: u64 = 16;
/// Largest header a reader accepts (also the bincode decode allocation limit).
pub const HEADER_LIMIT: usize = 16 << 20;
/// Largest decompressed file a reader accepts from a zstd-wrapped file.
pub const DECOMPRESSED_LIMIT: u64 = 16 << 30;
/// zstd frame magic (little-endian 0xFD2FB528).
pub const ZSTD_MAGIC: [u8; 4] = [0x28, 0xB5, 0x2F, 0xFD];
/// zstd level of `--compress` when no `--compress-level` is given. The
/// frame is a function of the container bytes and the level alone (any
/// thread count), so a given level's output is reproducible.
pub const ZSTD_LEVEL: i32 = 9;

/// Levels `--compress-level` accepts: zstd's 1 (fastest) to 22 (smallest).
/// zstd's negative "fast" levels and its 0 ("the library's default", which
/// would change with the library) are left out.
pub const ZSTD_LEVELS: std::ops::RangeInclusive<i32> = 1..=22;

/// zstd worker threads for one frame: as many as the current rayon pool
/// has threads, and never 0. zstd with workers cuts the input into jobs of
/// a size set by the level, not by the number of workers, so the frame is
/// the same bytes for any count from 1 up (`tests/batch.rs` checks it);
/// 0 (compressing on the calling thread) would give another frame.
/// Single-threaded level 9 took 1.8 s of the dragon's 2.0 s compressed
/// build.
fn zstd_workers() -> u32 {
    rayon::current_num_threads().max(1) as u32
}

/// Input bytes per zstd job with workers. zstd's default at level 9 is
/// 16 MiB, whose buffers raised the dragon's compressed build from 187 to
/// 255 MB peak (one worker) and 286 MB (two); 4 MiB keeps it at 201 and
/// 218 MB, as fast, and the frame 0.01% smaller.
const ZSTD_JOB_BYTES: u32 = 4 << 20;

/// File header.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Absolute offset of the payload (multiple of 16).
    pub payload_offset: u64,
    /// Payload length in bytes; the file ends exactly at `payload_offset + payload_len`.
    pub payload_len: u64,
    /// CRC-32 (IEEE, as zlib/PNG) of the payload bytes.
    pub payload_crc32: u32,
    /// Tool that wrote the file, e.g. "svpack 0.2.1".
    pub generator: String,
    /// Where the geometry came from.
    pub input: InputInfo,
    /// Options the file was built with.
    pub options: BuildOptions,
    /// Bounds of all meshes (zeros when empty).
    pub bounds_min: [f32; 3],
    /// Upper bounds.
    pub bounds_max: [f32; 3],
    /// Meshes in drawing order.
    pub meshes: Vec<MeshHeader>,
    /// Zero bytes at the end of the header (format 2.1; 0 in 2.0 files),
    /// after a u64 count of them: the room a writer keeps so that the
    /// header's length, and so where the payload starts, is known before
    /// the edge statistics are ([`header_room`]). Not part of the serde
    /// structure: [`encode_header`] appends it and the reader reads it.
    #[serde(skip)]
    pub reserved: u64,
}

/// Input description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InputInfo {
    /// File name without directories.
    pub file_name: String,
    /// "gltf" or "obj".
    pub format: String,
    /// Bytes read (main file and external buffers).
    pub bytes: u64,
    /// SHA-256 of those bytes in read order.
    pub sha256: [u8; 32],
}

/// Build options recorded in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BuildOptions {
    /// K: largest opposite-vertex count per side instance.
    pub max_mult: u32,
    /// Whether the file was written zstd-wrapped.
    pub compress: bool,
    /// How record vec4s are stored: [`Encoding::code`] (0 = f32, 1 = unorm16).
    pub positions: u8,
}

impl BuildOptions {
    /// The position encoding, or an error for an unknown code.
    pub fn encoding(&self) -> std::result::Result<Encoding, String> {
        Encoding::from_code(self.positions)
    }
}

/// How the vec4s of sides and caps records are stored (format-spec §4.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Encoding {
    /// Four little-endian f32 per vec4 (16 bytes); record space is world space.
    #[default]
    F32,
    /// Four little-endian u16 per vec4 (8 bytes): `xyz` are read as normalized
    /// UNSIGNED_SHORT (`c / 65535`) over the mesh's quantisation box, `w` holds
    /// the raw integer.
    Unorm16,
}

impl Encoding {
    /// Code stored in `BuildOptions::positions`.
    pub fn code(self) -> u8 {
        match self {
            Encoding::F32 => 0,
            Encoding::Unorm16 => 1,
        }
    }

    /// Encoding for a stored code.
    pub fn from_code(code: u8) -> std::result::Result<Encoding, String> {
        match code {
            0 => Ok(Encoding::F32),
            1 => Ok(Encoding::Unorm16),
            c => Err(format!(
                "unknown position encoding {c} (known: 0 = f32, 1 = unorm16)"
            )),
        }
    }

    /// Name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Encoding::F32 => "f32",
            Encoding::Unorm16 => "unorm16",
        }
    }

    /// Bytes per stored vec4.
    pub fn vec4_bytes(self) -> u64 {
        match self {
            Encoding::F32 => 16,
            Encoding::Unorm16 => 8,
        }
    }

    /// Largest `.w` integer the encoding stores exactly; `B.w` saturates here.
    pub fn w_limit(self) -> f32 {
        match self {
            Encoding::F32 => 16_777_216.0,
            Encoding::Unorm16 => 65_535.0,
        }
    }
}

/// Record-space value of a unorm16 code: `c / 65535` rounded once to f32, as
/// the GL conversion of a normalized UNSIGNED_SHORT (format-spec §4.5).
#[inline(always)]
pub fn unorm16_to_f32(c: u16) -> f32 {
    c as f32 / 65535.0
}

/// The unorm16 code whose record-space value is `u` (exact inverse of
/// [`unorm16_to_f32`] on its image; clamps anything else into 0..=65535).
#[inline(always)]
pub fn f32_to_unorm16(u: f32) -> u16 {
    (u as f64 * 65535.0).round().clamp(0.0, 65535.0) as u16
}

/// A mesh: one welded triangle set with its caps and side buckets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeshHeader {
    /// Mesh name (the input file stem for whole-file builds).
    pub name: String,
    /// Lower bounds of the mesh's positions.
    pub bounds_min: [f32; 3],
    /// Upper bounds.
    pub bounds_max: [f32; 3],
    /// Record space to world space: `world = position_offset + record · position_scale`
    /// per axis (f32 encoding: zeros and ones, record space is world space).
    pub position_offset: [f32; 3],
    /// Per-axis scale of that transform (all > 0).
    pub position_scale: [f32; 3],
    /// Build statistics.
    pub stats: MeshStats,
    /// Caps section: `count` triangles, 3 vec4 each.
    pub caps: Section,
    /// Side buckets, increasing k, only non-empty ones.
    pub buckets: Vec<BucketHeader>,
}

/// A payload section.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Section {
    /// Absolute byte offset (multiple of 16).
    pub offset: u64,
    /// Length in bytes.
    pub length: u64,
    /// Number of records.
    pub count: u64,
}

/// One side bucket: `instances` records of `(2 + k)` vec4.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct BucketHeader {
    /// Opposite vertices per instance.
    pub k: u32,
    /// Number of instances.
    pub instances: u64,
    /// Absolute byte offset (multiple of 16).
    pub offset: u64,
    /// `vec4_bytes · (2 + k) · instances`.
    pub length: u64,
}

/// Statistics of one mesh, as printed by `build` and `inspect`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MeshStats {
    /// Triangle primitives / OBJ groups read.
    pub primitives: u64,
    /// Triangles in the input (after triangulation, before welding).
    pub input_triangles: u64,
    /// Vertices in the input (position count).
    pub input_vertices: u64,
    /// Distinct positions used by kept triangles.
    pub welded_vertices: u64,
    /// Triangles dropped because two corners welded together.
    pub degenerate_triangles: u64,
    /// Point primitives/elements skipped.
    pub skipped_points: u64,
    /// Line primitives/elements skipped.
    pub skipped_lines: u64,
    /// Kept triangles (caps records).
    pub triangles: u64,
    /// Undirected edges.
    pub edges: u64,
    /// Side instances after splitting.
    pub edge_instances: u64,
    /// Edges with one opposite vertex.
    pub open_edges: u64,
    /// Edges with more than two opposite vertices.
    pub non_manifold_edges: u64,
    /// Largest opposite-vertex count.
    pub max_fan: u32,
    /// Edges by opposite-vertex count (JSON name `opposite_histogram`).
    #[serde(rename = "opposite_histogram")]
    pub histogram: Vec<HistogramEntry>,
}

impl MeshStats {
    /// Adds `other` into `self` (totals summed, `max_fan` maxed, histograms merged).
    pub fn add(&mut self, other: &MeshStats) {
        self.primitives += other.primitives;
        self.input_triangles += other.input_triangles;
        self.input_vertices += other.input_vertices;
        self.welded_vertices += other.welded_vertices;
        self.degenerate_triangles += other.degenerate_triangles;
        self.skipped_points += other.skipped_points;
        self.skipped_lines += other.skipped_lines;
        self.triangles += other.triangles;
        self.edges += other.edges;
        self.edge_instances += other.edge_instances;
        self.open_edges += other.open_edges;
        self.non_manifold_edges += other.non_manifold_edges;
        self.max_fan = self.max_fan.max(other.max_fan);
        for e in &other.histogram {
            match self
                .histogram
                .iter_mut()
                .find(|h| h.opposites == e.opposites)
            {
                Some(h) => h.edges += e.edges,
                None => self.histogram.push(*e),
            }
        }
        self.histogram.sort_by_key(|h| h.opposites);
    }
}

/// One histogram bar.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HistogramEntry {
    /// Opposite-vertex count.
    pub opposites: u32,
    /// Number of edges with that count.
    pub edges: u64,
}

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::legacy().with_limit::<HEADER_LIMIT>()
}

/// Rounds `v` up to a multiple of [`ALIGN`].
pub fn align_up(v: u64) -> u64 {
    v.div_ceil(ALIGN) * ALIGN
}

/// Data for one mesh to be written: the header parts and the float sections.
pub struct MeshPayload<'a> {
    /// Mesh header; section offsets and lengths are filled in by [`encode_to`].
    pub header: MeshHeader,
    /// Caps floats, in record space.
    pub caps: &'a [f32],
    /// Side bucket floats, in record space, in the order of `header.buckets`.
    pub buckets: Vec<&'a [f32]>,
}

/// Encodes record floats (vec4 after vec4, starting at a vec4 boundary)
/// into `buf`, which holds at least `floats.len() · bytes per float`;
/// returns the bytes written. Unorm16 stores `xyz` as the codes of their
/// record-space values and `w` as a saturated integer.
fn encode_floats(floats: &[f32], enc: Encoding, buf: &mut [u8]) -> usize {
    match enc {
        Encoding::F32 => {
            for (i, v) in floats.iter().enumerate() {
                buf[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
            }
            floats.len() * 4
        }
        Encoding::Unorm16 => {
            for (i, v) in floats.iter().enumerate() {
                let c = if i % 4 == 3 {
                    v.clamp(0.0, 65535.0) as u16
                } else {
                    f32_to_unorm16(*v)
                };
                buf[2 * i..2 * i + 2].copy_from_slice(&c.to_le_bytes());
            }
            floats.len() * 2
        }
    }
}

/// Writes record floats in `enc` ([`encode_floats`]), then zeros up to the
/// next multiple of [`ALIGN`], through a small buffer.
fn write_records<W: Write>(out: &mut W, floats: &[f32], enc: Encoding) -> std::io::Result<()> {
    // f32 on a little-endian machine: the memory already is the file's bytes.
    if enc == Encoding::F32 && cfg!(target_endian = "little") {
        let bytes: &[u8] = bytemuck::cast_slice(floats);
        out.write_all(bytes)?;
        let n = bytes.len() as u64;
        return out.write_all(&[0u8; 16][..(align_up(n) - n) as usize]);
    }
    let mut buf = [0u8; 1 << 16];
    let mut written = 0u64;
    for chunk in floats.chunks(buf.len() / 4) {
        let n = encode_floats(chunk, enc, &mut buf);
        out.write_all(&buf[..n])?;
        written += n as u64;
    }
    let pad = (align_up(written) - written) as usize;
    out.write_all(&[0u8; 16][..pad])
}

/// CRC-32 of what [`write_records`] writes, computed on all threads.
///
/// The floats are cut into fixed chunks whose encoded sizes are multiples of
/// [`ALIGN`], so [`write_records`] of each chunk pads nothing except after the
/// last one, and the chunks' byte streams concatenate to exactly the
/// section's (an empty section writes nothing, not even padding). Each chunk is hashed on its own and the CRCs are combined in
/// chunk order (`crc32fast::Hasher::combine`), so the result is the CRC of the
/// whole stream whatever the thread count.
fn crc_records(hasher: &mut crc32fast::Hasher, floats: &[f32], enc: Encoding) {
    use rayon::prelude::*;
    /// 1 MiB of f32 (512 KiB of unorm16): both multiples of ALIGN.
    const CHUNK_FLOATS: usize = 1 << 18;
    let parts: Vec<crc32fast::Hasher> = floats
        .par_chunks(CHUNK_FLOATS)
        .map(|chunk| {
            let mut h = crc32fast::Hasher::new();
            crc_records_serial(&mut h, chunk, enc);
            h
        })
        .collect();
    for part in &parts {
        hasher.combine(part);
    }
}

/// CRC-32 of what [`write_records`] writes, on the calling thread.
fn crc_records_serial(hasher: &mut crc32fast::Hasher, floats: &[f32], enc: Encoding) {
    struct H<'a>(&'a mut crc32fast::Hasher);
    impl Write for H<'_> {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.update(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    write_records(&mut H(hasher), floats, enc).expect("hashing cannot fail");
}

/// The header's bytes as a file holds them (format-spec §3): the 2.0
/// fields, then [`Header::reserved`], its count and that many zeros. Their
/// length does not change once sections are placed: fixed-width integers
/// make it independent of the offsets and the checksum.
pub fn encode_header(header: &Header) -> Result<Vec<u8>> {
    let mut bytes = bincode::serde::encode_to_vec(header, bincode_config())
        .map_err(|e| Error::Other(format!("cannot encode header: {e}")))?;
    bytes.extend_from_slice(&header.reserved.to_le_bytes());
    bytes.resize(bytes.len() + header.reserved as usize, 0);
    Ok(bytes)
}

/// Fewest kept triangles for which a writer keeps header room
/// ([`header_room`]). Below it the caps are under 3 MiB, whose copy (about
/// half a millisecond here) is not worth a header longer than it has to be.
pub const ROOM_MIN_TRIANGLES: u64 = 1 << 16;

/// Histogram entries (distinct opposite counts) the header room holds. The
/// most any of the 26 models in `../shared/meshes` has is 5 (three of them
/// have 4 or 5); a mesh with more is written without room.
pub const ROOM_HISTOGRAM_ENTRIES: usize = 64;

/// The length a writer gives the header of `header` if the file keeps
/// room: a one-mesh file of at least [`ROOM_MIN_TRIANGLES`] triangles
/// (compressed too, so that a compressed file holds the same container as
/// an uncompressed one but for its `compress` flag). `header` needs its
/// strings, options and the mesh's name and `stats.triangles`; offsets,
/// statistics and buckets do not count. The length is that of the header
/// with [`ROOM_HISTOGRAM_ENTRIES`] histogram entries and a bucket for every
/// k up to K, which does not depend on the edges; a header up to that long
/// is padded to it with [`Header::reserved`] (about 0.9 KB of zeros on the
/// dragon), a longer one is written as it is. Why: with two threads the
/// caps (a third of the file) are written while the edges are being made,
/// and with one thread before they are made, from the soup, which needs to
/// know where the payload starts (benches/ROUNDS.md, "Eighteenth round"
/// and "Twenty-second round").
pub fn header_room(header: &Header) -> Result<Option<usize>> {
    let [mesh] = header.meshes.as_slice() else {
        return Ok(None);
    };
    if mesh.stats.triangles < ROOM_MIN_TRIANGLES {
        return Ok(None);
    }
    let longest = MeshHeader {
        stats: MeshStats {
            histogram: vec![
                HistogramEntry {
                    opposites: 0,
                    edges: 0
                };
                ROOM_HISTOGRAM_ENTRIES
            ],
            ..mesh.stats.clone()
        },
        buckets: vec![
            BucketHeader {
                k: 0,
                instances: 0,
                offset: 0,
                length: 0
            };
            header.options.max_mult as usize
        ],
        ..mesh.clone()
    };
    let probe = Header {
        meshes: vec![longest],
        reserved: 0,
        ..header.clone()
    };
    Ok(Some(encode_header(&probe)?.len()))
}

/// Sets `header.reserved` so that the header is [`header_room`] bytes long
/// where the file keeps room and the header fits in it, and to 0 elsewhere.
/// Returns the header's encoded length, room included.
fn reserve_room(header: &mut Header) -> Result<usize> {
    header.reserved = 0;
    let len = encode_header(header)?.len();
    if let Some(room) = header_room(header)? {
        header.reserved = room.saturating_sub(len) as u64;
    }
    Ok(len + header.reserved as usize)
}

/// Fills every section's offset, length and count and the payload's offset
/// and length, from each mesh's section float counts (`floats[m]`: the caps,
/// then the buckets in header order). Returns the encoded header's length.
fn place_sections(header: &mut Header, floats: &[Vec<u64>]) -> Result<usize> {
    let vec4 = header
        .options
        .encoding()
        .map_err(Error::Other)?
        .vec4_bytes();
    // One encoding with zeros tells where the payload starts.
    let probe_len = reserve_room(header)?;
    let payload_offset = align_up((PREAMBLE_LEN + probe_len) as u64);
    let mut offset = payload_offset;
    for (mh, f) in header.meshes.iter_mut().zip(floats) {
        mh.caps = Section {
            offset,
            length: f[0] / 4 * vec4,
            count: f[0] / 12,
        };
        offset = align_up(offset + mh.caps.length);
        for (bh, &n) in mh.buckets.iter_mut().zip(&f[1..]) {
            bh.offset = offset;
            bh.length = n / 4 * vec4;
            offset = align_up(offset + bh.length);
        }
    }
    header.payload_offset = payload_offset;
    header.payload_len = offset - payload_offset;
    Ok(probe_len)
}

/// Fills section offsets, lengths and the payload checksum into a header.
/// Returns the encoded header bytes and the final header.
pub fn finalize_header(
    mut header: Header,
    meshes: &[MeshPayload<'_>],
) -> Result<(Vec<u8>, Header)> {
    header.meshes = meshes.iter().map(|m| m.header.clone()).collect();
    let enc = header.options.encoding().map_err(Error::Other)?;
    let floats: Vec<Vec<u64>> = meshes
        .iter()
        .map(|m| {
            std::iter::once(m.caps.len() as u64)
                .chain(m.buckets.iter().map(|b| b.len() as u64))
                .collect()
        })
        .collect();
    let probe_len = place_sections(&mut header, &floats)?;
    let mut crc = crc32fast::Hasher::new();
    for m in meshes {
        crc_records(&mut crc, m.caps, enc);
        for data in &m.buckets {
            crc_records(&mut crc, data, enc);
        }
    }
    header.payload_crc32 = crc.finalize();
    let bytes = encode_header(&header)?;
    debug_assert_eq!(bytes.len(), probe_len);
    Ok((bytes, header))
}

/// The bytes before the header: magic, version, header length and CRC.
fn preamble(hbytes: &[u8]) -> [u8; PREAMBLE_LEN] {
    let mut pre = [0u8; PREAMBLE_LEN];
    pre[0..8].copy_from_slice(&MAGIC);
    pre[8..10].copy_from_slice(&VERSION_MAJOR.to_le_bytes());
    pre[10..12].copy_from_slice(&VERSION_MINOR.to_le_bytes());
    pre[12..16].copy_from_slice(&(hbytes.len() as u32).to_le_bytes());
    pre[16..20].copy_from_slice(&crc32fast::hash(hbytes).to_le_bytes());
    pre
}

/// Encodes the whole file to `out` (uncompressed container bytes).
pub fn encode_to<W: Write>(
    out: &mut W,
    header: Header,
    meshes: &[MeshPayload<'_>],
) -> Result<Header> {
    let (hbytes, header) = finalize_header(header, meshes)?;
    let io = |e: std::io::Error| Error::Other(format!("write failed: {e}"));
    out.write_all(&preamble(&hbytes)).map_err(io)?;
    out.write_all(&hbytes).map_err(io)?;
    let pad = header.payload_offset as usize - PREAMBLE_LEN - hbytes.len();
    out.write_all(&[0u8; 16][..pad]).map_err(io)?;
    let enc = header.options.encoding().map_err(Error::Other)?;
    for m in meshes {
        write_records(out, m.caps, enc).map_err(io)?;
        for b in &m.buckets {
            write_records(out, b, enc).map_err(io)?;
        }
    }
    Ok(header)
}

/// Total size of the uncompressed container for `header` (after [`finalize_header`]).
pub fn container_len(header: &Header) -> u64 {
    header.payload_offset + header.payload_len
}

/// A temporary file beside `path`, renamed onto it once complete, so that
/// no reader ever sees a partial output.
///
/// Created with the permissions any new file gets (0666 less the umask, as
/// `File::create` does), not the temp file default of 0600: the output is
/// an asset other users and servers read, and the rename keeps the mode.
fn temp_beside(path: &Path) -> Result<tempfile::NamedTempFile> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let mut builder = tempfile::Builder::new();
    builder.prefix(".svpack-").suffix(".tmp");
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o666));
    builder.tempfile_in(dir).map_err(|e| Error::io(path, e))
}

/// Puts the complete temp file `tmp` (from [`temp_beside`]) at `path`: a
/// rename, except that on Linux an existing regular file at `path` is
/// swapped out (`renameat2` with `RENAME_EXCHANGE`) and then removed.
///
/// Why: on ext4 (its default `auto_da_alloc`), a rename that replaces a
/// file makes the rename call itself start writeback of the new file's
/// data, allocating its blocks and submitting its I/O: 66–73 ms for a
/// 120 MiB file here, on top of the 24 ms of freeing the old file. A build
/// into a fresh path pays neither; rebuilding in place, what a pipeline
/// does every time, paid both. The exchange is just as atomic for readers
/// (`path` always names the old or the new complete file, never nothing),
/// and leaves the new data to the kernel's flusher threads, as for a new
/// file. What it gives up is that heuristic's partial protection against
/// power loss right after the build, which a new output never had either
/// (svpack does not fsync: a pipeline reruns the build).
///
/// Anything else at `path` (nothing, a directory, a symlink) and any
/// filesystem without the exchange get the plain rename, with its usual
/// errors and semantics (a symlink is replaced, not followed).
fn persist(tmp: tempfile::NamedTempFile, path: &Path) -> Result<()> {
    persist_with(tmp, path, exchange)
}

/// [`persist`] with `swap` for the exchange (tests make it fail, as a
/// filesystem without `RENAME_EXCHANGE` does).
fn persist_with(
    tmp: tempfile::NamedTempFile,
    path: &Path,
    swap: impl Fn(&Path, &Path) -> std::io::Result<()>,
) -> Result<()> {
    if cfg!(target_os = "linux")
        && std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_file())
        && swap(tmp.path(), path).is_ok()
    {
        // `tmp`'s path now names the old file: remove it, beside the
        // batch's other builds when this thread has a `removals::Remover`.
        // (Were `path` replaced by a directory between the check and the
        // exchange, this fails on the directory, which is left beside the
        // output and named in the error.)
        return crate::removals::remove_old(path, tmp.into_temp_path());
    }
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// Atomically swaps the directory entries `a` and `b` (both must exist).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::os::unix::ffi::OsStrExt;
    let c = |p: &Path| std::ffi::CString::new(p.as_os_str().as_bytes());
    let (a, b) = (c(a)?, c(b)?);
    // The raw system call rather than libc's wrapper, which older glibc and
    // some musl versions lack; kernels before 3.15 or filesystems without
    // the flag fail with ENOSYS or EINVAL, and the caller renames instead.
    // SAFETY: two NUL-terminated paths that outlive the call.
    let rc = unsafe {
        libc::syscall(
            libc::SYS_renameat2,
            libc::AT_FDCWD,
            a.as_ptr(),
            libc::AT_FDCWD,
            b.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// No exchange off Linux: [`persist`] renames.
#[cfg(not(target_os = "linux"))]
fn exchange(_: &Path, _: &Path) -> std::io::Result<()> {
    Err(std::io::ErrorKind::Unsupported.into())
}

/// Writes the file to `path` atomically (temp file in the same directory,
/// then renamed or swapped in, see `persist`), optionally zstd-wrapped.
pub fn write_file(
    path: &Path,
    header: Header,
    meshes: &[MeshPayload<'_>],
    compress: Option<i32>,
) -> Result<Written> {
    let tmp = temp_beside(path)?;
    let file = tmp.as_file().try_clone().map_err(|e| Error::io(path, e))?;
    let clock = WriteClock::default();
    let file = TimedFile {
        file,
        clock: &clock,
    };
    let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
    let header = if let Some(level) = compress {
        let (_, probe) = finalize_header(header.clone(), meshes)?;
        let mut enc =
            zstd_encoder(&mut w, level, container_len(&probe)).map_err(|e| Error::io(path, e))?;
        let h = encode_to(&mut enc, header, meshes).map_err(|e| with_path(e, path))?;
        enc.finish().map_err(|e| Error::io(path, e))?;
        h
    } else {
        encode_to(&mut w, header, meshes).map_err(|e| with_path(e, path))?
    };
    w.flush().map_err(|e| Error::io(path, e))?;
    drop(w);
    // No fsync: the rename already guarantees readers never see a partial
    // file; surviving power loss is not worth ~100 ms per build in a pipeline
    // that can simply rerun.
    let size = tmp
        .as_file()
        .metadata()
        .map_err(|e| Error::io(path, e))?
        .len();
    persist(tmp, path)?;
    let (write_calls, write_bytes) = clock.spent();
    Ok(Written {
        header,
        bytes: size,
        write_calls,
        write_bytes,
    })
}

/// One mesh's payload produced piece by piece, for [`write_file_streamed`].
///
/// The sections are the caps, then the side buckets in the mesh header's
/// order. The payload is cut into independent units; in every section, unit
/// `u`'s floats follow unit `u − 1`'s, so each unit knows where its pieces go
/// before any is written.
pub trait PayloadSource: Sync {
    /// Number of units.
    fn units(&self) -> usize;
    /// Floats (in record space) that `unit` writes into `section`.
    fn floats(&self, unit: usize, section: usize) -> usize;
    /// Writes `unit`'s floats: `outs[s]` is its piece of section `s`,
    /// [`PayloadSource::floats`]`(unit, s)` long. Every float must be
    /// written: the pieces hold whatever an earlier unit left there.
    fn fill(&self, unit: usize, outs: &mut [&mut [f32]]);
    /// Whether [`PayloadSource::fill`] can write `unit`: false for a unit
    /// whose input the caller freed once it was written ahead (see
    /// [`write_file_streamed_finishing`]).
    fn can_fill(&self, unit: usize) -> bool {
        let _ = unit;
        true
    }
}

/// `buf` cut into consecutive pieces of `lens[i]` floats each (from its
/// start; what is left over is not in any piece): the `outs` a
/// [`PayloadSource::fill`] takes.
pub fn split_pieces<'a>(buf: &'a mut [f32], lens: &[usize]) -> Vec<&'a mut [f32]> {
    let mut outs = Vec::with_capacity(lens.len());
    let mut rest = buf;
    for &n in lens {
        let (piece, tail) = rest.split_at_mut(n);
        outs.push(piece);
        rest = tail;
    }
    outs
}

/// A NaN no record holds, put in every float of a unit's pieces before
/// [`PayloadSource::fill`] in debug builds, which then check that none is
/// left.
const UNWRITTEN: u32 = 0x7fa5_11ed;

/// Turns at writing one file, for threads that write units of it: a
/// thread about to write while another writes does `side` work until that
/// write ends or no side work is left, then writes (if both write, the
/// kernel serialises them on the file's lock). Why: writes into one file
/// take its lock in turn (`examples/file_write.rs`), so a thread waiting
/// for it is a thread idle; here it hashes what is left of the input's
/// digest instead (`load::DigestSlices`).
#[derive(Default)]
struct WriteTurns {
    /// Set while a thread writes.
    busy: std::sync::atomic::AtomicBool,
    /// The writes' time.
    clock: WriteClock,
}

impl WriteTurns {
    /// Writes `bytes` at `offset` of `file` in turn, doing `side` work
    /// while another thread writes.
    fn write(
        &self,
        file: &std::fs::File,
        bytes: &[u8],
        offset: u64,
        side: &dyn Fn() -> bool,
    ) -> std::io::Result<()> {
        use std::sync::atomic::Ordering::Relaxed;
        let wait = crate::trace::now();
        let mut waited = false;
        while self.busy.load(Relaxed) {
            waited = true;
            if !side() {
                break;
            }
        }
        if let (Some(wait), true) = (wait, waited) {
            crate::trace::since("wait for the file", wait);
        }
        self.busy.store(true, Relaxed);
        let write = crate::trace::span("file write");
        let written = self.clock.write_at(file, bytes, offset);
        write.end();
        self.busy.store(false, Relaxed);
        written
    }
}

/// The time a file's writers spent inside the calls that put its bytes
/// into the file (positioned writes, or the buffered writer's writes),
/// summed over the threads that made them ([`Written::write_calls`]).
#[derive(Default)]
struct WriteClock {
    /// Nanoseconds.
    time: std::sync::atomic::AtomicU64,
    /// Bytes the calls wrote.
    bytes: std::sync::atomic::AtomicU64,
}

impl WriteClock {
    /// `write`, a write call that returns the bytes it wrote, its time
    /// and bytes added.
    fn time(&self, write: impl FnOnce() -> std::io::Result<usize>) -> std::io::Result<usize> {
        use std::sync::atomic::Ordering::Relaxed;
        let start = std::time::Instant::now();
        let written = write();
        let ns = u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX);
        self.time.fetch_add(ns, Relaxed);
        self.bytes
            .fetch_add(*written.as_ref().unwrap_or(&0) as u64, Relaxed);
        written
    }

    /// [`write_at`], timed.
    fn write_at(&self, file: &std::fs::File, buf: &[u8], offset: u64) -> std::io::Result<()> {
        self.time(|| write_at(file, buf, offset).map(|()| buf.len()))
            .map(drop)
    }

    /// The time and bytes so far.
    fn spent(&self) -> (std::time::Duration, u64) {
        use std::sync::atomic::Ordering::Relaxed;
        (
            std::time::Duration::from_nanos(self.time.load(Relaxed)),
            self.bytes.load(Relaxed),
        )
    }
}

/// A file, its writes timed by a [`WriteClock`]: the buffered writer's
/// file in [`write_file`].
struct TimedFile<'a> {
    file: std::fs::File,
    clock: &'a WriteClock,
}

impl Write for TimedFile<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.clock.time(|| self.file.write(buf))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        // (A file's flush writes nothing: it has no buffer.)
        self.file.flush()
    }
}

/// What a file writer ([`write_file`], [`write_file_streamed`],
/// [`write_file_streamed_finishing`]) wrote.
#[derive(Debug, Clone)]
pub struct Written {
    /// The final header.
    pub header: Header,
    /// Bytes on disk.
    pub bytes: u64,
    /// Time inside the calls that put the file's bytes into it (its
    /// positioned writes, including those of an [`AheadFile`] it
    /// finishes and of moves within the file; for [`write_file`], its
    /// buffered writer's writes), summed over the threads that made them:
    /// the copy into the page cache, which no code of svpack's can make
    /// shorter. Not the filling, hashing or compressing around them.
    pub write_calls: std::time::Duration,
    /// Bytes those calls wrote: each byte the writers put into the file
    /// once (the zero gaps between sections, which the file's length
    /// gives, are not written), plus pieces written ahead that were moved
    /// within the file or written again (`layout::write_sides_ahead`'s
    /// guess failing).
    pub write_bytes: u64,
}

/// Writes `buf` at `offset` of `file`.
fn write_at(file: &std::fs::File, buf: &[u8], offset: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::os::unix::fs::FileExt::write_all_at(file, buf, offset)
    }
    #[cfg(windows)]
    {
        let (mut buf, mut offset) = (buf, offset);
        while !buf.is_empty() {
            match std::os::windows::fs::FileExt::seek_write(file, buf, offset)? {
                0 => return Err(std::io::ErrorKind::WriteZero.into()),
                n => {
                    buf = &buf[n..];
                    offset += n as u64;
                }
            }
        }
        Ok(())
    }
    #[cfg(not(any(unix, windows)))]
    {
        let _ = (file, buf, offset);
        Err(std::io::Error::new(
            std::io::ErrorKind::Unsupported,
            "positioned writes are not available on this platform",
        ))
    }
}

/// Moves the `len` bytes at `from` of `file` up to `to` (`to >= from`; the
/// two ranges may overlap), a block at a time from the end, so that no
/// byte is overwritten before it is read; and writes zeros over what the
/// move leaves of `from..from + len` below `to`. The file grows if `to +
/// len` is past its end.
///
/// Why: when a file's header outgrows its room, every section written
/// ahead lies too low by as much; moving them is a copy within the page
/// cache, where filling them again needs their input, which a one-thread
/// build frees once the caps are written (`build`).
fn move_up(
    file: &std::fs::File,
    from: u64,
    to: u64,
    len: u64,
    clock: &WriteClock,
) -> std::io::Result<()> {
    debug_assert!(to >= from);
    const STEP: u64 = 1 << 21;
    let mut buf = vec![0u8; STEP.min(len) as usize];
    let mut end = len;
    while end > 0 {
        let n = STEP.min(end);
        let chunk = &mut buf[..n as usize];
        read_at(file, chunk, from + end - n)?;
        clock.write_at(file, chunk, to + end - n)?;
        end -= n;
    }
    let stale = (to - from).min(len);
    if stale > 0 {
        buf.clear();
        buf.resize(STEP.min(stale) as usize, 0);
        let mut at = 0;
        while at < stale {
            let n = STEP.min(stale - at);
            clock.write_at(file, &buf[..n as usize], from + at)?;
            at += n;
        }
    }
    Ok(())
}

/// Reads `buf.len()` bytes at `offset` of `file`.
fn read_at(file: &std::fs::File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    #[cfg(unix)]
    {
        std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
    }
    #[cfg(windows)]
    {
        let (mut buf, mut offset) = (buf, offset);
        while !buf.is_empty() {
            match std::os::windows::fs::FileExt::seek_read(file, buf, offset)? {
                0 => return Err(std::io::ErrorKind::UnexpectedEof.into()),
                n => {
                    buf = &mut buf[n..];
                    offset += n as u64;
                }
            }
        }
        Ok(())
    }
    #[cfg(not(any(unix, windows)))]
    {
        let _ = (file, buf, offset);
        Err(std::io::Error::new(
            std::io::ErrorKind::Unsupported,
            "positioned reads are not available on this platform",
        ))
    }
}

/// Reserves the disk blocks of bytes `from..size` of a new `size`-byte
/// `file` before they are written, on ext4 and XFS only (`fallocate`);
/// anywhere else, or if the call fails, the writes allocate as they go, as
/// without it.
///
/// Why: with no blocks behind it, every 4 KiB block a buffered write covers
/// is reserved one by one (ext4's delayed allocation); with the blocks
/// reserved in one call, the writes only look them up. Copying 128 MiB into
/// the page cache here, 1 MiB per write: 21.2–21.4 → 18.9–19.5 ms (the call
/// included; fastest of 5, two runs of `examples/file_write.rs`); the
/// dragon's layout + write, 39.8 → 38.0 ms with one thread and 25.1 → 22.9
/// ms with two (`benches/compare_binaries.py`, 7 rounds). Only these two
/// filesystems: on tmpfs, for one, `fallocate` zeroes pages that the
/// writes then overwrite. The reserved blocks are "unwritten" until written
/// back, which the kernel does later, outside the build.
fn preallocate(file: &std::fs::File, from: u64, size: u64) {
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::io::AsRawFd;
        const EXT4: i64 = 0xEF53;
        const XFS: i64 = 0x5846_5342;
        let fd = file.as_raw_fd();
        // SAFETY: `statfs` is plain data that `fstatfs` fills; `fd` is an
        // open descriptor for the duration of both calls.
        unsafe {
            let mut st: libc::statfs = std::mem::zeroed();
            if libc::fstatfs(fd, &mut st) != 0 || !matches!(st.f_type as i64, EXT4 | XFS) {
                return;
            }
            // Mode 0 (allocate, may extend): the size is already `size`.
            // A failure (no space for the reservation, an old kernel) is
            // left to the writes, which report it if it is real.
            if size > from {
                let _ = libc::fallocate(fd, 0, from as libc::off_t, (size - from) as libc::off_t);
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = (file, from, size);
}

/// Writes a one-mesh uncompressed file to `path` atomically, filling the
/// payload unit by unit straight into the file instead of from buffers in
/// memory: the same bytes as [`write_file`] of the whole buffers.
///
/// Why: the buffers are the largest allocation of a build (144 bytes per
/// triangle), and filling fresh memory costs page faults and zeroing before
/// the bytes are even copied to the file. Here each thread fills one unit at
/// a time into a buffer it reuses, which stays in cache, hashes it and
/// writes it at its precomputed offset (`pwrite`); the units' CRCs are
/// combined in file order, so the file is the same whatever the thread count.
/// The header, which holds the CRC, is written last, at the start.
pub fn write_file_streamed(
    path: &Path,
    header: Header,
    mesh: MeshHeader,
    source: &dyn PayloadSource,
) -> Result<Written> {
    let input = (header.input.bytes, header.input.sha256);
    write_file_streamed_finishing(path, header, mesh, source, None, &|| false, move || input)
}

/// One unit's piece of one section written ahead ([`AheadFile`]): the
/// unit, the section, where it went, its byte length and CRC.
struct Piece {
    unit: usize,
    section: usize,
    at: u64,
    len: u64,
    crc: crc32fast::Hasher,
}

/// The temp file that will become the output, with units of its payload
/// written before the whole payload is known ([`AheadFile::new`]), at the
/// offsets a file with header room ([`header_room`]) puts them: the caps
/// while the edges are being made (with one thread, from the soup before
/// they are made; with two and a mesh with open edges, by both threads
/// after the topology's first pass, [`AheadFile::write_shared`]), and
/// side blocks while the rest of the edges are.
/// [`write_file_streamed_finishing`] keeps every piece that went where
/// the final file puts it, moves up within the file those that went lower
/// (the header outgrew its room), and writes the others again.
///
/// Why: on ext4, writes into one file take the file's lock in turn, so the
/// copy into the page cache is serial: with two threads, the write stage
/// was one thread copying the whole output while the other filled units
/// and then waited. Copying the caps (a third of the dragon's output)
/// while the other thread makes the edges takes them off that serial path
/// (benches/ROUNDS.md, "Eighteenth round"), and the sides' blocks copied
/// as the edges are finished take most of the rest ("Nineteenth round").
pub struct AheadFile {
    tmp: tempfile::NamedTempFile,
    path: std::path::PathBuf,
    enc: Encoding,
    caps_offset: u64,
    sides_offset: u64,
    pieces: std::sync::Mutex<Vec<Piece>>,
    /// The writing threads' turns.
    turns: WriteTurns,
    /// Held while the file's length changes.
    resizing: std::sync::Mutex<()>,
}

/// A thread's buffers for [`AheadFile::write`], reused from call to call.
pub struct UnitBuffers((Vec<f32>, Vec<u8>));

impl UnitBuffers {
    /// Buffers for units of up to `floats` floats (larger ones grow them).
    pub fn new(floats: usize) -> Self {
        UnitBuffers(unit_buffers(floats))
    }
}

/// The pieces of an [`AheadFile`], for the writer that finishes it.
pub struct WrittenAhead {
    tmp: tempfile::NamedTempFile,
    pieces: Vec<Piece>,
    /// The writes' time and bytes ([`Written::write_calls`],
    /// [`Written::write_bytes`]).
    write_calls: (std::time::Duration, u64),
}

impl AheadFile {
    /// A new temp file beside `path` for a one-mesh file with `header` and
    /// `mesh`, of which only the name and `stats.triangles` are used: the
    /// file is placed as one with header room, whose payload starts at the
    /// same offset whatever its edges.
    pub fn new(path: &Path, mut header: Header, mesh: MeshHeader) -> Result<AheadFile> {
        let enc = header.options.encoding().map_err(Error::Other)?;
        let mut floats = vec![0u64; 1 + mesh.buckets.len()];
        floats[0] = mesh.stats.triangles * 12;
        header.meshes = vec![mesh];
        place_sections(&mut header, std::slice::from_ref(&floats))?;
        let caps = header.meshes[0].caps;
        Ok(AheadFile {
            tmp: temp_beside(path)?,
            path: path.to_path_buf(),
            enc,
            caps_offset: caps.offset,
            // Where the first bucket starts: right after the caps.
            sides_offset: align_up(caps.offset + caps.length),
            pieces: Default::default(),
            turns: Default::default(),
            resizing: Default::default(),
        })
    }

    /// Where the caps start.
    pub fn caps_offset(&self) -> u64 {
        self.caps_offset
    }

    /// Where the first side bucket starts, whatever its k.
    pub fn sides_offset(&self) -> u64 {
        self.sides_offset
    }

    /// Bytes per vec4 of the file's encoding.
    pub fn vec4_bytes(&self) -> u64 {
        self.enc.vec4_bytes()
    }

    /// Makes the file at least `end` bytes long and reserves the blocks of
    /// bytes `from..end` (`fallocate` on ext4 and XFS), as the finishing writer does for
    /// the rest. Why: writes into reserved blocks only look them up.
    pub fn reserve(&self, from: u64, end: u64) -> Result<()> {
        let _one = self.resizing.lock().unwrap_or_else(|e| e.into_inner());
        let file = self.tmp.as_file();
        let io = |e| Error::io(&self.path, e);
        if file.metadata().map_err(io)?.len() < end {
            file.set_len(end).map_err(io)?;
        }
        preallocate(file, from, end);
        Ok(())
    }

    /// Writes every unit of `source`, a payload of one section, one after
    /// the other from byte `at`, on the calling thread with its `bufs`, as
    /// units `first_unit..` of section `section` of the final payload. A
    /// thread that finds another writing does `side` work meanwhile (as
    /// [`write_file_streamed_finishing`] does).
    pub fn write(
        &self,
        source: &dyn PayloadSource,
        first_unit: usize,
        section: usize,
        at: u64,
        bufs: &mut UnitBuffers,
        side: &dyn Fn() -> bool,
    ) -> Result<()> {
        let next = std::sync::atomic::AtomicUsize::new(0);
        self.write_shared(source, first_unit, section, at, &next, bufs, side)
    }

    /// [`AheadFile::write`] by several threads at once: each call takes the
    /// units of `source` one at a time, the next not yet taken (counted
    /// by `next`, from 0), and returns when none is left; each unit goes
    /// where [`AheadFile::write`] puts it. Why: a thread that would wait
    /// for the other's copy helps with it (`build::build_file`).
    #[allow(clippy::too_many_arguments)]
    pub fn write_shared(
        &self,
        source: &dyn PayloadSource,
        first_unit: usize,
        section: usize,
        at: u64,
        next: &std::sync::atomic::AtomicUsize,
        bufs: &mut UnitBuffers,
        side: &dyn Fn() -> bool,
    ) -> Result<()> {
        let per_float = self.enc.vec4_bytes() / 4;
        let file = self.tmp.as_file();
        let write = |bytes: &[u8], offset: u64| self.turns.write(file, bytes, offset, side);
        let mut pieces = Vec::new();
        // Unit `past`'s offset is `at`: units are taken in increasing
        // order, so each thread's offsets are running sums.
        let (mut past, mut at) = (0, at);
        loop {
            let u = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            if u >= source.units() {
                break;
            }
            while past < u {
                at += source.floats(past, 0) as u64 * per_float;
                past += 1;
            }
            let len = source.floats(u, 0) as u64 * per_float;
            let mut crc = write_unit(source, u, 1, self.enc, &[at], &mut bufs.0, &write)
                .map_err(|e| Error::io(&self.path, e))?;
            pieces.push(Piece {
                unit: first_unit + u,
                section,
                at,
                len,
                crc: crc.pop().unwrap_or_default(),
            });
            (past, at) = (u + 1, at + len);
        }
        self.pieces
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .extend(pieces);
        Ok(())
    }

    /// The file and what was written into it (in no particular order).
    pub fn finish(self) -> WrittenAhead {
        WrittenAhead {
            tmp: self.tmp,
            pieces: self.pieces.into_inner().unwrap_or_else(|e| e.into_inner()),
            write_calls: self.turns.clock.spent(),
        }
    }
}

/// A thread's buffers for [`write_unit`]: the floats, large enough for
/// `widest` (rounded up to a large block, `alloc::large_capacity`, since
/// the dragon's units of 0.8–1 MB took fresh 4 KiB pages, 2 MiB of them
/// with one thread), and the bytes of an encoding other than f32.
fn unit_buffers(widest: usize) -> (Vec<f32>, Vec<u8>) {
    (
        Vec::with_capacity(crate::alloc::large_capacity::<f32>(widest)),
        Vec::new(),
    )
}

/// Fills unit `u` of `source` (`sections` sections) into the buffers and
/// writes each non-empty piece with `write` at `starts[s]`; returns the
/// pieces' CRCs.
fn write_unit(
    source: &dyn PayloadSource,
    u: usize,
    sections: usize,
    enc: Encoding,
    starts: &[u64],
    (fbuf, bbuf): &mut (Vec<f32>, Vec<u8>),
    write: &dyn Fn(&[u8], u64) -> std::io::Result<()>,
) -> std::io::Result<Vec<crc32fast::Hasher>> {
    let per_float = enc.vec4_bytes() / 4;
    let lens: Vec<usize> = (0..sections).map(|s| source.floats(u, s)).collect();
    // Not zeroed first: `fill` writes every float (which debug builds
    // check with a sentinel). Zeroing was a memset of the whole output,
    // 125 MB on the dragon.
    let total = lens.iter().sum();
    if fbuf.len() < total {
        fbuf.resize(total, 0.0);
    }
    let fbuf = &mut fbuf[..total];
    if cfg!(debug_assertions) {
        fbuf.fill(f32::from_bits(UNWRITTEN));
    }
    let mut outs = split_pieces(fbuf, &lens);
    let fill = crate::trace::span_n("fill", u as u64);
    source.fill(u, &mut outs);
    fill.end();
    debug_assert!(
        fbuf.iter().all(|f| f.to_bits() != UNWRITTEN),
        "unit {u}: the payload source left floats unwritten"
    );
    let mut hashes = Vec::with_capacity(sections);
    let mut at = 0;
    for (s, &n) in lens.iter().enumerate() {
        let piece = &fbuf[at..at + n];
        at += n;
        let crc = crate::trace::span_n("encode and checksum", u as u64);
        let bytes: &[u8] = if enc == Encoding::F32 && cfg!(target_endian = "little") {
            bytemuck::cast_slice(piece)
        } else {
            bbuf.resize(n * per_float as usize, 0);
            let len = encode_floats(piece, enc, bbuf);
            &bbuf[..len]
        };
        let mut h = crc32fast::Hasher::new();
        h.update(bytes);
        crc.end();
        if !bytes.is_empty() {
            write(bytes, starts[s])?;
        }
        hashes.push(h);
    }
    Ok(hashes)
}

/// [`write_file_streamed`], with the first units of the payload already
/// written when `ahead` has them at the offsets this file puts them (or
/// lower, by a header that outgrew its room: then they are moved up; else
/// they are discarded and written again), the header's input byte count
/// and SHA-256 given by `input` once the payload is written, and `side`
/// called, a slice
/// of work at a time, by a thread about to write while another is writing:
/// how a build finishes a digest its load left pending
/// (`load::DigestSlices`). `side` returns false once it has nothing left.
///
/// Why: buffered writes to one file take its lock in turn (on ext4, two
/// threads writing halves of one file take as long as one thread, two
/// files half as long; `examples/file_write.rs`), so with two threads one
/// copies while the other fills the next unit and then waits, about a
/// third of the write stage: hashing there costs the build almost nothing,
/// where the load waited for it. (The hashing as one task beside the
/// payload, `rayon::join`, made the dragon's write stage 3 ms longer:
/// the other thread then filled and copied alone.)
pub fn write_file_streamed_finishing(
    path: &Path,
    mut header: Header,
    mesh: MeshHeader,
    source: &dyn PayloadSource,
    ahead: Option<WrittenAhead>,
    side: &(dyn Fn() -> bool + Sync),
    input: impl FnOnce() -> (u64, [u8; 32]),
) -> Result<Written> {
    use rayon::prelude::*;
    let enc = header.options.encoding().map_err(Error::Other)?;
    let per_float = enc.vec4_bytes() / 4;
    let sections = 1 + mesh.buckets.len();
    let units = source.units();
    let mut floats = vec![0u64; sections];
    for u in 0..units {
        for (s, f) in floats.iter_mut().enumerate() {
            *f += source.floats(u, s) as u64;
        }
    }
    header.meshes = vec![mesh];
    let probe_len = place_sections(&mut header, std::slice::from_ref(&floats))?;
    let m = &header.meshes[0];
    // Where each unit's piece of each section starts in the file.
    let mut next: Vec<u64> = std::iter::once(m.caps.offset)
        .chain(m.buckets.iter().map(|b| b.offset))
        .collect();
    let mut starts = vec![0u64; units * sections];
    for u in 0..units {
        for s in 0..sections {
            starts[u * sections + s] = next[s];
            next[s] += source.floats(u, s) as u64 * per_float;
        }
    }

    // The pieces written ahead that went exactly where this file puts them
    // (a unit's only non-empty piece, at its offset and length); a unit is
    // written here unless it has one. A piece of the right unit, section
    // and length that went lower in the file than this file puts it
    // (because the header outgrew its room, see `header_room`, which moves
    // every section up) is moved up to its place within the file. Anything
    // else written elsewhere is cut off the file first (from the lowest
    // such byte on, with every piece past it), so that no stale byte stays
    // in a gap the writer leaves as zeros.
    let size = container_len(&header);
    // Per unit written ahead, its piece's section and CRC.
    let mut done: Vec<Option<(usize, crc32fast::Hasher)>> = (0..units).map(|_| None).collect();
    // This writer's writes (the moves, the units, the header), after those
    // of the file written ahead.
    let turns = WriteTurns::default();
    let (ahead_time, ahead_bytes) = ahead.as_ref().map_or(Default::default(), |a| a.write_calls);
    let (tmp, from) = match ahead {
        Some(a) => {
            // Where this file puts the piece, if it holds a whole unit.
            let place = |p: &Piece| {
                (p.unit < units
                    && p.section < sections
                    && source.floats(p.unit, p.section) as u64 * per_float == p.len
                    && (0..sections).all(|s| s == p.section || source.floats(p.unit, s) == 0))
                .then(|| starts[p.unit * sections + p.section])
            };
            let cut = a
                .pieces
                .iter()
                .filter(|p| place(p).is_none_or(|at| at < p.at))
                .map(|p| p.at)
                .min()
                .unwrap_or(u64::MAX);
            if cut != u64::MAX {
                a.tmp
                    .as_file()
                    .set_len(cut)
                    .map_err(|e| Error::io(path, e))?;
            }
            let mut kept: Vec<(Piece, u64)> = a
                .pieces
                .into_iter()
                .filter_map(|p| place(&p).map(|at| (p, at)))
                // (A piece placed lower than it went is empty, or past
                // the cut: written again either way.)
                .filter(|(p, at)| *at >= p.at && p.at + p.len <= cut)
                .collect();
            // Highest first: each piece then moves into bytes no piece
            // still to move is read from (see `move_up`).
            kept.sort_by_key(|(p, _)| std::cmp::Reverse(p.at));
            let mut from = 0;
            for (p, at) in kept {
                if done[p.unit].is_some() {
                    continue;
                }
                if at != p.at {
                    move_up(a.tmp.as_file(), p.at, at, p.len, &turns.clock)
                        .map_err(|e| Error::io(path, e))?;
                }
                from = from.max(at + p.len);
                done[p.unit] = Some((p.section, p.crc));
            }
            (a.tmp, from)
        }
        None => (temp_beside(path)?, 0),
    };
    if let Some(u) = (0..units).find(|&u| done[u].is_none() && !source.can_fill(u)) {
        return Err(Error::Other(format!(
            "internal error: unit {u} of the payload was not written ahead and cannot be filled again"
        )));
    }
    let file = tmp.as_file();
    file.set_len(size).map_err(|e| Error::io(path, e))?;
    preallocate(file, from, size);
    // Each thread's fill buffer holds the largest unit.
    let widest = (0..units)
        .filter(|&u| done[u].is_none())
        .map(|u| (0..sections).map(|s| source.floats(u, s)).sum::<usize>())
        .max()
        .unwrap_or(0);
    let write = |bytes: &[u8], offset: u64| turns.write(file, bytes, offset, side);
    // Per unit, its pieces' CRCs (a unit written ahead has its one piece's,
    // in its section's place).
    let crcs: Vec<Vec<crc32fast::Hasher>> = done
        .into_par_iter()
        .enumerate()
        .map_init(
            || unit_buffers(widest),
            |bufs, (u, done)| match done {
                Some((s, crc)) => {
                    let mut hashes = vec![crc32fast::Hasher::new(); s];
                    hashes.push(crc);
                    Ok(hashes)
                }
                None => {
                    let starts = &starts[u * sections..(u + 1) * sections];
                    write_unit(source, u, sections, enc, starts, bufs, &write)
                        .map_err(|e| Error::io(path, e))
                }
            },
        )
        .collect::<Result<Vec<_>>>()?;
    (header.input.bytes, header.input.sha256) = input();
    // The payload's CRC: every section's pieces in unit order, then the
    // section's zero padding (as `write_records` writes it).
    let mut crc = crc32fast::Hasher::new();
    for (s, &f) in floats.iter().enumerate() {
        // (A unit written ahead has CRCs up to its one section only.)
        for unit in crcs.iter().filter_map(|u| u.get(s)) {
            crc.combine(unit);
        }
        let bytes = f * per_float;
        crc.update(&[0u8; 16][..(align_up(bytes) - bytes) as usize]);
    }
    header.payload_crc32 = crc.finalize();
    let hbytes = encode_header(&header)?;
    if hbytes.len() != probe_len {
        return Err(Error::Other(
            "header length changed after placing sections".into(),
        ));
    }
    let clock = &turns.clock;
    clock
        .write_at(file, &preamble(&hbytes), 0)
        .map_err(|e| Error::io(path, e))?;
    clock
        .write_at(file, &hbytes, PREAMBLE_LEN as u64)
        .map_err(|e| Error::io(path, e))?;
    persist(tmp, path)?;
    let (time, bytes) = clock.spent();
    Ok(Written {
        header,
        bytes: size,
        write_calls: ahead_time + time,
        write_bytes: ahead_bytes + bytes,
    })
}

fn with_path(e: Error, path: &Path) -> Error {
    match e {
        Error::Other(msg) => Error::input(path, msg),
        e => e,
    }
}

/// A file read back into memory.
#[derive(Debug, Clone)]
pub struct SvpkFile {
    /// The decoded header.
    pub header: Header,
    /// Version minor found in the file.
    pub version_minor: u16,
    /// The uncompressed container bytes.
    pub bytes: FileBytes,
    /// Whether the file on disk was zstd-wrapped.
    pub compressed: bool,
    /// Size of the file on disk.
    pub file_bytes: u64,
}

impl SvpkFile {
    /// The file's position encoding (validated when the file was read).
    pub fn encoding(&self) -> Encoding {
        self.header.options.encoding().unwrap_or_default()
    }

    /// A section's vec4s as record-space floats. Unorm16 `xyz` become
    /// `c / 65535`, `w` the stored integer.
    ///
    /// f32 sections of a mapped file ([`FileBytes::Mapped`]) are views into
    /// the mapping, which are f32-aligned there (sections start at multiples
    /// of 16 bytes, the mapping at a page); anything else is converted into
    /// a buffer of its own (a `Vec<u8>`'s bytes need not be f32-aligned).
    pub fn floats(&self, offset: u64, length: u64) -> Floats {
        let (start, end) = (offset as usize, (offset + length) as usize);
        if let FileBytes::Mapped(map) = &self.bytes
            && self.encoding() == Encoding::F32
            && cfg!(target_endian = "little")
            && bytemuck::try_cast_slice::<u8, f32>(&map[start..end]).is_ok()
        {
            return Floats(FloatsRepr::Mapped {
                map: map.clone(),
                start,
                end,
            });
        }
        let bytes = &self.bytes[start..end];
        Floats(FloatsRepr::Owned(match self.encoding() {
            Encoding::F32 => bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
            Encoding::Unorm16 => bytes
                .chunks_exact(2)
                .enumerate()
                .map(|(i, c)| {
                    let v = u16::from_le_bytes([c[0], c[1]]);
                    if i % 4 == 3 {
                        v as f32
                    } else {
                        unorm16_to_f32(v)
                    }
                })
                .collect(),
        }))
    }
}

pub use crate::file_bytes::{FileBytes, MAP_MIN};

/// A section's record-space floats ([`SvpkFile::floats`]): a view into a
/// mapped file, or floats of their own. Derefs to `[f32]`.
#[derive(Clone)]
pub struct Floats(FloatsRepr);

#[derive(Clone)]
enum FloatsRepr {
    Owned(Vec<f32>),
    /// Bytes `start..end` of the mapping, f32-aligned (checked when made).
    Mapped {
        map: std::sync::Arc<memmap2::Mmap>,
        start: usize,
        end: usize,
    },
}

impl std::ops::Deref for Floats {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        match &self.0 {
            FloatsRepr::Owned(v) => v,
            FloatsRepr::Mapped { map, start, end } => bytemuck::cast_slice(&map[*start..*end]),
        }
    }
}

impl From<Vec<f32>> for Floats {
    fn from(v: Vec<f32>) -> Self {
        Floats(FloatsRepr::Owned(v))
    }
}

impl std::fmt::Debug for Floats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let kind = match self.0 {
            FloatsRepr::Owned(_) => "owned",
            FloatsRepr::Mapped { .. } => "mapped",
        };
        write!(f, "Floats({} floats, {kind})", self.len())
    }
}

/// Reads and fully validates a file from disk.
///
/// Uncompressed files of at least [`MAP_MIN`] bytes are mapped read-only
/// ([`FileBytes::Mapped`], see [`crate::file_bytes`] for the contract), and
/// [`SvpkFile::floats`] returns views of their f32 sections instead of
/// copying them: the dragon's 125 MB output read and checked in 21–22 ms
/// against 51–365 ms read (benches/ROUNDS.md, "Eighth round").
pub fn read_file(path: &Path) -> Result<SvpkFile> {
    let bytes = crate::file_bytes::read_or_map(path).map_err(|e| Error::io(path, e))?;
    match bytes {
        // A compressed file is decompressed straight from the mapping.
        FileBytes::Mapped(map) if map.starts_with(&ZSTD_MAGIC) => {
            let bytes = FileBytes::Read(decompress(path, &map)?);
            decode_bytes(path, bytes, map.len() as u64, true)
        }
        FileBytes::Mapped(map) => {
            let len = map.len() as u64;
            decode_bytes(path, FileBytes::Mapped(map), len, false)
        }
        FileBytes::Read(data) => decode(path, data),
    }
}

/// Validates and decodes file bytes (`path` is only used in messages).
pub fn decode(path: &Path, data: Vec<u8>) -> Result<SvpkFile> {
    let file_bytes = data.len() as u64;
    if data.starts_with(&ZSTD_MAGIC) {
        let bytes = FileBytes::Read(decompress(path, &data)?);
        decode_bytes(path, bytes, file_bytes, true)
    } else {
        decode_bytes(path, FileBytes::Read(data), file_bytes, false)
    }
}

/// [`decode`] of the container `bytes` (decompressed already when the file
/// on disk, `file_bytes` long, was `compressed`).
fn decode_bytes(
    path: &Path,
    bytes: FileBytes,
    file_bytes: u64,
    compressed: bool,
) -> Result<SvpkFile> {
    let err = |msg: String| Error::input(path, msg);
    if bytes.len() < PREAMBLE_LEN {
        return Err(err(format!(
            "truncated file: {} bytes, shorter than the {PREAMBLE_LEN}-byte preamble",
            bytes.len()
        )));
    }
    if bytes[0..8] != MAGIC {
        return Err(err("not an svpack file (bad magic)".into()));
    }
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at =
        |o: usize| u32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let (major, minor) = (u16_at(8), u16_at(10));
    if major != VERSION_MAJOR {
        return Err(err(format!(
            "unsupported format version {major}.{minor} (this svpack reads {VERSION_MAJOR}.x{})",
            if major < VERSION_MAJOR {
                "; rebuild the file from its source with this svpack"
            } else {
                "; a newer svpack wrote it"
            }
        )));
    }
    let header_len = u32_at(12) as usize;
    if header_len > HEADER_LIMIT {
        return Err(err(format!(
            "header length {header_len} exceeds the {HEADER_LIMIT}-byte limit"
        )));
    }
    if PREAMBLE_LEN + header_len > bytes.len() {
        return Err(err(format!(
            "truncated file: header needs {} bytes, file has {}",
            PREAMBLE_LEN + header_len,
            bytes.len()
        )));
    }
    let hbytes = &bytes[PREAMBLE_LEN..PREAMBLE_LEN + header_len];
    if crc32fast::hash(hbytes) != u32_at(16) {
        return Err(err("header checksum mismatch (file corrupted)".into()));
    }
    let (mut header, mut used): (Header, usize) =
        bincode::serde::decode_from_slice(hbytes, bincode_config())
            .map_err(|e| err(format!("cannot decode header: {e}")))?;
    if minor >= 1 {
        // 2.1: the reserved room, a count and that many zeros.
        let rest = &hbytes[used..];
        let count = rest
            .get(..8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
            .ok_or_else(|| {
                err("cannot decode header: the reserved room's count is missing".into())
            })?;
        let zeros = usize::try_from(count)
            .ok()
            .and_then(|n| n.checked_add(8))
            .and_then(|end| rest.get(8..end))
            .ok_or_else(|| {
                err(format!(
                    "cannot decode header: {count} reserved bytes, only {} left",
                    rest.len() - 8
                ))
            })?;
        if zeros.iter().any(|&b| b != 0) {
            return Err(err("header's reserved room is not zero".into()));
        }
        header.reserved = count;
        used += 8 + zeros.len();
    }
    // Same major, newer minor: trailing header fields we do not know are fine.
    let newer_minor = minor > VERSION_MINOR;
    if used != header_len && !newer_minor {
        return Err(err(format!(
            "header has {} trailing bytes",
            header_len - used
        )));
    }
    validate_layout(&header, header_len, bytes.len() as u64).map_err(err)?;
    let payload = &bytes[header.payload_offset as usize..];
    if crc32fast::hash(payload) != header.payload_crc32 {
        return Err(err("payload checksum mismatch (file corrupted)".into()));
    }
    Ok(SvpkFile {
        header,
        version_minor: minor,
        bytes,
        compressed,
        file_bytes,
    })
}

fn decompress(path: &Path, data: &[u8]) -> Result<Vec<u8>> {
    use std::io::Read;
    let dec =
        zstd::stream::Decoder::new(data).map_err(|e| Error::input(path, format!("zstd: {e}")))?;
    let mut out = Vec::new();
    dec.take(DECOMPRESSED_LIMIT + 1)
        .read_to_end(&mut out)
        .map_err(|e| Error::input(path, format!("corrupt zstd stream: {e}")))?;
    if out.len() as u64 > DECOMPRESSED_LIMIT {
        return Err(Error::input(
            path,
            format!("decompressed size exceeds the {DECOMPRESSED_LIMIT}-byte limit"),
        ));
    }
    Ok(out)
}

/// Checks that sections tile the payload exactly, in order, with the sizes their
/// counts imply.
fn validate_layout(
    h: &Header,
    header_len: usize,
    file_len: u64,
) -> std::result::Result<(), String> {
    let expect_payload = align_up((PREAMBLE_LEN + header_len) as u64);
    if h.payload_offset != expect_payload {
        return Err(format!(
            "payload offset {} should be {expect_payload}",
            h.payload_offset
        ));
    }
    let end = h
        .payload_offset
        .checked_add(h.payload_len)
        .ok_or("payload length overflows")?;
    if end != file_len {
        return Err(if end > file_len {
            format!("truncated file: payload ends at byte {end}, file has {file_len}")
        } else {
            format!("{} unexpected bytes after the payload", file_len - end)
        });
    }
    if h.options.max_mult == 0 || h.options.max_mult > crate::layout::MAX_MAX_MULT {
        return Err(format!("max_mult {} out of range", h.options.max_mult));
    }
    let vec4 = h.options.encoding()?.vec4_bytes();
    let mut at = h.payload_offset;
    for (mi, m) in h.meshes.iter().enumerate() {
        if !m
            .position_scale
            .iter()
            .chain(&m.position_offset)
            .all(|v| v.is_finite())
            || m.position_scale.iter().any(|&v| v <= 0.0)
        {
            return Err(format!(
                "mesh {mi}: position transform offset {:?} scale {:?} is invalid (finite, scale > 0)",
                m.position_offset, m.position_scale
            ));
        }
        let caps_len = m
            .caps
            .count
            .checked_mul(3 * vec4)
            .ok_or("caps count overflows")?;
        if m.caps.offset != at || m.caps.length != caps_len {
            return Err(format!(
                "mesh {mi}: caps section at {}+{} should be at {at}+{caps_len}",
                m.caps.offset, m.caps.length
            ));
        }
        at = align_up(at.checked_add(caps_len).ok_or("section offsets overflow")?);
        let mut last_k = 0;
        for b in &m.buckets {
            if b.k <= last_k || b.k > h.options.max_mult || b.instances == 0 {
                return Err(format!(
                    "mesh {mi}: bucket k={} with {} instances is invalid (k must increase, be <= max_mult {}, and be non-empty)",
                    b.k, b.instances, h.options.max_mult
                ));
            }
            last_k = b.k;
            let len = b
                .instances
                .checked_mul(vec4 * (2 + b.k as u64))
                .ok_or("bucket size overflows")?;
            if b.offset != at || b.length != len {
                return Err(format!(
                    "mesh {mi}: bucket k={} at {}+{} should be at {at}+{len}",
                    b.k, b.offset, b.length
                ));
            }
            at = align_up(at.checked_add(len).ok_or("section offsets overflow")?);
        }
    }
    if at != end {
        return Err(format!("sections end at {at} but payload ends at {end}"));
    }
    Ok(())
}

/// The zstd encoder of a compressed file: `level`, one worker per thread
/// of the current rayon pool, [`ZSTD_JOB_BYTES`] jobs, and the content size
/// (`len`, which the stream must then be) in the frame header. Every frame
/// svpack writes or sizes comes from here, so that `inspect`'s size at a
/// level is the size `build --compress-level` writes.
fn zstd_encoder<W: Write>(
    w: W,
    level: i32,
    len: u64,
) -> std::io::Result<zstd::Encoder<'static, W>> {
    let mut enc = zstd::stream::Encoder::new(w, level)?;
    enc.multithread(zstd_workers())?;
    enc.set_parameter(zstd::zstd_safe::CParameter::JobSize(ZSTD_JOB_BYTES))?;
    enc.include_contentsize(true)?;
    enc.set_pledged_src_size(Some(len))?;
    Ok(enc)
}

/// The zstd frame `build --compress-level level` writes for the file read
/// as `file`, on the current rayon pool's threads: its container with the
/// header's `--compress` record set (and the header's checksum to match),
/// the one difference between a compressed build's container and a plain
/// one's, so the frame is byte for byte the one the build writes.
///
/// The record is set by changing its one byte in the file's own header
/// bytes, not by encoding the decoded header again: a file of an earlier
/// minor version (2.0 has no room count) would come out as this
/// version's, longer, and its offsets would no longer hold (`inspect`
/// then reported such a file's own size as its frame's).
pub fn compressed_frame(file: &SvpkFile, level: i32) -> Result<Vec<u8>> {
    let bytes = &file.bytes[..];
    let header_len = u32::from_le_bytes(bytes[12..16].try_into().expect("4 bytes")) as usize;
    let mut hbytes = bytes[PREAMBLE_LEN..PREAMBLE_LEN + header_len].to_vec();
    if !file.header.options.compress {
        // Where the record's byte is: the one byte two encodings differing
        // only in it differ by. The fields before it are the same in every
        // minor version (fields are only ever appended).
        let mut header = file.header.clone();
        let plain = encode_header(&header)?;
        header.options.compress = true;
        let set = encode_header(&header)?;
        let at = plain.iter().zip(&set).position(|(a, b)| a != b);
        match at {
            Some(at) if at < header_len && hbytes[at] == plain[at] => hbytes[at] = set[at],
            _ => {
                return Err(Error::Other(
                    "the header's --compress record is not where it should be".into(),
                ));
            }
        }
    }
    let io = |e: std::io::Error| Error::Other(format!("zstd: {e}"));
    // A frame is rarely above a third of its input here (`bench
    // --compression`); the vector grows if it is.
    let mut enc = zstd_encoder(
        Vec::with_capacity(bytes.len() / 3),
        level,
        bytes.len() as u64,
    )
    .map_err(io)?;
    // The file's own preamble (its minor version too), the header's
    // checksum redone.
    let mut pre = bytes[..PREAMBLE_LEN].to_vec();
    pre[16..20].copy_from_slice(&crc32fast::hash(&hbytes).to_le_bytes());
    enc.write_all(&pre).map_err(io)?;
    enc.write_all(&hbytes).map_err(io)?;
    enc.write_all(&bytes[PREAMBLE_LEN + header_len..])
        .map_err(io)?;
    enc.finish().map_err(io)
}

/// Bytes the file takes as the zstd frame `build --compress-level level`
/// writes ([`compressed_frame`]; its size on disk if it already is a frame,
/// whatever its level).
pub fn zstd_size(file: &SvpkFile, level: i32) -> u64 {
    if file.compressed {
        return file.file_bytes;
    }
    compressed_frame(file, level).map_or(file.file_bytes, |f| f.len() as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `preallocate` keeps a file's size and its zeros, and on ext4 or XFS
    /// (where svpack calls `fallocate`) gives it its blocks. Caught: a
    /// length past the size (the file grows), a wrong magic number (no
    /// blocks on this machine's ext4).
    #[cfg(target_os = "linux")]
    #[test]
    fn preallocation_reserves_blocks_without_changing_the_file() {
        use std::os::unix::fs::MetadataExt;
        use std::os::unix::io::AsRawFd;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.bin");
        let file = std::fs::File::create(&path).unwrap();
        let size = 3 << 20;
        file.set_len(size).unwrap();
        assert_eq!(
            file.metadata().unwrap().blocks(),
            0,
            "a sparse file to start"
        );
        preallocate(&file, 0, size);
        let meta = file.metadata().unwrap();
        assert_eq!(meta.len(), size);
        // SAFETY: plain data filled by `fstatfs` on an open descriptor.
        let fs = unsafe {
            let mut st: libc::statfs = std::mem::zeroed();
            assert_eq!(libc::fstatfs(file.as_raw_fd(), &mut st), 0);
            st.f_type as i64
        };
        if matches!(fs, 0xEF53 | 0x5846_5342) {
            assert!(meta.blocks() * 512 >= size, "{} blocks", meta.blocks());
        }
        drop(file);
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(bytes.len() as u64, size);
        assert!(bytes.iter().all(|&b| b == 0));
    }

    /// `persist` onto a directory fails like a rename (naming the path) and
    /// leaves the directory and its contents alone, with no temp file left;
    /// onto nothing and onto a regular file it puts the temp file's bytes
    /// at the path, and the replaced file lives on under its other links,
    /// also where the exchange fails (it falls back to the rename).
    /// Caught: an exchange tried without checking what is at the path
    /// (the directory ends up under the temp name).
    #[cfg(unix)]
    #[test]
    fn persist_replaces_files_whole_and_leaves_directories_alone() {
        let dir = tempfile::tempdir().unwrap();
        let put = |path: &Path, bytes: &[u8]| -> Result<()> {
            let mut tmp = temp_beside(path)?;
            tmp.write_all(bytes).unwrap();
            persist(tmp, path)
        };
        let names = || -> Vec<String> {
            let mut v: Vec<String> = std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            v.sort();
            v
        };
        let out = dir.path().join("o.svpk");
        put(&out, b"first").unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"first");
        std::fs::hard_link(&out, dir.path().join("link")).unwrap();
        put(&out, b"second").unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"second");
        assert_eq!(std::fs::read(dir.path().join("link")).unwrap(), b"first");

        // A filesystem without the exchange: the rename, same result.
        let mut tmp = temp_beside(&out).unwrap();
        tmp.write_all(b"third").unwrap();
        let refuse = |_: &Path, _: &Path| Err(std::io::ErrorKind::InvalidInput.into());
        persist_with(tmp, &out, refuse).unwrap();
        assert_eq!(std::fs::read(&out).unwrap(), b"third");
        assert_eq!(std::fs::read(dir.path().join("link")).unwrap(), b"first");

        let d = dir.path().join("d.svpk");
        std::fs::create_dir(&d).unwrap();
        std::fs::write(d.join("keep"), b"x").unwrap();
        let err = put(&d, b"fourth").unwrap_err().to_string();
        assert!(err.contains("d.svpk"), "{err}");
        assert!(d.join("keep").is_file());
        assert_eq!(names(), ["d.svpk", "link", "o.svpk"]);
    }

    #[test]
    fn parallel_crc_is_the_crc_of_the_written_bytes() {
        // Lengths around the parallel chunk size, in whole vec4s, both
        // encodings; values in [0, 1] so unorm16 codes vary.
        for floats in [
            0usize,
            4,
            12,
            (1 << 18) - 4,
            1 << 18,
            (1 << 18) + 8,
            3 * (1 << 18) + 44,
        ] {
            let data: Vec<f32> = (0..floats)
                .map(|i| ((i as u64 * 2_654_435_761) % 1000) as f32 / 999.0)
                .collect();
            for enc in [Encoding::F32, Encoding::Unorm16] {
                let mut bytes = Vec::new();
                write_records(&mut bytes, &data, enc).unwrap();
                assert_eq!(bytes.len() as u64 % ALIGN, 0);
                let mut h = crc32fast::Hasher::new();
                h.update(b"prefix");
                crc_records(&mut h, &data, enc);
                let mut want = crc32fast::Hasher::new();
                want.update(b"prefix");
                want.update(&bytes);
                assert_eq!(h.finalize(), want.finalize(), "{floats} floats, {enc:?}");
            }
        }
    }

    /// `move_up` puts a range's bytes at a higher offset, overlapping its
    /// old place or not, across several of its 2 MiB steps, and zeroes what
    /// is left of the old place below the new one; every other byte stays.
    /// Caught: the steps taken from the start (an overlapping move copies
    /// bytes it has already overwritten), and the stale bytes left.
    #[test]
    fn moving_a_range_up_keeps_its_bytes_and_zeroes_what_it_leaves() {
        let len = (5 << 20) + 3;
        let size = 3 * len;
        let data: Vec<u8> = (0..size as u64)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8 | 1)
            .collect();
        for (from, to) in [
            (100, 107),
            (100, 100 + len / 2),
            (100, 100 + 2 * len),
            (64, 64),
        ] {
            let mut tmp = tempfile::NamedTempFile::new().unwrap();
            tmp.write_all(&data).unwrap();
            move_up(
                tmp.as_file(),
                from as u64,
                to as u64,
                len as u64,
                &WriteClock::default(),
            )
            .unwrap();
            let got = std::fs::read(tmp.path()).unwrap();
            let mut want = data.clone();
            want.resize(want.len().max(to + len), 0);
            want.copy_within(from..from + len, to);
            want[from..to.min(from + len)].fill(0);
            assert_eq!(got.len(), want.len(), "{from} -> {to}");
            let first = got.iter().zip(&want).position(|(a, b)| a != b);
            assert_eq!(first, None, "{from} -> {to}: first wrong byte");
        }
    }

    /// A unit that was not written ahead and that its source cannot fill
    /// again is an error, not a panic or a file with a hole. Caught: the
    /// check left out (the source below panics when asked to fill).
    #[test]
    fn a_unit_no_one_can_fill_is_an_error() {
        struct Freed;
        impl PayloadSource for Freed {
            fn units(&self) -> usize {
                2
            }
            fn floats(&self, _: usize, section: usize) -> usize {
                if section == 0 { 12 } else { 0 }
            }
            fn fill(&self, unit: usize, outs: &mut [&mut [f32]]) {
                assert!(unit != 1, "unit 1's input was freed");
                outs[0].fill(1.0);
            }
            fn can_fill(&self, unit: usize) -> bool {
                unit != 1
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("f.svpk");
        let (header, mesh) = empty_headers();
        let err =
            write_file_streamed_finishing(&out, header, mesh, &Freed, None, &|| false, || {
                (0, [0; 32])
            })
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("unit 1") && err.contains("cannot be filled"),
            "{err}"
        );
        assert!(!out.exists(), "no output");
    }

    /// A file header with no mesh and a mesh header with nothing in it,
    /// for f32 positions.
    fn empty_headers() -> (Header, MeshHeader) {
        let header = Header {
            payload_offset: 0,
            payload_len: 0,
            payload_crc32: 0,
            generator: "test".into(),
            input: InputInfo {
                file_name: "f.obj".into(),
                format: "obj".into(),
                bytes: 0,
                sha256: [0; 32],
            },
            options: BuildOptions {
                max_mult: 5,
                compress: false,
                positions: Encoding::F32.code(),
            },
            bounds_min: [0.0; 3],
            bounds_max: [0.0; 3],
            meshes: Vec::new(),
            reserved: 0,
        };
        let mesh = MeshHeader {
            name: "f".into(),
            bounds_min: [0.0; 3],
            bounds_max: [0.0; 3],
            position_offset: [0.0; 3],
            position_scale: [1.0; 3],
            stats: MeshStats::default(),
            caps: Section {
                offset: 0,
                length: 0,
                count: 0,
            },
            buckets: Vec::new(),
        };
        (header, mesh)
    }

    /// `AheadFile::write_shared`: units taken by several calls, in any
    /// split, go where one `write` puts them, with the same pieces.
    /// Caught: each call's offsets counted from its first unit taken as if
    /// it were unit 0 (the split calls wrote units 3.. over units 0..), a
    /// unit's own length left out of the running offset, and units taken
    /// twice (the counter read and then stepped apart: the pieces
    /// differed).
    #[test]
    fn units_shared_by_calls_land_where_one_writer_puts_them() {
        /// Units of 1 to 7 triangles (12 floats each), unit `u`'s floats
        /// `u` plus their place; `units` of them.
        struct Steps(usize);
        impl PayloadSource for Steps {
            fn units(&self) -> usize {
                self.0
            }
            fn floats(&self, unit: usize, section: usize) -> usize {
                if section == 0 { 12 * (unit + 1) } else { 0 }
            }
            fn fill(&self, unit: usize, outs: &mut [&mut [f32]]) {
                for (i, f) in outs[0].iter_mut().enumerate() {
                    *f = (100 * unit + i) as f32;
                }
                // Let the other thread take units in between.
                std::thread::sleep(std::time::Duration::from_micros(200));
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let (header, mut mesh) = empty_headers();
        mesh.stats.triangles = (1..=7).sum();
        let open = |name: &str| {
            AheadFile::new(&dir.path().join(name), header.clone(), mesh.clone()).unwrap()
        };
        // The file's bytes and its pieces (unit, offset, length, CRC).
        let written = |file: AheadFile| {
            let w = file.finish();
            let mut pieces: Vec<_> = w
                .pieces
                .iter()
                .map(|p| (p.unit, p.section, p.at, p.len, p.crc.clone().finalize()))
                .collect();
            pieces.sort_unstable();
            (std::fs::read(w.tmp.path()).unwrap(), pieces)
        };
        let mut bufs = UnitBuffers::new(12 * 7);
        let one = open("one.svpk");
        let at = one.caps_offset();
        one.write(&Steps(7), 5, 0, at, &mut bufs, &|| false)
            .unwrap();
        let want = written(one);
        assert_eq!(want.1.len(), 7);
        assert_eq!(want.1[6].0, 11, "units numbered from first_unit");

        // Units 3.. by one call, then 0..3 by another.
        let split = open("split.svpk");
        let next = std::sync::atomic::AtomicUsize::new(3);
        split
            .write_shared(&Steps(7), 5, 0, at, &next, &mut bufs, &|| false)
            .unwrap();
        let next = std::sync::atomic::AtomicUsize::new(0);
        split
            .write_shared(&Steps(3), 5, 0, at, &next, &mut bufs, &|| false)
            .unwrap();
        assert!(written(split) == want, "split calls");

        // Two threads at once.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let both = open("both.svpk");
        let next = std::sync::atomic::AtomicUsize::new(0);
        let call = || {
            let mut bufs = UnitBuffers::new(12 * 7);
            both.write_shared(&Steps(7), 5, 0, at, &next, &mut bufs, &|| false)
        };
        let (x, y) = pool.install(|| rayon::join(call, call));
        x.and(y).unwrap();
        assert!(written(both) == want, "two threads");
    }
}
