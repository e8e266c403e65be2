//! Loading: glTF 2.0 and OBJ files into one world-space triangle soup.
//!
//! Loaders only decode; they do not weld, drop degenerates or check for
//! NaN/Inf (the build step does that, and lint reports it). They do reject
//! structurally broken files (missing buffers, indices out of range, cycles in
//! the node graph, unknown versions) with an [`Error::Input`] naming the file.

pub mod gltf;
pub mod obj;

use crate::error::{Error, Result};
use crate::file_bytes::FileBytes;
use sha2::{Digest, Sha256};
use std::path::Path;

/// A named range of triangles in a [`Soup`] (one glTF primitive instance or one
/// OBJ object/group), so later stages can say where a finding comes from.
#[derive(Debug, Clone, PartialEq)]
pub struct Part {
    /// Human-readable origin, e.g. `node "Wheel.L" > mesh "Tire" > primitive 0`
    /// or `object "Cube"` (OBJ).
    pub name: String,
    /// First triangle of this part in [`Soup::indices`] (triangle index, not index-buffer offset).
    pub first_triangle: u32,
    /// Number of triangles in this part.
    pub triangle_count: u32,
}

/// Counters the loader reports besides the triangles.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LoadStats {
    /// Triangle primitives (glTF) or objects/groups (OBJ) read.
    pub primitives: u64,
    /// Primitives/elements skipped because they are points.
    pub skipped_points: u64,
    /// Primitives/elements skipped because they are lines.
    pub skipped_lines: u64,
    /// Non-fatal remarks worth showing the user (one line each).
    pub warnings: Vec<String>,
}

/// World-space triangle soup as loaded: `indices` holds 3 entries per
/// triangle, each an index into `positions`. Positions are f32, already
/// transformed by node world matrices (glTF) and possibly containing NaN/Inf.
#[derive(Debug, Clone, Default)]
pub struct Soup {
    /// Vertex positions (world space).
    pub positions: Vec<[f32; 3]>,
    /// Triangle corner indices into `positions`, 3 per triangle, in the input's winding.
    pub indices: Vec<u32>,
    /// Named triangle ranges, in order, covering all triangles.
    pub parts: Vec<Part>,
    /// Vertex positions the input declares (the header's `input_vertices`):
    /// OBJ `v` statements; glTF POSITION elements of the triangle
    /// primitives, once per instance (as many as `positions`). For OBJ,
    /// `positions` may hold more: the loader exports a vertex once per block
    /// of faces that uses it (welding merges the copies).
    pub input_vertices: u64,
    /// Loader counters.
    pub stats: LoadStats,
    /// Total bytes read from disk (main file plus external buffers).
    pub input_bytes: u64,
    /// SHA-256 over every byte read, in read order (main file first).
    pub input_sha256: [u8; 32],
}

impl Soup {
    /// Number of triangles.
    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }
}

/// Hashes and counts every byte a loader reads, so the output header can
/// record exactly which input it came from.
#[derive(Default)]
pub struct InputDigest {
    hasher: Sha256,
    bytes: u64,
}

impl InputDigest {
    /// Feed bytes that were read from an input file.
    pub fn update(&mut self, data: &[u8]) {
        self.hasher.update(data);
        self.bytes += data.len() as u64;
    }

    /// Bytes fed so far and the SHA-256 digest.
    pub fn finish(self) -> (u64, [u8; 32]) {
        (self.bytes, self.hasher.finalize().into())
    }

    /// Byte count and SHA-256 of `data` alone.
    pub fn of(data: &[u8]) -> (u64, [u8; 32]) {
        Self::of_parts([data])
    }

    /// Byte count and SHA-256 of `parts`, fed in order.
    pub fn of_parts<'a>(parts: impl IntoIterator<Item = &'a [u8]>) -> (u64, [u8; 32]) {
        let mut digest = Self::default();
        for part in parts {
            digest.update(part);
        }
        digest.finish()
    }
}

/// Inputs smaller than this are hashed on the calling thread: starting a
/// thread costs tens of microseconds, about what hashing this much takes.
const CONCURRENT_DIGEST_MIN: usize = 256 << 10;

/// Runs `work` on this thread while another thread computes the digest of
/// `parts` (fed in order, as if read one after the other), and returns both.
///
/// Why: hashing a large file costs a few percent of parsing it, and the two
/// are independent (`work` may read the same bytes). It only uses a second
/// thread when the rayon pool the caller runs in has more than one, so
/// `--threads 1` still means one core. The digest is the same either way.
pub fn digest_while<T>(parts: &[&[u8]], work: impl FnOnce() -> T) -> ((u64, [u8; 32]), T) {
    let hash = || {
        let _digest = crate::trace::span("digest");
        InputDigest::of_parts(parts.iter().copied())
    };
    let work = || {
        let _parse = crate::trace::span("parse");
        work()
    };
    let total: usize = parts.iter().map(|p| p.len()).sum();
    if total < CONCURRENT_DIGEST_MIN || rayon::current_num_threads() < 2 {
        return (hash(), work());
    }
    std::thread::scope(|scope| {
        let hasher = std::thread::Builder::new()
            .name("svpack-sha256".into())
            .spawn_scoped(scope, hash);
        let result = work();
        // If the thread could not be started (or died), hash here instead.
        let digest = match hasher.map(|h| h.join()) {
            Ok(Ok(digest)) => digest,
            _ => hash(),
        };
        (digest, result)
    })
}

/// The digest of an input's first part (the file itself), started on
/// another thread before the rest of what it covers is known, and
/// completed by [`DigestHead::finish_while`] or stopped part way by
/// [`DigestHead::stop_after`].
///
/// Why: a glTF's external buffers are known only once its JSON is parsed,
/// so the digest used to start after the parse, and with two threads the
/// load then waited for it (the dragon's GLB: 13 ms of hashing beside a
/// 6 ms decode). Started when the file is read, it also runs beside the
/// JSON parse and checks. It starts a thread only where [`digest_while`]
/// would (two threads or more in the calling pool, a large enough file);
/// otherwise the digest is computed on the calling thread. The digest is
/// the same either way.
pub(crate) struct DigestHead<'s> {
    /// The hashing thread: the digest of the first `n` bytes of `first`
    /// (all of them unless stopped).
    thread: Option<std::thread::ScopedJoinHandle<'s, (InputDigest, usize)>>,
    first: &'s [u8],
    /// Set to make the thread stop at its next block and hand back what it
    /// has (by [`DigestHead::stop_after`], or on drop when the load fails).
    stop: &'s std::sync::atomic::AtomicBool,
}

/// Runs `body` with a [`DigestHead`] of `first` (hashing it from now on,
/// see there).
pub(crate) fn with_digest_head<R>(first: &[u8], body: impl FnOnce(DigestHead<'_>) -> R) -> R {
    use std::sync::atomic::{AtomicBool, Ordering::Relaxed};
    let stop = AtomicBool::new(false);
    std::thread::scope(|scope| {
        let thread = (first.len() >= CONCURRENT_DIGEST_MIN && rayon::current_num_threads() >= 2)
            .then(|| {
                let stop = &stop;
                std::thread::Builder::new()
                    .name("svpack-sha256".into())
                    .spawn_scoped(scope, move || {
                        let _digest = crate::trace::span("digest");
                        let mut digest = InputDigest::default();
                        let mut hashed = 0;
                        for block in first.chunks(HEAD_BLOCK) {
                            if stop.load(Relaxed) {
                                break;
                            }
                            digest.update(block);
                            hashed += block.len();
                        }
                        (digest, hashed)
                    })
                    .ok()
            })
            .flatten();
        let _parse = crate::trace::span("parse");
        body(DigestHead {
            thread,
            first,
            stop: &stop,
        })
    })
}

/// Bytes [`with_digest_head`]'s thread hashes between looks at its stop
/// flag: a stop waits for at most one block (about 0.2 ms).
const HEAD_BLOCK: usize = 256 << 10;

impl DigestHead<'_> {
    /// The digest of the first part and then `rest` (fed in order), computed
    /// while `work` runs on this thread, and `work`'s result.
    pub(crate) fn finish_while<T>(
        mut self,
        rest: &[&[u8]],
        work: impl FnOnce() -> T,
    ) -> ((u64, [u8; 32]), T) {
        let first = self.first;
        let all = || InputDigest::of_parts(std::iter::once(first).chain(rest.iter().copied()));
        let Some(head) = self.thread.take() else {
            let mut parts = vec![first];
            parts.extend_from_slice(rest);
            return digest_while(&parts, work);
        };
        std::thread::scope(|scope| {
            // The rest is hashed after the first part, on a thread of its
            // own, so `work` need not wait for the first part.
            let tail = std::thread::Builder::new()
                .name("svpack-sha256".into())
                .spawn_scoped(scope, move || {
                    let (mut digest, hashed) = head.join().ok()?;
                    digest.update(&first[hashed..]);
                    for part in rest {
                        digest.update(part);
                    }
                    Some(digest.finish())
                });
            let result = work();
            // If a thread could not be started or died, hash here instead.
            let digest = match tail.map(|t| t.join()) {
                Ok(Ok(Some(digest))) => digest,
                _ => all(),
            };
            (digest, result)
        })
    }

    /// Runs `work` on this thread, then stops the digest of the first part
    /// where its thread has got to and returns it with the number of bytes
    /// it covers, and `work`'s result. Without a thread the first part is
    /// hashed here, whole, before `work` (one thread means one core).
    ///
    /// Why: a build needs the digest only for the header, written last; the
    /// bytes left are hashed while the output's payload is written, by a
    /// thread that would otherwise wait for the other's copying into the
    /// page cache ([`DigestSlices`], `format::write_file_streamed_finishing`),
    /// instead of the load waiting for them.
    pub(crate) fn stop_after<T>(mut self, work: impl FnOnce() -> T) -> ((InputDigest, usize), T) {
        let first = self.first;
        let Some(head) = self.thread.take() else {
            let mut digest = InputDigest::default();
            digest.update(first);
            return ((digest, first.len()), work());
        };
        let result = work();
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let digest = head.join().unwrap_or_else(|_| (InputDigest::default(), 0));
        (digest, result)
    }
}

impl Drop for DigestHead<'_> {
    fn drop(&mut self) {
        if self.thread.is_some() {
            self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }
}

/// An input's byte count and SHA-256, possibly with bytes still to hash:
/// what a loader hands a build that finishes the digest later
/// ([`gltf::load_gltf_deferred`]).
pub enum PendingDigest {
    /// The byte count and digest, complete.
    Done(u64, [u8; 32]),
    /// The digest of `data[..from]`, to be continued with `data[from..]`.
    Rest {
        /// The digest so far.
        digest: InputDigest,
        /// The bytes it covers, in full.
        data: FileBytes,
        /// How many of them are hashed.
        from: usize,
    },
}

impl PendingDigest {
    /// The byte count and SHA-256 of everything, hashing what is left.
    pub fn finish(self) -> (u64, [u8; 32]) {
        match self {
            PendingDigest::Done(bytes, sha) => (bytes, sha),
            PendingDigest::Rest {
                mut digest,
                data,
                from,
            } => {
                digest.update(&data[from..]);
                digest.finish()
            }
        }
    }
}

/// A [`PendingDigest`] hashed a slice at a time by whichever thread has a
/// moment ([`DigestSlices::step`]), then finished: how a build hashes what
/// its load left of the input while it writes the output
/// (`format::write_file_streamed_finishing`).
pub struct DigestSlices(std::sync::Mutex<PendingDigest>);

/// Bytes one [`DigestSlices::step`] hashes: about 10 µs here, so a thread
/// that hashes while waiting for another's write starts its own soon after.
const SLICE: usize = 16 << 10;

impl DigestSlices {
    /// Slices of `digest`.
    pub fn new(digest: PendingDigest) -> Self {
        DigestSlices(std::sync::Mutex::new(digest))
    }

    /// Hashes the next slice, unless another thread is hashing one; false
    /// once nothing is left.
    pub fn step(&self) -> bool {
        let Ok(mut pending) = self.0.try_lock() else {
            return true;
        };
        match &mut *pending {
            PendingDigest::Done(..) => false,
            PendingDigest::Rest { digest, data, from } => {
                let end = data.len().min(*from + SLICE);
                digest.update(&data[*from..end]);
                *from = end;
                end < data.len()
            }
        }
    }

    /// The byte count and SHA-256 of everything, hashing what is left here.
    pub fn finish(&self) -> (u64, [u8; 32]) {
        let _rest = crate::trace::span("digest: the rest");
        let mut pending = self.0.lock().unwrap_or_else(|e| e.into_inner());
        std::mem::replace(&mut *pending, PendingDigest::Done(0, [0; 32])).finish()
    }
}

/// Input formats svpack reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// glTF 2.0, JSON (`.gltf`) or binary (`.glb`).
    Gltf,
    /// Wavefront OBJ.
    Obj,
}

/// Detects the format from the file's first bytes, falling back to the extension.
pub fn detect_format(path: &Path, head: &[u8]) -> Result<Format> {
    if head.starts_with(b"glTF") {
        return Ok(Format::Gltf);
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("gltf") | Some("glb") => Ok(Format::Gltf),
        Some("obj") => Ok(Format::Obj),
        _ => Err(Error::input(
            path,
            "unknown input format (expected .gltf, .glb or .obj)",
        )),
    }
}

/// The bytes of the file at `path`, mapped when large
/// ([`crate::file_bytes::read_or_map`]), with errors as [`Error::Io`].
pub fn read_file(path: &Path) -> Result<FileBytes> {
    crate::file_bytes::read_or_map(path).map_err(|e| Error::io(path, e))
}

/// What the head of the file at `path` says of its build: its format (None
/// when it is neither, or unreadable), its size, and the bytes of the soup
/// its load will make, estimated (see [`soup_estimate`]).
struct SizeHint {
    format: Option<Format>,
    size: u64,
    soup: u64,
}

impl SizeHint {
    /// [`work_estimate`]'s measure: an OBJ's text twice, else the soup.
    fn work(&self) -> u64 {
        match self.format {
            Some(Format::Obj) => self.size.saturating_mul(2),
            _ => self.soup,
        }
    }
}

fn size_hint(path: &Path) -> SizeHint {
    use std::io::Read;
    let unknown = |size| SizeHint {
        format: None,
        size,
        soup: size,
    };
    let Ok(mut file) = std::fs::File::open(path) else {
        return unknown(0);
    };
    let size = file.metadata().map_or(0, |m| m.len());
    let mut head = Vec::with_capacity(20);
    if (&mut file).take(20).read_to_end(&mut head).is_err() {
        return unknown(size);
    }
    match detect_format(path, &head) {
        Ok(Format::Obj) => SizeHint {
            format: Some(Format::Obj),
            size,
            soup: size / 2,
        },
        Ok(Format::Gltf) => match gltf::soup_bytes(&mut file, &head, size) {
            Some(soup) => SizeHint {
                format: Some(Format::Gltf),
                size,
                soup,
            },
            None => unknown(size),
        },
        Err(_) => unknown(size),
    }
}

/// An estimate of the bytes of positions and triangles (12 bytes each) the
/// load of the input at `path` will make, read from its head, never its
/// buffers: the measure by which a batch orders its inputs
/// ([`work_estimate`]) and budgets their memory
/// (`build::memory_estimate`).
///
/// - An OBJ counts half its text: the dragon's 31.8 MiB of text hold 15.0
///   MiB of positions and triangles, the 5M scene's 195 MiB 86.6 MiB.
/// - A glTF counts its JSON and, for every mesh instance its load places,
///   each triangle primitive's positions and triangles
///   ([`gltf::soup_bytes`]), wherever their buffers are: a `.gltf`'s own
///   size leaves out its `.bin` files, a `.glb`'s counts its images, and a
///   mesh placed by three nodes is loaded three times.
/// - Anything else, and a glTF whose JSON cannot be read, counts its size;
///   an unreadable file counts 0 (its build reports the problem).
pub fn soup_estimate(path: &Path) -> u64 {
    size_hint(path).soup
}

/// An estimate of the work of building the input at `path`, in weighted
/// bytes, by which a batch starts its largest inputs first
/// (`build::build_batch`): [`soup_estimate`], with an OBJ's counted four
/// times (twice its text). Why: an OBJ's build took about 9 ns a byte of
/// text here (the dragon's 33 MB in 315 ms, the 5M scene's 204 MB in 1.8 s,
/// one thread), about twice a glTF's per byte of geometry (the dragon's
/// GLB, 15.7 MB, in 68 ms).
pub fn work_estimate(path: &Path) -> u64 {
    size_hint(path).work()
}

/// [`work_estimate`] and [`soup_estimate`] of the input at `path` from one
/// read of its head (a glTF's JSON parsed once): what a batch under a
/// memory budget asks of each input.
pub fn estimates(path: &Path) -> (u64, u64) {
    let hint = size_hint(path);
    (hint.work(), hint.soup)
}

/// Loads a glTF or OBJ file into a world-space soup.
pub fn load(path: &Path) -> Result<Soup> {
    let data = read_file(path)?;
    match detect_format(path, &data)? {
        Format::Gltf => gltf::load_gltf(path, data),
        Format::Obj => obj::load_obj(path, data),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The estimates a batch orders its inputs by and budgets memory with:
    /// an OBJ's soup half its text, its work twice its text; a glTF's JSON
    /// and, per mesh instance, its triangle primitives' positions and
    /// triangles, from a `.gltf` whose buffer is another file (not there:
    /// only the JSON is read); otherwise the size, or 0 for a missing file
    /// (a GLB's: `tests/gltf_load.rs`). Caught: the OBJ's weight left out
    /// of the work; each mesh counted once, not per instance; every mode
    /// taken as a list of triangles (the points counted, the strip short).
    #[test]
    fn soup_estimates_count_obj_text_and_gltf_instances() {
        let dir = tempfile::tempdir().unwrap();
        let at = |name: &str, bytes: &[u8]| {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
        let path = at("t.obj", obj);
        assert_eq!(soup_estimate(&path), obj.len() as u64 / 2);
        assert_eq!(work_estimate(&path), 2 * obj.len() as u64);
        // Mesh 0 is placed by node 0 and by node 2 (a child of node 1);
        // mesh 1 by no node. Its points and its normals are never read.
        let json = br#"{"asset": {"version": "2.0"},
  "accessors": [
    {"bufferView": 0, "componentType": 5126, "count": 1000, "type": "VEC3"},
    {"bufferView": 1, "componentType": 5123, "count": 3000, "type": "SCALAR"},
    {"bufferView": 2, "componentType": 5126, "count": 10, "type": "VEC3"},
    {"bufferView": 3, "componentType": 5126, "count": 1000, "type": "VEC3"}],
  "meshes": [
    {"primitives": [
      {"attributes": {"POSITION": 0, "NORMAL": 3}, "indices": 1},
      {"attributes": {"POSITION": 0}, "mode": 0},
      {"attributes": {"POSITION": 2}, "mode": 5}]},
    {"primitives": [{"attributes": {"POSITION": 3}}]}],
  "nodes": [{"mesh": 0}, {"children": [2]}, {"mesh": 0, "translation": [1, 0, 0]}],
  "scenes": [{"nodes": [0, 1]}],
  "scene": 0,
  "buffers": [{"uri": "elsewhere.bin", "byteLength": 9999999}]}"#;
        let instance = (1000 + 1000) * 12 + (10 + 8) * 12;
        let path = at("m.gltf", json);
        assert_eq!(soup_estimate(&path), json.len() as u64 + 2 * instance);
        assert_eq!(work_estimate(&path), soup_estimate(&path));
        // Not JSON, or not glTF JSON: the file's size.
        let text = b"{\"accessors\": [{\"count\": \"many\"}]}";
        assert_eq!(work_estimate(&at("broken.gltf", text)), text.len() as u64);
        let other = at("notes.txt", b"twelve bytes");
        assert_eq!(work_estimate(&other), 12);
        assert_eq!(soup_estimate(&other), 12);
        assert_eq!(work_estimate(&dir.path().join("missing.obj")), 0);
        assert_eq!(soup_estimate(&dir.path().join("missing.obj")), 0);
    }

    /// Slices hashed by two threads at once (each step takes the next
    /// slice or none), then the rest by `finish`: the SHA-256 of the whole,
    /// from any starting point and however many steps ran. Caught: a slice
    /// hashed twice or skipped when two threads step together, and
    /// `finish` restarting from the first byte.
    #[test]
    fn digest_slices_from_two_threads_give_the_whole_digest() {
        let data: Vec<u8> = (0..(5 * SLICE + 123) as u32)
            .map(|i| (i ^ (i >> 7)) as u8)
            .collect();
        let whole = InputDigest::of(&data);
        for (from, steps) in [(0, 0), (0, 2), (3, 100), (SLICE + 7, 3), (data.len(), 1)] {
            let mut digest = InputDigest::default();
            digest.update(&data[..from]);
            let slices = DigestSlices::new(PendingDigest::Rest {
                digest,
                data: FileBytes::Read(data.clone()),
                from,
            });
            std::thread::scope(|s| {
                for _ in 0..2 {
                    s.spawn(|| {
                        for _ in 0..steps {
                            slices.step();
                        }
                    });
                }
            });
            assert_eq!(slices.finish(), whole, "from {from}, {steps} steps");
        }
        let done = DigestSlices::new(PendingDigest::Done(whole.0, whole.1));
        assert!(!done.step());
        assert_eq!(done.finish(), whole);
    }
}
