//! Wavefront OBJ loader.
//!
//! `tobj` does the parsing; this module prepares the bytes for it and turns its
//! models into a [`Soup`]. What happens, in order:
//!
//! 1. **Encoding.** UTF-8 (with or without BOM) is read as is. UTF-16 with a
//!    byte-order mark is decoded (with a warning), because some Windows tools
//!    write it. Any other NUL byte is an error (UTF-16 without BOM, or binary
//!    data). Invalid UTF-8 on lines that carry no geometry (comments, object
//!    names, often Latin-1 from old exporters) is replaced by `?` with a
//!    warning; on `v`/`f` lines it is an error.
//! 2. **Pre-scan** (one pass over the bytes, in place, no allocation per line).
//!    Statements svpack has no use for are blanked by overwriting their keyword
//!    with `#`, so tobj sees a comment: `vt`, `vn`, `vp`, `usemtl`, `mtllib`,
//!    `l` and `p`. Why: tobj parses `l` exactly like `f` (`l 1 2 3 4` would
//!    become a quad), silently drops `p`, rejects `usemtl` followed by a tab or
//!    without a name, and validates texture/normal indices we never use; and
//!    with `mtllib` gone no `.mtl` file is ever looked for. `l`/`p` elements
//!    are counted here. Line continuations (`\` at the end of a line), which
//!    tobj does not understand, are joined. In the common case (UTF-8 text
//!    that tobj accepts without repairs) this runs piece by piece as tobj
//!    reads (`PrescanReader`), on a 64 KiB copy of each piece, so the file is
//!    neither modified (it may be being hashed on another thread) nor walked
//!    twice; anything else is redone on an owned copy of the whole text
//!    (`parse_owned`), with the same result.
//! 3. **Parse** with `tobj::load_obj_buf` (untriangulated, one index per
//!    attribute). On the piece-by-piece path, a model longer than
//!    `MODEL_BLOCK_FACES` faces is handed to tobj in blocks: the pre-scan
//!    repeats the model's `o`/`g` statement at a piece boundary, so tobj
//!    exports the block and reuses its face buffer (104 bytes per face,
//!    otherwise the largest buffer of a build); the blocks have the same
//!    name and become one part again. `input_vertices` is the number of
//!    `v` statements either way. tobj's small blocks (a `String` per line,
//!    each object's buffers) come from an arena (`alloc::arena`) whose
//!    pages, once the models are freed, the weld reuses. With two threads or
//!    more, a text of at least `SPLIT_MIN` bytes is parsed in two parts at
//!    once (`parse_split`): a second reader gives tobj the first part's `v`
//!    statements and then the rest, and the models are those of the whole
//!    text cut into one more block; both readers' blocks come from the
//!    arena (its two owners). A few recoverable problems are repaired in
//!    place and the parse is retried (see `repair_vertex_lines`); any other
//!    failure is turned into a message naming the offending line
//!    (`diagnose`).
//! 4. **Triangulate** (`Triangulator`): triangles pass through; every face
//!    with `n >= 4` corners gives exactly `n - 2` triangles that use all its
//!    corners (so edges still match the neighbouring faces) in the face's
//!    winding. Quads are split along the diagonal that gives the larger
//!    smaller triangle (for a concave quad: the one from the reflex corner).
//!    Larger faces are projected onto the plane perpendicular to their Newell
//!    normal; strictly convex ones are fanned, others go to `earcutr`, whose
//!    result is completed (corners it dropped as collinear are put back),
//!    checked and oriented; both are then improved by Delaunay edge flips,
//!    which remove slivers. A face ear clipping cannot handle (degenerate,
//!    self-intersecting) is fanned `(0, i, i+1)` with a warning.
//!
//! What the counters count (OBJ has no "primitives", so elements are counted):
//! * `skipped_points`: point elements, i.e. every vertex reference in a `p`
//!   statement (the OBJ spec makes each one a point element) and every `f`
//!   with a single corner. A file with vertices but no `f`, `l` or `p`
//!   statement at all is a point cloud: then every vertex counts as one point.
//! * `skipped_lines`: line elements, i.e. every `l` statement (one polyline,
//!   however many vertices it lists) and every `f` with exactly two corners.
//! * `primitives`: objects/groups (tobj models) that produced at least one
//!   triangle, which is also the number of [`Part`]s.

use super::{Part, Soup};
use crate::alloc::arena::Arena;
use crate::error::{Error, Result};
use crate::file_bytes::FileBytes;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

/// Loads a `.obj` whose bytes are `data` (read or mapped; a mapping is
/// copied only when the text needs rewriting, see `parse_owned`).
///
/// Every object/group with triangles becomes a [`Part`] named `object "name"`
/// (tobj's model name; consecutive models with the same name are merged).
/// Polygons are triangulated (concave ones correctly, keeping the face's
/// winding); points and lines are skipped and counted in
/// [`LoadStats`](super::LoadStats). Only `data` is read: material libraries
/// are never opened, so a missing `.mtl` does not matter.
///
/// Errors are [`Error::Input`] naming `path` and, where possible, the line:
/// unparsable numbers, indices out of range, UTF-16 without byte-order mark,
/// binary data. An empty file gives an empty soup. NaN/Inf coordinates are
/// passed through (the build step rejects them).
///
/// The input's SHA-256 is computed beside the parse, on a second thread, when
/// the calling rayon pool has more than one thread ([`super::digest_while`]).
pub fn load_obj(path: &Path, data: impl Into<FileBytes>) -> Result<Soup> {
    let data: FileBytes = data.into();
    // Hashing and parsing are independent; with more than one thread the
    // digest is computed beside the parse (see `digest_while`).
    // The parser's small blocks in an arena that becomes a kept block once
    // they are freed, for the weld (`alloc::arena`); dropped at the end of
    // this function, after the soup is built and the models are freed.
    warm_up_tobj();
    let arena = crate::alloc::arena::open(ARENA_PER_BYTE * data.len() + ARENA_EXTRA);
    let ((input_bytes, input_sha256), streamed) = super::digest_while(&[&data], || {
        guarded(|| arena.scope(|| parse_streaming(&data, &arena)))
    });
    let parsed = match streamed {
        Ok(Some(parsed)) => {
            // The text is no longer needed; free it before building the
            // soup, which for big files is the peak of memory use.
            drop(data);
            Ok(parsed)
        }
        Ok(None) => guarded(|| arena.scope(|| parse_owned(data.into_vec()))),
        Err(msg) => Err(msg),
    };
    let mut soup = parsed
        .and_then(|parsed| guarded(|| finish(parsed)))
        .map_err(|msg| Error::input(path, msg))?;
    soup.input_bytes = input_bytes;
    soup.input_sha256 = input_sha256;
    Ok(soup)
}

/// Address space the parser's arena reserves per byte of input, and beyond
/// that (`alloc::arena`): nothing is faulted in until used, and an arena
/// that runs out leaves the rest to malloc.
const ARENA_PER_BYTE: usize = 4;
const ARENA_EXTRA: usize = 64 << 20;

/// Parses an empty text once per process, before any arena opens. Why:
/// tobj's hash maps (ahash's) seed themselves on first use into
/// process-wide statics (three blocks, 88 bytes), which live as long as the
/// process; made inside the first parse's arena scope, they held its first
/// chunk for good, and with it the arena, so that every later parse of the
/// process used malloc (`alloc::arena`).
fn warm_up_tobj() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // An empty text is a valid OBJ without models; the result is not
        // needed.
        let _ = run_tobj(&mut &b""[..]);
    });
}

/// Runs one step of the pipeline, turning a panic into an error message.
///
/// tobj and earcutr are third-party parsers fed untrusted input; the known
/// panic causes are avoided by the pre-scan, but a panic must still never
/// take the whole process down.
fn guarded<T>(step: impl FnOnce() -> Result<T, String>) -> Result<T, String> {
    match catch_unwind(AssertUnwindSafe(step)) {
        Ok(result) => result,
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            Err(format!("internal error while reading OBJ: {what}"))
        }
    }
}

/// What parsing produced, before the soup is built.
struct Parsed {
    models: Vec<tobj::Model>,
    scan: Prescan,
    warnings: Vec<String>,
}

/// The common case in one pass, without copying the file: UTF-8 text with
/// `\n` line ends that tobj accepts as it is (after the pre-scan). The
/// pre-scan runs piece by piece as tobj reads (`PrescanReader`), on a small
/// buffer, so the file itself stays unmodified (it may be being hashed on
/// another thread) and each piece is still in cache when tobj parses it.
///
/// Returns `None` when the text needs anything else (re-encoding, NUL bytes,
/// invalid UTF-8, CR-only line ends, repairs, or an error to diagnose):
/// then [`parse_owned`] does all of it on the whole text, from the start, so
/// the result is exactly the same whichever path is taken.
fn parse_streaming(data: &[u8], arena: &Arena) -> Result<Option<Parsed>, String> {
    if data.starts_with(&[0xFE, 0xFF]) || data.starts_with(&[0xFF, 0xFE]) {
        return Ok(None);
    }
    // As `normalize_encoding` does: the byte-order mark is not text.
    let text = data.strip_prefix(&[0xEF, 0xBB, 0xBF]).unwrap_or(data);
    // Stops at the first line end, so this is no second pass.
    if !text.contains(&b'\n') && text.contains(&b'\r') {
        return Ok(None);
    }
    if text.len() >= SPLIT_MIN
        && rayon::current_num_threads() >= 2
        && let Some(split) = split_point(text)
    {
        match parse_split(text, split, arena) {
            Split::Parsed(parsed) => return Ok(Some(parsed)),
            Split::Declined => return Ok(None),
            // Parsed again by one reader below, as with one thread: a
            // one-thread build's soup (the build's message about a
            // non-finite position then names the same vertex), and its
            // models where the cut has no statement to repeat.
            Split::OneReader => {}
        }
    }
    let mut reader = PrescanReader::new(text);
    match run_tobj(&mut reader) {
        Ok(models) if reader.finished() => Ok(Some(Parsed {
            models,
            scan: reader.scanner.scan,
            warnings: Vec::new(),
        })),
        _ => Ok(None),
    }
}

/// Texts at least this long are parsed in two parts at once
/// ([`parse_split`]) when the calling rayon pool has two threads or more.
/// A threshold chosen, not measured: 2 MiB of OBJ take tobj about 15 ms
/// here, against about 0.5 ms for finding the cut of a 4 MB text and
/// 0.1 ms for the second part's thread to start (timers in a local build,
/// benches/ROUNDS.md, Fifty-sixth round).
const SPLIT_MIN: usize = 2 << 20;

/// [`parse_streaming`]'s parse on two threads: tobj reads `text[..split]`
/// on this thread and the rest on another, each through its own
/// [`PrescanReader`], and the two lists of models are joined. `split` is
/// the start of a line that no statement before it continues onto
/// ([`split_point`]).
///
/// Why: tobj parses on one thread (about 7 ms per MB here), and for a
/// large OBJ it is most of a build; a two-thread build used its second
/// thread only for the input's digest meanwhile.
///
/// Why the result is the one-thread parse's: the second part's reader
/// ([`PrescanReader::after`]) gives tobj the first part's `v` statements
/// alone, so its positions are numbered as in the whole text (absolute
/// and relative indices resolve to the same vertices, and a face may use
/// any earlier vertex), then repeats the `o`/`g` statement in force at
/// `split`, so its first model has the name the whole text gives it. A
/// model cut at `split` becomes two models of the same name, as at a
/// block boundary (`MODEL_BLOCK_FACES`), which [`build_soup`] merges into
/// one part: the soup then holds the vertices the two halves share twice,
/// which welding merges, so every triangle has the same corner positions
/// in the same order, and a build's output the same bytes.
///
/// The second part goes to whichever reader claims it first (`claim`):
/// the other thread when it starts before this one reaches `split`, else
/// this thread, which reads on. So a pool whose other thread is busy (a
/// batch building two inputs at once) does not parse the first part's
/// vertices twice. Reading on, it also ends tobj's model at `split` and
/// starts one of the same name, as the other reader does, so the models
/// (and the soup) are the same whoever reads the rest.
///
/// [`Split::Declined`] when either part needs what [`parse_streaming`]
/// declines (the caller then parses the whole text as [`parse_owned`]);
/// [`Split::OneReader`] when a position is not finite (the build's
/// message names the soup's vertex, whose number the shared vertices
/// change) or the statement in force at the cut was continued (it cannot
/// be repeated): the caller then parses again with one reader, as a
/// one-thread build does.
fn parse_split(text: &[u8], split: usize, arena: &Arena) -> Split {
    let claim = std::sync::atomic::AtomicBool::new(false);
    let mut second = None;
    // The first part on this thread, which may be inside the loader's
    // arena scope (`rayon::join` called from outside the pool would run
    // both parts on its workers); the second on the pool, in a scope of
    // the same arena (its second owner: `alloc::arena`).
    let first = rayon::in_place_scope(|scope| {
        let slot = &mut second;
        let claim = &claim;
        scope.spawn(move |_| *slot = arena.scope(|| second_part(text, split, claim)));
        first_part(text, split, claim)
    });
    join_parts(first, second)
}

/// What [`parse_split`] gives.
enum Split {
    Parsed(Parsed),
    /// A part cannot be read as [`parse_streaming`] reads a text.
    Declined,
    /// A position is not finite, or the `o`/`g` statement in force at the
    /// cut cannot be repeated there (it was continued on another line).
    OneReader,
}

/// What one reader of [`parse_split`] read.
struct PartRead {
    /// tobj's models; `None` if tobj failed or the text needs decoding.
    models: Option<Vec<tobj::Model>>,
    /// Every position of `models` is finite.
    finite: bool,
    /// The reader met the cut and could not repeat the statement there.
    no_cut: bool,
    scan: Prescan,
}

impl PartRead {
    /// What tobj read from `reader`.
    fn of(reader: &mut PrescanReader<'_>) -> Self {
        let models = run_tobj(reader).ok().filter(|_| reader.finished());
        let finite = models
            .iter()
            .flatten()
            .all(|m| m.mesh.positions.iter().all(|c| c.is_finite()));
        PartRead {
            models,
            finite,
            no_cut: reader.no_cut,
            scan: std::mem::take(&mut reader.scanner.scan),
        }
    }
}

/// [`parse_split`]'s first reader: `text` up to `split`, and on past it if
/// it claims the rest first; and whether it stopped at the cut (the other
/// reader claimed the rest).
fn first_part(
    text: &[u8],
    split: usize,
    claim: &std::sync::atomic::AtomicBool,
) -> (PartRead, bool) {
    let mut reader = PrescanReader::new(text);
    reader.stop_at = split;
    reader.claim = Some(claim);
    let read = PartRead::of(&mut reader);
    // Claiming the rest sets `stop_at` back to 0.
    (read, reader.stop_at == split)
}

/// [`parse_split`]'s second reader, if it claims the rest first: what it
/// read, and its scan's counts at the cut.
fn second_part(
    text: &[u8],
    split: usize,
    claim: &std::sync::atomic::AtomicBool,
) -> Option<(PartRead, Option<Prescan>)> {
    if claim.swap(true, std::sync::atomic::Ordering::AcqRel) {
        return None;
    }
    let _parse = crate::trace::span("parse: second part");
    let mut reader = PrescanReader::after(text, split);
    let read = PartRead::of(&mut reader);
    Some((read, reader.before.take()))
}

/// The two readers' results as one parse (see [`parse_split`]).
fn join_parts(first: (PartRead, bool), second: Option<(PartRead, Option<Prescan>)>) -> Split {
    let (first, stopped) = first;
    if first.no_cut {
        return Split::OneReader;
    }
    let Some(mut models) = first.models else {
        return Split::Declined;
    };
    if !stopped {
        // The first reader read the whole text.
        return match first.finite {
            true => Split::Parsed(Parsed {
                models,
                scan: first.scan,
                warnings: Vec::new(),
            }),
            false => Split::OneReader,
        };
    }
    let Some((second, before)) = second else {
        return Split::Declined;
    };
    if second.no_cut {
        return Split::OneReader;
    }
    let (Some(rest), Some(before)) = (second.models, before) else {
        return Split::Declined;
    };
    // Both readers scanned the same bytes before the cut (a check).
    if before.vertices != first.scan.vertices || before.faces != first.scan.faces {
        return Split::Declined;
    }
    if !(first.finite && second.finite) {
        return Split::OneReader;
    }
    // tobj ends a text with its current model even if it has no faces (a
    // cut just after an `o` line): nothing of the soup, and not a model
    // the other reader's models would have.
    if models.last().is_some_and(|m| m.mesh.indices.is_empty()) {
        models.pop();
    }
    models.extend(rest);
    // The second reader's scan went over the whole text.
    Split::Parsed(Parsed {
        models,
        scan: second.scan,
        warnings: Vec::new(),
    })
}

/// Where [`parse_split`] cuts `text`: the start of a line near the point
/// that gives its two readers equal work, or `None` where there is no such
/// line (a text of a few long lines).
///
/// The first reader parses `text[..split]`; the second the `v` statements
/// of that part again and then the rest. Counting a byte of either kind
/// the same, with `V(x)` the bytes of `v` lines before `x` and `n` the
/// text's length, the two are equal where `2·split − V(split) = n` (on
/// the 5M scene the readers then end within 30 ms of each other; where
/// the vertices all come first, both parts hold all of them and only the
/// faces decide). `V` is estimated from 64 samples of 16 KiB
/// spread over the text (a file's vertex lines may all come first, as in
/// the dragon's, or before each object's faces, as in the generated
/// scenes), so finding the point reads about 1 MiB. Then the cut moves to
/// the next line start, and to an `o`/`g` statement if one begins within
/// 64 KiB (no model is then cut in two), and past any line that a
/// backslash continues.
fn split_point(text: &[u8]) -> Option<usize> {
    const SAMPLES: usize = 64;
    const WINDOW: usize = 16 << 10;
    const SNAP: usize = 64 << 10;
    let n = text.len();
    if n < 2 {
        return None;
    }
    // The share of `v` lines' bytes in each sample's whole lines.
    let density: Vec<f64> = (0..SAMPLES)
        .map(|i| {
            let at = i * n / SAMPLES;
            let window = &text[at..(at + WINDOW).min(n)];
            let start = if at == 0 {
                0
            } else {
                find_newline(window).map_or(window.len(), |e| e + 1)
            };
            let (mut v, mut all) = (0usize, 0usize);
            let mut lines = Lines { pos: start };
            while let Some((s, e)) = lines.next(window) {
                if e == window.len() {
                    break;
                }
                all += e + 1 - s;
                if window[s..e].starts_with(b"v ") {
                    v += e + 1 - s;
                }
            }
            if all == 0 { 0.0 } else { v as f64 / all as f64 }
        })
        .collect();
    // V at the end of each sample's stretch of the text, then the first
    // stretch where the second reader's work falls below the first's.
    let stretch = n as f64 / SAMPLES as f64;
    let mut v_before = 0.0;
    let mut cut = n as f64 / 2.0;
    for (i, &d) in density.iter().enumerate() {
        let x0 = i as f64 * stretch;
        // Where 2x − (v_before + d·(x − x0)) = n inside this stretch.
        let x = (n as f64 + v_before - d * x0) / (2.0 - d);
        if x <= x0 + stretch {
            cut = x.max(x0);
            break;
        }
        v_before += d * stretch;
    }
    let mut split = (cut as usize).clamp(1, n - 1);
    split += find_newline(&text[split - 1..]).map(|e| e + 1)? - 1;
    // A model's start close by.
    let mut lines = Lines { pos: split };
    while let Some((s, e)) = lines.next(text) {
        if s >= split + SNAP {
            break;
        }
        if matches!(&text[s..e], [b'o' | b'g', b' ', ..]) {
            split = s;
            break;
        }
    }
    // Never inside a continued statement: after a line ending in `\`.
    let mut lines = Lines { pos: split };
    while split < n {
        let before = text[..split].strip_suffix(b"\n").unwrap_or(&text[..split]);
        if continuation(before.rsplit(|&b| b == b'\n').next().unwrap_or(&[])).is_none() {
            return Some(split);
        }
        lines.next(text)?;
        split = lines.pos;
    }
    None
}

/// Every step on an owned copy of the text, which may be modified as a whole:
/// decoding, the pre-scan, and parsing with repairs and diagnostics.
fn parse_owned(data: Vec<u8>) -> Result<Parsed, String> {
    let mut warnings = Vec::new();
    let mut text = normalize_encoding(data, &mut warnings)?;
    let scan = prescan(&mut text);
    let models = parse_with_repairs(&mut text, &scan, &mut warnings)?;
    Ok(Parsed {
        models,
        scan,
        warnings,
    })
}

/// Builds the soup and the statistics; errors are messages without the path.
fn finish(parsed: Parsed) -> Result<Soup, String> {
    let Parsed {
        models,
        scan,
        mut warnings,
    } = parsed;
    let mut soup = build_soup(models, &mut warnings)?;
    soup.input_vertices = scan.vertices;
    let stats = &mut soup.stats;
    stats.skipped_points += scan.point_refs;
    stats.skipped_lines += scan.line_statements;
    if scan.faces == 0
        && scan.line_statements == 0
        && scan.point_statements == 0
        && scan.vertices > 0
    {
        stats.skipped_points += scan.vertices;
        warnings.push(format!(
            "no faces, lines or points: the {} vertices are a point cloud and were skipped",
            scan.vertices
        ));
    }
    stats.warnings.append(&mut warnings);
    Ok(soup)
}

// ---------------------------------------------------------------------------
// Encoding
// ---------------------------------------------------------------------------

/// Makes `data` UTF-8 text with `\n` line ends, or explains why it cannot.
fn normalize_encoding(mut data: Vec<u8>, warnings: &mut Vec<String>) -> Result<Vec<u8>, String> {
    if let Some(big_endian) = match data.get(..2) {
        Some([0xFE, 0xFF]) => Some(true),
        Some([0xFF, 0xFE]) => Some(false),
        _ => None,
    } {
        data = decode_utf16(&data[2..], big_endian)?;
        warnings.push(format!(
            "file is UTF-16{} encoded; decoded it, but OBJ files should be ASCII/UTF-8",
            if big_endian { "BE" } else { "LE" }
        ));
    } else if data.starts_with(&[0xEF, 0xBB, 0xBF]) {
        // A UTF-8 byte-order mark would otherwise glue itself to the first
        // keyword and make tobj ignore the first statement.
        data.drain(..3);
    }

    // `contains` on bytes is a vectorised memchr; the position only matters
    // for the message.
    if data.contains(&0) {
        let at = data.iter().position(|&b| b == 0).unwrap_or(0);
        let line = 1 + data[..at].iter().filter(|&&b| b == b'\n').count();
        return Err(if looks_like_utf16(&data) {
            "file is UTF-16 encoded (without byte-order mark); OBJ must be ASCII/UTF-8".to_string()
        } else {
            format!("NUL byte on line {line}: this is binary data, not OBJ text (ASCII/UTF-8)")
        });
    }

    if std::str::from_utf8(&data).is_err() {
        replace_invalid_utf8(&mut data, warnings)?;
    }

    // Classic Mac OS line ends (CR only): tobj splits lines at LF alone, so the
    // whole file would be one line. Same length, so done in place.
    if !data.contains(&b'\n') && data.contains(&b'\r') {
        for b in data.iter_mut().filter(|b| **b == b'\r') {
            *b = b'\n';
        }
    }
    Ok(data)
}

/// Decodes UTF-16 (the byte-order mark already removed) to UTF-8 bytes.
fn decode_utf16(bytes: &[u8], big_endian: bool) -> Result<Vec<u8>, String> {
    if !bytes.len().is_multiple_of(2) {
        return Err(
            "file starts with a UTF-16 byte-order mark but has an odd number of bytes".into(),
        );
    }
    let units = bytes.chunks_exact(2).map(|c| {
        if big_endian {
            u16::from_be_bytes([c[0], c[1]])
        } else {
            u16::from_le_bytes([c[0], c[1]])
        }
    });
    let mut out = String::with_capacity(bytes.len() / 2);
    for ch in char::decode_utf16(units) {
        match ch {
            Ok(c) => out.push(c),
            Err(e) => {
                return Err(format!(
                    "invalid UTF-16 text (unpaired surrogate 0x{:04X})",
                    e.unpaired_surrogate()
                ));
            }
        }
    }
    Ok(out.into_bytes())
}

/// True if the start of `data` has NUL bytes at every other position, the
/// signature of ASCII text stored as UTF-16.
fn looks_like_utf16(data: &[u8]) -> bool {
    let head = &data[..data.len().min(512)];
    let pairs = head.len() / 2;
    if pairs < 2 {
        return false;
    }
    let even = head.iter().step_by(2).filter(|&&b| b == 0).count();
    let odd = head.iter().skip(1).step_by(2).filter(|&&b| b == 0).count();
    even.max(odd) * 10 >= pairs * 9
}

/// Replaces invalid UTF-8 with `?` on lines without geometry; fails on
/// `v`/`f` lines, where a guessed byte could silently change the mesh.
fn replace_invalid_utf8(data: &mut [u8], warnings: &mut Vec<String>) -> Result<(), String> {
    let mut replaced = 0usize;
    let mut first_line = 0usize;
    let mut lines = Lines::default();
    let mut line_no = 0usize;
    while let Some((s, e)) = lines.next(data) {
        line_no += 1;
        let line = &mut data[s..e];
        if std::str::from_utf8(line).is_ok() {
            continue;
        }
        let (ks, ke) = keyword_ascii(line);
        if matches!(&line[ks..ke], b"v" | b"f") {
            return Err(format!(
                "line {line_no}: not valid UTF-8 text; OBJ must be ASCII/UTF-8"
            ));
        }
        let mut i = 0;
        while let Err(err) = std::str::from_utf8(&line[i..]) {
            let bad = i + err.valid_up_to();
            let len = err.error_len().unwrap_or(line.len() - bad);
            line[bad..bad + len].fill(b'?');
            replaced += len;
            i = bad + len;
        }
        if first_line == 0 {
            first_line = line_no;
        }
    }
    warnings.push(format!(
        "{replaced} byte(s) of invalid UTF-8 in comments/names replaced by '?' \
         (first on line {first_line}); OBJ files should be ASCII/UTF-8"
    ));
    Ok(())
}

// ---------------------------------------------------------------------------
// Lines and tokens
// ---------------------------------------------------------------------------

/// Walks `\n`-separated lines as byte ranges (without the `\n`). Kept apart
/// from the text so the caller may modify the text between steps.
#[derive(Default)]
struct Lines {
    pos: usize,
}

impl Lines {
    fn next(&mut self, text: &[u8]) -> Option<(usize, usize)> {
        if self.pos >= text.len() {
            return None;
        }
        let start = self.pos;
        let end = find_newline(&text[start..]).map_or(text.len(), |i| start + i);
        self.pos = end + 1;
        Some((start, end))
    }
}

/// Position of the first `\n` in `bytes`, eight bytes at a time. Why not
/// `iter().position`: every line of the file goes through this, and a
/// byte-by-byte loop cost more than everything else the pre-scan does.
fn find_newline(bytes: &[u8]) -> Option<usize> {
    const ONES: u64 = u64::from_ne_bytes([0x01; 8]);
    const HIGHS: u64 = u64::from_ne_bytes([0x80; 8]);
    const NEWLINES: u64 = u64::from_ne_bytes([b'\n'; 8]);
    let mut words = bytes.chunks_exact(8);
    let mut at = 0;
    for word in &mut words {
        // Bytes equal to `\n` become zero; `(x - 1) & !x` sets the high bit
        // of every zero byte, and of no byte below the first one (a borrow
        // only moves upwards), so the lowest flag is the first `\n`.
        let x = u64::from_le_bytes(word.try_into().expect("8 bytes")) ^ NEWLINES;
        let zeros = x.wrapping_sub(ONES) & !x & HIGHS;
        if zeros != 0 {
            return Some(at + zeros.trailing_zeros() as usize / 8);
        }
        at += 8;
    }
    words
        .remainder()
        .iter()
        .position(|&b| b == b'\n')
        .map(|i| at + i)
}

/// ASCII whitespace as `str::split_whitespace` (which tobj uses) sees it.
fn is_blank(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\r' | 0x0b | 0x0c)
}

/// Byte range of the first ASCII-whitespace-separated word of `line`.
fn keyword_ascii(line: &[u8]) -> (usize, usize) {
    let mut s = 0;
    while s < line.len() && is_blank(line[s]) {
        s += 1;
    }
    let mut e = s;
    while e < line.len() && !is_blank(line[e]) {
        e += 1;
    }
    (s, e)
}

/// Byte range of the first word exactly as tobj splits it (Unicode
/// whitespace); only differs from [`keyword_ascii`] for non-ASCII lines.
fn keyword(line: &[u8]) -> (usize, usize) {
    let (s, e) = keyword_ascii(line);
    // The ASCII scan stops only at ASCII whitespace, so it is exact unless
    // a non-ASCII byte (possibly Unicode whitespace) came before its end.
    if line[..e].is_ascii() {
        return (s, e);
    }
    match std::str::from_utf8(line) {
        Ok(text) => {
            let rest = text.trim_start();
            let s = text.len() - rest.len();
            (s, s + rest.find(char::is_whitespace).unwrap_or(rest.len()))
        }
        Err(_) => (s, e),
    }
}

/// Number of ASCII-whitespace-separated words in `bytes`.
fn count_words(bytes: &[u8]) -> u64 {
    let mut n = 0;
    let mut in_word = false;
    for &b in bytes {
        let word = !is_blank(b);
        if word && !in_word {
            n += 1;
        }
        in_word = word;
    }
    n
}

/// Byte ranges of the whitespace-separated words of `line` (as tobj splits).
fn words(line: &str) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, c) in line.char_indices() {
        match (c.is_whitespace(), start) {
            (true, Some(s)) => {
                out.push((s, i));
                start = None;
            }
            (false, None) => start = Some(i),
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, line.len()));
    }
    out
}

// ---------------------------------------------------------------------------
// Pre-scan
// ---------------------------------------------------------------------------

/// What the pre-scan found, and where it joined continued lines.
#[derive(Default)]
struct Prescan {
    /// `v` statements.
    vertices: u64,
    /// `f` statements.
    faces: u64,
    /// `l` statements (each one line element).
    line_statements: u64,
    /// `p` statements.
    point_statements: u64,
    /// Vertex references in `p` statements (each one point element).
    point_refs: u64,
    /// Byte offsets of `\n`s replaced by a space to join a continued line,
    /// ascending, so messages can still give physical line numbers.
    joins: Vec<usize>,
}

impl Prescan {
    /// Physical (1-based, as an editor shows) number of the `index`-th
    /// (0-based) line of the joined text, which starts at byte `start`.
    fn line_number(&self, index: usize, start: usize) -> usize {
        index + 1 + self.joins.partition_point(|&j| j < start)
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    Vertex,
    Face,
    Line,
    Point,
    Comment,
    /// `o` or `g`: a new object or group (tobj starts a new model).
    Group,
    Other,
}

/// One pass over the text: count, blank unused statements, join continuations.
fn prescan(text: &mut [u8]) -> Prescan {
    let mut scanner = Prescanner::default();
    scanner.run(text, 0);
    scanner.scan
}

/// The pre-scan as a state machine over consecutive pieces of the text, so it
/// can also run piece by piece as tobj reads ([`PrescanReader`]).
#[derive(Default)]
struct Prescanner {
    scan: Prescan,
    /// Kind of the statement whose line ended in a continuation.
    continued: Option<Kind>,
    /// `scan.faces` when the current tobj model began (at the last `o` or
    /// `g`, or the last [`PrescanReader`] block boundary).
    model_faces: u64,
    /// The last `o` or `g` statement, as tobj will read it (`None` before
    /// the first: tobj then names the model "unnamed_object").
    group_line: Option<Vec<u8>>,
    /// An `o` or `g` statement was continued on the next line: it cannot be
    /// repeated verbatim, so models are not cut into blocks.
    group_continued: bool,
}

impl Prescanner {
    /// Pre-scans `piece`, which starts at byte `offset` of the text and is
    /// either the rest of the text or ends just after a `\n`.
    fn run(&mut self, piece: &mut [u8], offset: usize) {
        self.run_with(piece, offset, |_, _, _| {});
    }

    /// [`Prescanner::run`], calling `each(s, e, kind)` after each line
    /// `piece[s..e]` with the kind of the statement it belongs to (a
    /// continued statement's kind for each of its lines).
    fn run_with(
        &mut self,
        piece: &mut [u8],
        offset: usize,
        mut each: impl FnMut(usize, usize, Kind),
    ) {
        // Line ends from a bit mask per 64 bytes rather than a search per
        // line: the mask is branch-free SIMD, while a search stops at a
        // different place on every line (a mispredicted branch per line).
        // `line` only changes bytes up to its own `\n`, so the masks of the
        // bytes after it stay right.
        let mut start = 0;
        let mut block = 0;
        while block < piece.len() {
            let block_end = (block + 64).min(piece.len());
            let mut bits = newline_bits(&piece[block..block_end]);
            while bits != 0 {
                let e = block + bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let kind = self.line(piece, start, e, offset);
                each(start, e, kind);
                start = e + 1;
            }
            block = block_end;
        }
        if start < piece.len() {
            let kind = self.line(piece, start, piece.len(), offset);
            each(start, piece.len(), kind);
        }
    }

    /// One line `piece[s..e]`, followed by a `\n` unless `e` is the end.
    /// Returns the kind of the statement the line belongs to.
    fn line(&mut self, piece: &mut [u8], s: usize, e: usize, offset: usize) -> Kind {
        let scan = &mut self.scan;
        let line = &mut piece[s..e];
        let first_part = self.continued.is_none();
        let kind = match self.continued.take() {
            Some(kind) => kind,
            // Shortcuts for nearly every line of a mesh, with the result
            // `classify_and_blank` would give (an ASCII keyword ended by a
            // space is exactly what `keyword` finds).
            None => match line {
                [b'v', b' ', ..] => {
                    scan.vertices += 1;
                    Kind::Vertex
                }
                [b'f', b' ', ..] => {
                    scan.faces += 1;
                    Kind::Face
                }
                [b'#', ..] => Kind::Comment,
                _ => classify_and_blank(line, scan),
            },
        };
        if kind == Kind::Group && first_part {
            self.model_faces = scan.faces;
            self.group_line = Some(line.to_vec());
        }
        if kind != Kind::Comment
            && let Some(backslash) = continuation(line)
        {
            if kind == Kind::Group {
                self.group_continued = true;
            }
            line[backslash..].fill(b' ');
            if e < piece.len() {
                piece[e] = b' ';
                scan.joins.push(offset + e);
                self.continued = Some(kind);
            }
        }
        if kind == Kind::Point {
            // The first part starts with the (blanked) keyword, now "#".
            let words = count_words(&piece[s..e]);
            scan.point_refs += if first_part {
                words.saturating_sub(1)
            } else {
                words
            };
        }
        kind
    }
}

/// Bit `i` set where `block[i]` (at most 64 bytes) is `\n`.
fn newline_bits(block: &[u8]) -> u64 {
    // SSE2 is part of x86-64: 16 compares and one mask extraction per 16
    // bytes (LLVM does not find this for the portable loop below, which it
    // turns into slow 64-bit shifts per byte).
    #[cfg(target_arch = "x86_64")]
    if block.len() == 64 {
        use std::arch::x86_64::{__m128i, _mm_cmpeq_epi8, _mm_movemask_epi8, _mm_set1_epi8};
        // SAFETY: these intrinsics only need SSE2, which every x86-64 CPU
        // has (it is part of the architecture's baseline target features).
        let bits = unsafe {
            let newline = _mm_set1_epi8(b'\n' as i8);
            let mut bits = 0u64;
            for (k, lane) in block.chunks_exact(16).enumerate() {
                let v: __m128i = bytemuck::pod_read_unaligned(lane);
                let mask = _mm_movemask_epi8(_mm_cmpeq_epi8(v, newline)) as u16;
                bits |= u64::from(mask) << (16 * k);
            }
            bits
        };
        return bits;
    }
    block
        .iter()
        .enumerate()
        .fold(0, |bits, (i, &b)| bits | (u64::from(b == b'\n') << i))
}

/// True if `bytes` are all ASCII and none is NUL: then they are valid UTF-8
/// without NUL, which is all `normalize_encoding` asks of most files. One
/// branch-free pass (it vectorises) instead of a NUL search plus UTF-8
/// validation.
fn plain_ascii(bytes: &[u8]) -> bool {
    const ONES: u64 = u64::from_ne_bytes([0x01; 8]);
    const HIGHS: u64 = u64::from_ne_bytes([0x80; 8]);
    let mut words = bytes.chunks_exact(8);
    // Per byte, the high bit of `x` flags non-ASCII, and that of
    // `(x - 1) & !x` flags zero if the byte and those below it are ASCII
    // (otherwise the word is flagged already).
    let flags = words.by_ref().fold(0u64, |flags, word| {
        let x = u64::from_le_bytes(word.try_into().expect("8 bytes"));
        flags | (x.wrapping_sub(ONES) & !x) | x
    });
    flags & HIGHS == 0 && words.remainder().iter().all(|&b| b != 0 && b.is_ascii())
}

/// Bytes per piece [`PrescanReader`] copies and pre-scans at a time: small
/// enough to stay in the L2 cache until tobj has read it.
const PIECE: usize = 64 << 10;

/// Faces after which [`PrescanReader`] ends tobj's current model at the next
/// piece boundary. Why: tobj keeps every face of a model until the model
/// ends, 104 bytes each (four 24-byte index triples and a tag), so a
/// one-object mesh of 871k triangles held 90 MB of faces: the largest
/// buffer of the whole build, and every page of it fresh. In blocks of this
/// many faces the buffer stays under 7 MB and is reused (tobj clears it).
/// Vertices used by two blocks are exported by both; welding merges them.
const MODEL_BLOCK_FACES: u64 = 1 << 16;

/// Gives tobj the pre-scanned text without modifying (or copying all of) the
/// original: each piece of whole lines is copied into a buffer, checked
/// (no NUL byte, valid UTF-8, as `normalize_encoding` requires) and
/// pre-scanned there just before tobj reads it.
struct PrescanReader<'a> {
    /// Text not yet copied.
    rest: &'a [u8],
    /// Offset of `rest` in the text.
    offset: usize,
    /// The current piece, pre-scanned, and how much of it tobj has read.
    piece: Vec<u8>,
    read: usize,
    scanner: Prescanner,
    /// Set (and reading fails) when a piece needs `normalize_encoding`.
    needs_decoding: bool,
    /// Before this offset of the text only `v` statements reach tobj (a
    /// reader made by [`PrescanReader::after`]); 0 for a whole text.
    vertices_until: usize,
    /// The scan's counts at `vertices_until`, once the reader is past it.
    before: Option<Prescan>,
    /// The current piece's `v` statements, as line ranges (scratch).
    kept: Vec<(usize, usize)>,
    /// Where this reader stops unless it claims the rest first (`claim`,
    /// [`parse_split`]); 0 for none. Set back to 0 when it claims it.
    stop_at: usize,
    claim: Option<&'a std::sync::atomic::AtomicBool>,
    /// The reader met the cut of a split parse and could not repeat the
    /// statement in force there (reading then fails).
    no_cut: bool,
}

impl<'a> PrescanReader<'a> {
    fn new(text: &'a [u8]) -> Self {
        Self {
            rest: text,
            offset: 0,
            piece: Vec::with_capacity(PIECE.min(text.len()) + 256),
            read: 0,
            scanner: Prescanner::default(),
            needs_decoding: false,
            vertices_until: 0,
            before: None,
            kept: Vec::new(),
            stop_at: 0,
            claim: None,
            no_cut: false,
        }
    }

    /// A reader of `text` from `split` on, for [`parse_split`]'s second
    /// thread: tobj gets the `v` statements of `text[..split]` (each as
    /// the pre-scan leaves it, continued lines joined), then the `o`/`g`
    /// statement in force at `split` (or the name tobj gives a model before
    /// any: `unnamed_object`), then the rest as from [`PrescanReader::new`].
    /// The scan counts every statement of the text; `before` keeps its
    /// counts at `split`. `split` must start a line that no statement
    /// before it continues onto (reading fails otherwise).
    fn after(text: &'a [u8], split: usize) -> Self {
        let mut reader = Self::new(text);
        reader.vertices_until = split;
        reader
    }

    /// Whether tobj read the whole text, and all of it could be read.
    fn finished(&self) -> bool {
        self.rest.is_empty() && !self.needs_decoding
    }

    /// Drops every line of the (pre-scanned) piece but those of `v`
    /// statements.
    fn keep_vertices(&mut self) {
        let Self {
            piece,
            scanner,
            kept,
            offset,
            ..
        } = self;
        kept.clear();
        scanner.run_with(piece, *offset, |s, e, kind| {
            if kind == Kind::Vertex {
                kept.push((s, e));
            }
        });
        let mut to = 0;
        for &(s, e) in kept.iter() {
            // With its `\n`, or the space that joins it to the statement's
            // next line.
            let e = (e + 1).min(piece.len());
            piece.copy_within(s..e, to);
            to += e - s;
        }
        piece.truncate(to);
    }

    fn next_piece(&mut self) -> std::io::Result<()> {
        // At the cut of a split parse ([`parse_split`]): this reader reads
        // on if it claims the rest, else the rest is the other's.
        let mut cut = false;
        if self.stop_at > 0 && self.offset == self.stop_at {
            let claimed = self
                .claim
                .is_some_and(|c| c.swap(true, std::sync::atomic::Ordering::AcqRel));
            if claimed {
                // The end of this reader's text.
                self.piece.clear();
                self.read = 0;
                self.rest = &[];
                return Ok(());
            }
            self.stop_at = 0;
            cut = true;
        }
        let rest = self.rest;
        // Whole lines: up to the first `\n` at or after PIECE bytes (a
        // `\n` is ASCII, so pieces also split the text between characters).
        // No piece crosses `vertices_until` or `stop_at`, lines' starts.
        let bound = [self.vertices_until, self.stop_at]
            .into_iter()
            .filter(|&b| b > self.offset)
            .min();
        let limit = bound.map_or(rest.len(), |b| b - self.offset);
        let want = PIECE.min(limit);
        let end = find_newline(&rest[want - 1..limit]).map_or(limit, |i| want + i);
        let (piece, rest) = rest.split_at(end);
        if !plain_ascii(piece) && (piece.contains(&0) || std::str::from_utf8(piece).is_err()) {
            self.needs_decoding = true;
            return Err(std::io::Error::other("text needs decoding"));
        }
        self.piece.clear();
        if self.offset < self.vertices_until {
            self.piece.extend_from_slice(piece);
            self.keep_vertices();
            self.offset += end;
            self.rest = rest;
            self.read = 0;
            return Ok(());
        }
        let sc = &mut self.scanner;
        if self.vertices_until > 0 && self.before.is_none() {
            // The first piece after the first part's vertices.
            let scan = &sc.scan;
            self.before = Some(Prescan {
                vertices: scan.vertices,
                faces: scan.faces,
                line_statements: scan.line_statements,
                point_statements: scan.point_statements,
                point_refs: scan.point_refs,
                joins: Vec::new(),
            });
            cut = true;
        }
        // A repeated statement must be whole.
        if cut && (sc.continued.is_some() || sc.group_continued) {
            self.no_cut = true;
            return Err(std::io::Error::other("no place to cut the text"));
        }
        if cut || (sc.scan.faces - sc.model_faces >= MODEL_BLOCK_FACES && !sc.group_continued) {
            // Repeat the current model's `o`/`g` statement: tobj ends the
            // model there, exports it and reuses its face buffer. The
            // models have the same name, and `build_soup` merges them
            // back into one part. At a split parse's cut either reader
            // does so, so that the models are the same whichever reads
            // the rest.
            match &sc.group_line {
                Some(line) => self.piece.extend_from_slice(line),
                None => self.piece.extend_from_slice(b"o unnamed_object"),
            }
            self.piece.push(b'\n');
            sc.model_faces = sc.scan.faces;
        }
        let injected = self.piece.len();
        self.piece.extend_from_slice(piece);
        self.scanner.run(&mut self.piece[injected..], self.offset);
        self.offset += end;
        self.rest = rest;
        self.read = 0;
        Ok(())
    }
}

impl std::io::Read for PrescanReader<'_> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        use std::io::BufRead;
        let available = self.fill_buf()?;
        let n = available.len().min(out.len());
        out[..n].copy_from_slice(&available[..n]);
        self.consume(n);
        Ok(n)
    }
}

impl std::io::BufRead for PrescanReader<'_> {
    // Called for every line tobj reads.
    #[inline]
    fn fill_buf(&mut self) -> std::io::Result<&[u8]> {
        if self.read < self.piece.len() {
            return Ok(&self.piece[self.read..]);
        }
        if self.needs_decoding {
            return Err(std::io::Error::other("text needs decoding"));
        }
        // A loop: a piece of a text's first part may hold no `v` statement
        // (`PrescanReader::after`), and an empty slice would mean the end.
        while self.read == self.piece.len() && !self.rest.is_empty() {
            self.next_piece()?;
        }
        Ok(&self.piece[self.read..])
    }

    #[inline]
    fn consume(&mut self, n: usize) {
        self.read = (self.read + n).min(self.piece.len());
    }
}

/// Classifies a statement by its keyword, counts it and blanks it if tobj
/// should not see it.
fn classify_and_blank(line: &mut [u8], scan: &mut Prescan) -> Kind {
    let (s, e) = keyword(line);
    let (kind, blank) = match &line[s..e] {
        b"v" => {
            scan.vertices += 1;
            (Kind::Vertex, false)
        }
        b"f" => {
            scan.faces += 1;
            (Kind::Face, false)
        }
        b"l" => {
            scan.line_statements += 1;
            (Kind::Line, true)
        }
        b"p" => {
            scan.point_statements += 1;
            (Kind::Point, true)
        }
        b"o" | b"g" => (Kind::Group, false),
        b"vt" | b"vn" | b"vp" | b"usemtl" | b"mtllib" => (Kind::Other, true),
        [b'#', ..] => (Kind::Comment, false),
        _ => (Kind::Other, false),
    };
    if blank {
        line[s] = b'#';
        line[s + 1..e].fill(b' ');
    }
    kind
}

/// Position of a line-continuation backslash (last non-blank byte), if any.
fn continuation(line: &[u8]) -> Option<usize> {
    let mut e = line.len();
    while e > 0 && is_blank(line[e - 1]) {
        e -= 1;
    }
    if e > 0 && line[e - 1] == b'\\' {
        Some(e - 1)
    } else {
        None
    }
}

// ---------------------------------------------------------------------------
// Parsing with tobj
// ---------------------------------------------------------------------------

/// Material loader for tobj. `mtllib` lines are blanked, so it is never
/// called; should it be, it reads nothing and reports no materials, so a
/// missing `.mtl` can never fail the load.
fn no_materials(_: &Path) -> tobj::MTLLoadResult {
    Ok(Default::default())
}

fn run_tobj(reader: &mut impl std::io::BufRead) -> Result<Vec<tobj::Model>, tobj::LoadError> {
    // Untriangulated (tobj only fans, wrong for concave polygons) and one
    // index per attribute (single_index would split vertices at UV/normal
    // seams, which the weld step would then have to undo). Points and lines
    // are kept so they can be counted from `face_arities`.
    let options = tobj::LoadOptions {
        single_index: false,
        triangulate: false,
        ignore_points: false,
        ignore_lines: false,
    };
    let (models, _materials) = tobj::load_obj_buf(reader, &options, no_materials)?;
    Ok(models)
}

/// Runs tobj; on a recoverable error repairs the text in place and retries,
/// otherwise explains the error with a line number.
fn parse_with_repairs(
    text: &mut [u8],
    scan: &Prescan,
    warnings: &mut Vec<String>,
) -> Result<Vec<tobj::Model>, String> {
    use tobj::LoadError as E;
    let mut repaired_vertices = false;
    let mut stripped_colors = false;
    loop {
        let err = match run_tobj(&mut &*text) {
            Ok(models) => return Ok(models),
            Err(err) => err,
        };
        let strip = err == E::FaceColorOutOfBounds;
        let may_repair = match err {
            E::PositionParseError | E::ColorParseError => !repaired_vertices,
            E::FaceColorOutOfBounds => !stripped_colors,
            _ => false,
        };
        if may_repair && repair_vertex_lines(text, scan, strip, warnings)? {
            repaired_vertices = true;
            stripped_colors |= strip;
            continue;
        }
        return Err(diagnose(text, scan, err));
    }
}

/// Fixes `v` lines tobj rejects although their geometry is clear, in place
/// (same length, so line numbers stay right). Returns whether anything
/// changed; fails with a message for a line that cannot be read at all.
///
/// * A coordinate with trailing junk, such as `3.1+e2`, is read by its longest
///   valid prefix (`3.1`), as C's `strtod` and most OBJ readers do; not when
///   the junk starts with `,` (a decimal comma would silently give wrong
///   geometry).
/// * A vertex with 5 or more than 6 values (neither `x y z`, `x y z w` nor
///   `x y z r g b`) keeps `x y z`.
/// * With `strip_colors`, vertex colours are removed from every vertex: tobj
///   fails when only some vertices have colours, and svpack does not use them.
fn repair_vertex_lines(
    text: &mut [u8],
    scan: &Prescan,
    strip_colors: bool,
    warnings: &mut Vec<String>,
) -> Result<bool, String> {
    let mut fixed_numbers = 0usize;
    let mut first_fix = String::new();
    let mut odd_counts = 0usize;
    let mut first_odd = 0usize;
    let mut colored = 0usize;
    let mut lines = Lines::default();
    let mut index = 0usize;
    while let Some((s, e)) = lines.next(text) {
        let line_no = scan.line_number(index, s);
        index += 1;
        let Ok(line) = std::str::from_utf8(&text[s..e]) else {
            continue;
        };
        let words = words(line);
        if words.first().is_none_or(|&(a, b)| &line[a..b] != "v") {
            continue;
        }
        let values = words.len() - 1;
        if values < 3 {
            return Err(format!(
                "line {line_no}: vertex has {values} coordinate(s), expected 3"
            ));
        }
        // (start, end) byte ranges within the line to overwrite with spaces.
        let mut blank: Vec<(usize, usize)> = Vec::new();
        let numeric = if values == 4 { 4 } else { 3 };
        for &(a, b) in &words[1..=numeric] {
            let word = &line[a..b];
            if word.parse::<f32>().is_ok() {
                continue;
            }
            match longest_float_prefix(word) {
                Some((len, value)) if !word[len..].starts_with(',') => {
                    if fixed_numbers == 0 {
                        first_fix = format!("line {line_no}: {word:?} read as {value}");
                    }
                    fixed_numbers += 1;
                    blank.push((a + len, b));
                }
                _ => {
                    return Err(format!(
                        "line {line_no}: cannot parse vertex coordinate {word:?}"
                    ));
                }
            }
        }
        let keep = match values {
            3 | 4 => values,
            6 if !strip_colors => 6,
            6 => {
                colored += 1;
                3
            }
            _ => {
                if odd_counts == 0 {
                    first_odd = line_no;
                }
                odd_counts += 1;
                3
            }
        };
        if keep < values {
            blank.push((words[keep + 1].0, line.len()));
        }
        for (a, b) in blank {
            text[s + a..s + b].fill(b' ');
        }
    }
    if fixed_numbers > 0 {
        warnings.push(format!(
            "{fixed_numbers} malformed number(s) in vertex lines read by their longest \
             valid prefix, as C's strtod does (first: {first_fix})"
        ));
    }
    if odd_counts > 0 {
        warnings.push(format!(
            "{odd_counts} vertex line(s) with neither 3, 4 nor 6 values; used x y z only \
             (first: line {first_odd})"
        ));
    }
    if colored > 0 {
        warnings.push(
            "vertex colours ignored: only some vertices have them, which tobj cannot load"
                .to_string(),
        );
    }
    Ok(fixed_numbers + odd_counts + colored > 0)
}

/// Longest prefix of `word` that parses as `f32`, with its length and value.
fn longest_float_prefix(word: &str) -> Option<(usize, f32)> {
    (1..word.len())
        .rev()
        .filter(|&end| word.is_char_boundary(end))
        .find_map(|end| word[..end].parse::<f32>().ok().map(|v| (end, v)))
}

/// Turns a tobj error (which has no position) into a message naming the line.
fn diagnose(text: &[u8], scan: &Prescan, err: tobj::LoadError) -> String {
    use tobj::LoadError as E;
    let mut lines = Lines::default();
    let mut index = 0usize;
    let mut vertices_so_far = 0i64;
    let total_vertices = scan.vertices;
    while let Some((s, e)) = lines.next(text) {
        let line_no = scan.line_number(index, s);
        index += 1;
        let Ok(line) = std::str::from_utf8(&text[s..e]) else {
            if err == E::ReadError {
                return format!("line {line_no}: not valid UTF-8 text; OBJ must be ASCII/UTF-8");
            }
            continue;
        };
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.first().copied() {
            Some("v") => {
                vertices_so_far += 1;
                if let Some(msg) = vertex_problem(&words[1..]) {
                    return format!("line {line_no}: {msg}");
                }
            }
            Some("f") => {
                for corner in &words[1..] {
                    if let Some(msg) = corner_problem(corner, vertices_so_far, total_vertices) {
                        return format!("line {line_no}: {msg}");
                    }
                }
            }
            _ => {}
        }
    }
    match err {
        E::FaceVertexOutOfBounds => "a face refers to a vertex that is only defined after the \
             end of the face's object/group; tobj cannot load such forward references"
            .to_string(),
        E::FaceColorOutOfBounds => {
            "vertex colours are given for only some vertices; tobj cannot load this".to_string()
        }
        other => format!("OBJ parse error: {other}"),
    }
}

/// What tobj would reject about a `v` statement with values `values`.
fn vertex_problem(values: &[&str]) -> Option<String> {
    if values.len() < 3 {
        return Some(format!(
            "vertex has {} coordinate(s), expected 3",
            values.len()
        ));
    }
    let numeric = if values.len() == 4 { 4 } else { 3 };
    if let Some(bad) = values[..numeric].iter().find(|v| v.parse::<f32>().is_err()) {
        return Some(format!("cannot parse vertex coordinate {bad:?}"));
    }
    if values.len() == 4 && values[3].parse::<f32>() == Ok(0.0) {
        return Some("vertex has w = 0 (a point at infinity); cannot divide by it".to_string());
    }
    if values.len() == 5 || values.len() > 6 {
        return Some(format!(
            "vertex has {} values, expected x y z, x y z w or x y z r g b",
            values.len()
        ));
    }
    None
}

/// What tobj would reject about a face corner such as `-3/1/2`, given the
/// number of vertices defined before the face and in the whole file.
fn corner_problem(corner: &str, so_far: i64, total: u64) -> Option<String> {
    let parts: Vec<&str> = corner.split('/').collect();
    if parts.len() > 3 {
        return Some(format!(
            "face corner {corner:?} has more than three '/'-separated indices"
        ));
    }
    if parts
        .iter()
        .any(|p| !p.is_empty() && p.parse::<isize>().is_err())
    {
        return Some(format!("cannot parse face corner {corner:?}"));
    }
    let v = parts[0];
    if v.is_empty() {
        return Some(format!("face corner {corner:?} has no vertex index"));
    }
    let index: i64 = v.parse().ok()?;
    if index == 0 {
        return Some(format!(
            "vertex index 0 in face corner {corner:?} is invalid (OBJ indices start at 1)"
        ));
    }
    if index < 0 && so_far + index < 0 {
        return Some(format!(
            "relative vertex index {index} points before the first vertex \
             ({so_far} vertices defined so far)"
        ));
    }
    if index > 0 && index as u64 > total {
        return Some(format!(
            "vertex index {index} out of range (the file defines {total} vertices)"
        ));
    }
    None
}

// ---------------------------------------------------------------------------
// Building the soup
// ---------------------------------------------------------------------------

/// Concatenates tobj's models into one soup, triangulating polygons.
fn build_soup(models: Vec<tobj::Model>, warnings: &mut Vec<String>) -> Result<Soup, String> {
    let total_positions: usize = models.iter().map(|m| m.mesh.positions.len() / 3).sum();
    if u32::try_from(total_positions).is_err() {
        return Err(format!(
            "too many vertices ({total_positions}; at most {} are supported)",
            u32::MAX
        ));
    }
    let total_indices: usize = models.iter().map(|m| m.mesh.indices.len()).sum();

    let mut soup = Soup::default();
    let mut triangulator = Triangulator::default();
    let mut empty_faces = 0u64;

    for model in models {
        let name = model.name;
        let tobj::Mesh {
            positions,
            indices,
            face_arities,
            ..
        } = model.mesh;
        let internal =
            |what: &str| format!("internal error: tobj returned {what} for object {name:?}");
        if !positions.len().is_multiple_of(3) {
            return Err(internal("a partial position"));
        }
        let vertex_count = positions.len() / 3;
        // tobj's indices point into the model's own positions; it should
        // never produce one out of range, but a wrong index here would only
        // surface far away, so check (one tight pass: `max` vectorises,
        // `find` with its early exit does not).
        if indices
            .iter()
            .copied()
            .max()
            .is_some_and(|max| max as usize >= vertex_count)
        {
            let bad = indices
                .iter()
                .find(|&&i| i as usize >= vertex_count)
                .copied()
                .unwrap_or_default();
            return Err(format!(
                "object {name:?}: vertex index {bad} out of range ({vertex_count} vertices)"
            ));
        }
        let all_triangles = face_arities.is_empty();
        // tobj leaves face_arities empty when every face is a triangle.
        if all_triangles && !indices.len().is_multiple_of(3) {
            return Err(internal("a partial triangle"));
        }
        // Fits: the total was checked above.
        let base = soup.positions.len() as u32;
        if soup.positions.is_empty() {
            // The first model's buffer becomes the soup's (a single-object
            // file is then not copied at all, nor are fresh pages faulted
            // in); later models are appended to it.
            soup.positions = into_triples(positions);
            soup.positions
                .reserve_exact(total_positions - soup.positions.len());
        } else {
            soup.positions
                .extend(positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        }
        // This model's positions, flat, as the triangulator reads them.
        let model_positions = soup.positions[base as usize..].as_flattened();

        let first_index = soup.indices.len();
        if all_triangles {
            if soup.indices.is_empty() && base == 0 {
                // Same as for the positions: nothing to offset, so no copy.
                soup.indices = indices;
                soup.indices.reserve(total_indices - soup.indices.len());
            } else {
                soup.indices.extend(indices.iter().map(|&i| base + i));
            }
        } else {
            if soup.indices.capacity() == 0 {
                soup.indices.reserve(total_indices);
            }
            let mut offset = 0usize;
            for &arity in &face_arities {
                let n = arity as usize;
                let Some(corners) = indices.get(offset..offset + n) else {
                    return Err(internal("face arities longer than its indices"));
                };
                offset += n;
                match n {
                    0 => empty_faces += 1,
                    1 => soup.stats.skipped_points += 1,
                    2 => soup.stats.skipped_lines += 1,
                    3 => soup.indices.extend_from_slice(&[
                        base + corners[0],
                        base + corners[1],
                        base + corners[2],
                    ]),
                    _ => triangulator.polygon(
                        model_positions,
                        corners,
                        base,
                        &mut soup.indices,
                        &name,
                    ),
                }
            }
            if offset != indices.len() {
                return Err(internal("indices not covered by face arities"));
            }
        }

        let first_triangle = first_index / 3;
        let triangle_count = soup.indices.len() / 3 - first_triangle;
        if triangle_count == 0 {
            continue;
        }
        let (Ok(first_triangle), Ok(triangle_count)) = (
            u32::try_from(first_triangle),
            u32::try_from(soup.indices.len() / 3),
        ) else {
            return Err(format!(
                "too many triangles (at most {} are supported)",
                u32::MAX
            ));
        };
        let triangle_count = triangle_count - first_triangle;
        let part_name = format!("object {name:?}");
        match soup.parts.last_mut() {
            // tobj splits a model where `usemtl` changes or a group name
            // repeats; to the user that is still one object.
            Some(last) if last.name == part_name => last.triangle_count += triangle_count,
            _ => soup.parts.push(Part {
                name: part_name,
                first_triangle,
                triangle_count,
            }),
        }
    }

    soup.stats.primitives = soup.parts.len() as u64;
    if empty_faces > 0 {
        warnings.push(format!(
            "{empty_faces} face statement(s) without vertices ignored"
        ));
    }
    if triangulator.fallbacks > 0 {
        warnings.push(format!(
            "{} polygon(s) are degenerate or self-intersecting and were triangulated as a fan \
             (first in object {:?})",
            triangulator.fallbacks, triangulator.first_fallback
        ));
    }
    Ok(soup)
}

/// `flat` (x, y, z, x, y, z, ...) as points, reusing its allocation when
/// that is possible (it always is with the system allocator).
fn into_triples(mut flat: Vec<f32>) -> Vec<[f32; 3]> {
    debug_assert!(flat.len().is_multiple_of(3));
    // Shrinking gives the block back in place (no copy); bytemuck reuses the
    // block when its capacity is a whole number of points.
    flat.shrink_to_fit();
    bytemuck::allocation::try_cast_vec(flat)
        .unwrap_or_else(|(_, flat)| flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

// ---------------------------------------------------------------------------
// Polygon triangulation
// ---------------------------------------------------------------------------

/// Triangulates faces with 4 or more corners; keeps scratch buffers so the
/// hot loop does not allocate (earcutr's own result vector aside).
#[derive(Default)]
struct Triangulator {
    /// Corner positions relative to the first corner (precision for far-off models).
    points: Vec<[f64; 3]>,
    /// The same, projected to 2D, flat `x, y` pairs as earcutr wants them.
    flat: Vec<f64>,
    /// Triangles of the current face as corner numbers, 3 per triangle.
    triangles: Vec<usize>,
    /// The face's vertex indices, sorted, to find repeats.
    sorted: Vec<u32>,
    /// Which corners earcutr's output uses.
    used: Vec<bool>,
    /// Per boundary edge `i -> i+1`: uses in that direction and reversed.
    forward: Vec<u8>,
    backward: Vec<u8>,
    /// Interior edges as (vertex pair key, triangle slot), for flipping.
    edges: Vec<(u64, usize)>,
    /// Triangles already changed in the current flip sweep.
    touched: Vec<bool>,
    /// Polygons that had to be fanned because ear clipping failed.
    fallbacks: u64,
    first_fallback: String,
}

impl Triangulator {
    /// Appends `corners.len() - 2` triangles for the face `corners` (indices
    /// into `positions`, flat xyz), offset by `base`, with the face's winding.
    fn polygon(
        &mut self,
        positions: &[f32],
        corners: &[u32],
        base: u32,
        out: &mut Vec<u32>,
        object: &str,
    ) {
        let at = |c: u32| -> [f64; 3] {
            let k = c as usize * 3;
            [
                f64::from(positions[k]),
                f64::from(positions[k + 1]),
                f64::from(positions[k + 2]),
            ]
        };
        if corners.len() == 4 {
            // Relative to the first corner: small quads far from the origin
            // keep their precision.
            let o = at(corners[0]);
            let rel = |k: usize| sub(at(corners[k]), o);
            let quad = [rel(0), rel(1), rel(2), rel(3)];
            for k in split_quad(&quad) {
                out.push(base + corners[k]);
            }
            return;
        }

        let origin = at(corners[0]);
        self.points.clear();
        self.points.extend(corners.iter().map(|&c| {
            let p = at(c);
            [p[0] - origin[0], p[1] - origin[1], p[2] - origin[2]]
        }));
        let normal = newell(&self.points);
        let length = dot(normal, normal).sqrt();
        if !length.is_finite() || length == 0.0 {
            // NaN/Inf corners or no area at all: nothing to clip ears from.
            self.fan(corners, base, out, object);
            return;
        }
        // Project onto the plane perpendicular to the Newell normal, with a
        // basis (u, v) such that u x v = normal: the face's winding becomes
        // counter-clockwise in 2D, and a 2D triangle's signed area is its 3D
        // vector area along the normal. For planar faces this is equivalent
        // to dropping the normal's dominant axis; for warped ones it keeps
        // triangles facing the way of the face where an axis projection can
        // fold corners onto each other.
        let n = normal.map(|c| c / length);
        let u = normalize(cross(n, least_axis(n)));
        let v = cross(n, u);
        self.flat.clear();
        for &p in &self.points {
            self.flat.push(dot(p, u));
            self.flat.push(dot(p, v));
        }
        let n = corners.len();
        let mut triangles = std::mem::take(&mut self.triangles);
        triangles.clear();
        if is_convex(&self.flat) {
            for i in 1..n - 1 {
                triangles.extend_from_slice(&[0, i, i + 1]);
            }
        } else {
            // A face that visits the same vertices over and over (a malformed
            // test file repeats one quad's corners some 900 times) is not a
            // polygon; ear clipping would only fail on it, in cubic time. Real
            // polygons repeat a vertex only where a bridge joins a hole to the
            // outline: two repeats per hole of at least three corners.
            self.sorted.clear();
            self.sorted.extend_from_slice(corners);
            self.sorted.sort_unstable();
            let repeats = self.sorted.windows(2).filter(|w| w[0] == w[1]).count();
            let clipped = if 2 * repeats > n {
                None
            } else {
                earcutr::earcut(&self.flat, &[], 2).ok()
            };
            match clipped {
                Some(clipped) => triangles = clipped,
                None => {
                    self.triangles = triangles;
                    self.fan(corners, base, out, object);
                    return;
                }
            }
            if !self.complete(&mut triangles, n) {
                self.triangles = triangles;
                self.fan(corners, base, out, object);
                return;
            }
        }
        // Also for convex faces: a fan from corner 0 makes a sliver wherever
        // a neighbouring corner is (nearly) flat.
        self.flip_to_delaunay(&mut triangles, n);
        out.extend(triangles.iter().map(|&i| base + corners[i]));
        // Keep the buffer (earcutr's, if it made one) for the next face.
        self.triangles = triangles;
    }

    /// Fan fallback for polygons ear clipping cannot handle.
    fn fan(&mut self, corners: &[u32], base: u32, out: &mut Vec<u32>, object: &str) {
        if self.fallbacks == 0 {
            self.first_fallback = object.to_string();
        }
        self.fallbacks += 1;
        emit_fan(corners, base, out);
    }

    /// Checks and completes earcutr's triangles (corner numbers `0..n`) so
    /// they triangulate the whole boundary with the face's winding. Returns
    /// false if they cannot be made to.
    ///
    /// earcutr drops corners that repeat their neighbour or lie on the line
    /// between their neighbours. Those corners still bound the neighbouring
    /// faces, so leaving them out would open a crack in the mesh topology;
    /// they are put back by splitting the triangle on the shortened edge.
    /// earcutr also normalises orientation (its triangles turn the same way
    /// whatever the input's winding), so the winding is set afterwards from
    /// the direction in which the boundary edges appear.
    fn complete(&mut self, triangles: &mut Vec<usize>, n: usize) -> bool {
        if !triangles.len().is_multiple_of(3) || triangles.iter().any(|&i| i >= n) {
            return false;
        }
        self.used.clear();
        self.used.resize(n, false);
        for &i in triangles.iter() {
            self.used[i] = true;
        }
        let Some(start) = self.used.iter().position(|&u| u) else {
            return false;
        };
        // Walk the boundary once from a used corner; every gap between two
        // used corners p and q is a run of dropped corners.
        let mut p = start;
        for step in 1..=n {
            let q = (start + step) % n;
            if !self.used[q] {
                continue;
            }
            if q != (p + 1) % n && !reinsert_run(triangles, p, q, n) {
                return false;
            }
            p = q;
        }

        if triangles.len() != 3 * (n - 2) {
            return false;
        }
        self.forward.clear();
        self.forward.resize(n, 0);
        self.backward.clear();
        self.backward.resize(n, 0);
        for t in triangles.chunks_exact(3) {
            if t[0] == t[1] || t[1] == t[2] || t[2] == t[0] {
                return false;
            }
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                if b == (a + 1) % n {
                    self.forward[a] = self.forward[a].saturating_add(1);
                } else if a == (b + 1) % n {
                    self.backward[b] = self.backward[b].saturating_add(1);
                }
            }
        }
        // A triangulation of the polygon uses each boundary edge exactly once,
        // all in the same direction.
        let all_forward =
            self.forward.iter().all(|&c| c == 1) && self.backward.iter().all(|&c| c == 0);
        let all_backward =
            self.backward.iter().all(|&c| c == 1) && self.forward.iter().all(|&c| c == 0);
        if all_backward {
            for t in triangles.chunks_exact_mut(3) {
                t.swap(1, 2);
            }
        }
        all_forward || all_backward
    }
}

impl Triangulator {
    /// Lawson edge flips towards the constrained Delaunay triangulation of
    /// the projected polygon (`self.flat`), given valid counter-clockwise
    /// `triangles`. Why: ear clipping happily cuts zero-area slivers where a
    /// reflex corner lies on a diagonal (an L shape whose inner corner is on
    /// the line between two outer ones, common in architectural models once
    /// rounding moves it a hair). A later stage drops such slivers, leaving a
    /// crack inside the face that would cast a false silhouette. Flipping
    /// only where the quad is strictly convex keeps the triangulation valid;
    /// the predicates are exact, so the sweeps end (capped anyway).
    fn flip_to_delaunay(&mut self, triangles: &mut [usize], n: usize) {
        use robust::{Coord, incircle, orient2d};
        let flat = &self.flat;
        let pt = |i: usize| Coord {
            x: flat[2 * i],
            y: flat[2 * i + 1],
        };
        for _sweep in 0..n + 8 {
            self.edges.clear();
            for (slot, &a) in triangles.iter().enumerate() {
                let b = triangles[slot - slot % 3 + (slot + 1) % 3];
                if b != (a + 1) % n && a != (b + 1) % n {
                    let key = ((a.min(b) as u64) << 32) | a.max(b) as u64;
                    self.edges.push((key, slot));
                }
            }
            self.edges.sort_unstable();
            self.touched.clear();
            self.touched.resize(triangles.len() / 3, false);
            let mut flipped = false;
            for pair in self.edges.windows(2) {
                let [(k1, s1), (k2, s2)] = [pair[0], pair[1]];
                let (t1, t2) = (s1 / 3, s2 / 3);
                if k1 != k2 || t1 == t2 || self.touched[t1] || self.touched[t2] {
                    continue;
                }
                // Triangle t1 = (a, b, c) with the shared edge a -> b at its
                // slot; triangle t2 must run the edge the other way, b -> a.
                let at = |t: usize, k: usize| triangles[3 * t + k % 3];
                let (a, b, c) = (at(t1, s1), at(t1, s1 + 1), at(t1, s1 + 2));
                if at(t2, s2) != b || at(t2, s2 + 1) != a {
                    continue;
                }
                let d = at(t2, s2 + 2);
                if incircle(pt(a), pt(b), pt(c), pt(d)) > 0.0
                    && orient2d(pt(c), pt(a), pt(d)) > 0.0
                    && orient2d(pt(d), pt(b), pt(c)) > 0.0
                {
                    triangles[3 * t1..3 * t1 + 3].copy_from_slice(&[c, a, d]);
                    triangles[3 * t2..3 * t2 + 3].copy_from_slice(&[d, b, c]);
                    self.touched[t1] = true;
                    self.touched[t2] = true;
                    flipped = true;
                }
            }
            if !flipped {
                break;
            }
        }
    }
}

/// Replaces the triangle on edge `p`-`q` by a fan through the corners strictly
/// between `p` and `q` (boundary order), keeping its orientation.
fn reinsert_run(triangles: &mut Vec<usize>, p: usize, q: usize, n: usize) -> bool {
    let mut found = None;
    for (j, t) in triangles.chunks_exact(3).enumerate() {
        for k in 0..3 {
            let (a, b, c) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
            if (a, b) == (p, q) {
                found = Some((j, c, true));
            } else if (a, b) == (q, p) {
                found = Some((j, c, false));
            }
        }
        if found.is_some() {
            break;
        }
    }
    let Some((j, apex, forward)) = found else {
        return false;
    };
    let mut prev = p;
    let mut first = true;
    let mut corner = (p + 1) % n;
    loop {
        let tri = if forward {
            [prev, corner, apex]
        } else {
            [corner, prev, apex]
        };
        if first {
            triangles[3 * j..3 * j + 3].copy_from_slice(&tri);
            first = false;
        } else {
            triangles.extend_from_slice(&tri);
        }
        if corner == q {
            return true;
        }
        prev = corner;
        corner = (corner + 1) % n;
    }
}

/// Appends the fan `(0, i, i+1)` of `corners`.
fn emit_fan(corners: &[u32], base: u32, out: &mut Vec<u32>) {
    for i in 1..corners.len() - 1 {
        out.extend_from_slice(&[base + corners[0], base + corners[i], base + corners[i + 1]]);
    }
}

/// Corner order (two triangles) for a quad, keeping its winding: the
/// diagonal whose smaller triangle is larger. The turn at corner `i` (its
/// edges' cross product along the Newell normal) is twice the area of the
/// triangle cut off at `i`, so the diagonal 0-2 makes triangles of areas
/// `turn[1]` and `turn[3]`, the diagonal 1-3 `turn[0]` and `turn[2]`. For a
/// concave quad this picks the diagonal from the reflex corner (its turn is
/// negative), the only correct split; for a convex one it avoids a sliver
/// at a (nearly) flat corner.
fn split_quad(q: &[[f64; 3]; 4]) -> [usize; 6] {
    let normal = newell(q);
    let turn = |i: usize| {
        let (prev, next) = (q[(i + 3) % 4], q[(i + 1) % 4]);
        dot(cross(sub(q[i], prev), sub(next, q[i])), normal)
    };
    let (t0, t1, t2, t3) = (turn(0), turn(1), turn(2), turn(3));
    // NaN compares false: the default split 0-2.
    if t0.min(t2) > t1.min(t3) {
        [1, 2, 3, 3, 0, 1]
    } else {
        [0, 1, 2, 0, 2, 3]
    }
}

/// True if the 2D polygon (flat `x, y` pairs) is strictly convex, simple and
/// counter-clockwise: every corner turns left and the edge directions go
/// round only once (the edges' x component changes sign at most twice; a
/// pentagram turns left everywhere but goes round twice).
fn is_convex(flat: &[f64]) -> bool {
    let n = flat.len() / 2;
    let pt = |i: usize| (flat[2 * (i % n)], flat[2 * (i % n) + 1]);
    let mut changes = 0;
    let mut first_dx = 0.0f64;
    let mut last_dx = 0.0f64;
    for i in 0..n {
        let (x0, y0) = pt(i);
        let (x1, y1) = pt(i + 1);
        let (x2, y2) = pt(i + 2);
        let turn = (x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1);
        if turn <= 0.0 || turn.is_nan() {
            return false;
        }
        let dx = x1 - x0;
        if dx != 0.0 {
            if last_dx != 0.0 && (dx > 0.0) != (last_dx > 0.0) {
                changes += 1;
            }
            if first_dx == 0.0 {
                first_dx = dx;
            }
            last_dx = dx;
        }
    }
    if first_dx != 0.0 && (first_dx > 0.0) != (last_dx > 0.0) {
        changes += 1;
    }
    changes <= 2
}

/// Newell normal: twice the vector area of the closed polygon `points`.
fn newell(points: &[[f64; 3]]) -> [f64; 3] {
    let mut n = [0.0; 3];
    let count = points.len();
    for (i, c) in points.iter().enumerate() {
        let d = points[(i + 1) % count];
        n[0] += (c[1] - d[1]) * (c[2] + d[2]);
        n[1] += (c[2] - d[2]) * (c[0] + d[0]);
        n[2] += (c[0] - d[0]) * (c[1] + d[1]);
    }
    n
}

/// Unit vector along the coordinate axis least aligned with `n`.
fn least_axis(n: [f64; 3]) -> [f64; 3] {
    let a = n.map(f64::abs);
    if a[0] <= a[1] && a[0] <= a[2] {
        [1.0, 0.0, 0.0]
    } else if a[1] <= a[2] {
        [0.0, 1.0, 0.0]
    } else {
        [0.0, 0.0, 1.0]
    }
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    a.map(|c| c / l)
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri_area_2d(flat: &[f64], t: &[usize]) -> f64 {
        let p = |i: usize| (flat[2 * i], flat[2 * i + 1]);
        let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
        ((b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)) / 2.0
    }

    #[test]
    fn corner_dropped_by_earcut_is_put_back() {
        // An L whose corner 1 repeats corner 2; earcutr drops one of them.
        let flat = [
            2.0, 0.0, 2.0, 1.0, 2.0, 1.0, 1.0, 1.0, 1.0, 2.0, 0.0, 2.0, 0.0, 0.0,
        ];
        let mut t = earcutr::earcut(&flat, &[], 2).unwrap();
        assert!(t.len() < 15, "earcutr no longer drops the repeat: {t:?}");
        let mut tr = Triangulator::default();
        assert!(tr.complete(&mut t, 7));
        assert_eq!(t.len(), 15);
        assert!((0..7).all(|i| t.contains(&i)), "{t:?}");
        let area: f64 = t.chunks(3).map(|c| tri_area_2d(&flat, c)).sum();
        assert!((area - 3.0).abs() < 1e-12, "area {area}");
        assert!(t.chunks(3).all(|c| tri_area_2d(&flat, c) >= 0.0));
    }

    #[test]
    fn clockwise_input_keeps_its_winding() {
        // earcutr orients its output its own way; `complete` turns it back.
        let flat = [0.0, 0.0, 0.0, 2.0, 1.0, 2.0, 1.0, 1.0, 2.0, 1.0, 2.0, 0.0];
        let mut t = earcutr::earcut(&flat, &[], 2).unwrap();
        let mut tr = Triangulator::default();
        assert!(tr.complete(&mut t, 6));
        let areas: Vec<f64> = t.chunks(3).map(|c| tri_area_2d(&flat, c)).collect();
        assert!(areas.iter().all(|&a| a < 0.0), "{areas:?}");
        assert!((areas.iter().sum::<f64>() + 3.0).abs() < 1e-12);
    }

    /// Random simple polygons (4 to 12 corners) on a 5x5 lattice (many collinear and
    /// cocircular corners), exact and rotated by 0.5 rad (rounding noise):
    /// always n-2 triangles with the face's winding covering exactly the
    /// polygon, no slivers, no fallback.
    #[test]
    fn random_lattice_polygons_triangulate_exactly() {
        type P = (f64, f64);
        fn orient(a: P, b: P, c: P) -> f64 {
            (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0)
        }
        fn on_segment(a: P, b: P, p: P) -> bool {
            orient(a, b, p) == 0.0
                && p.0 >= a.0.min(b.0)
                && p.0 <= a.0.max(b.0)
                && p.1 >= a.1.min(b.1)
                && p.1 <= a.1.max(b.1)
        }
        fn simple(p: &[P]) -> bool {
            let n = p.len();
            for i in 0..n {
                for j in i + 1..n {
                    let (a, b, c, d) = (p[i], p[(i + 1) % n], p[j], p[(j + 1) % n]);
                    if j == i + 1 || (i == 0 && j == n - 1) {
                        // Adjacent edges may only share their common corner.
                        let (o, x, y) = if j == i + 1 { (b, a, d) } else { (a, b, c) };
                        let same_way = (x.0 - o.0) * (y.0 - o.0) + (x.1 - o.1) * (y.1 - o.1) > 0.0;
                        if orient(x, o, y) == 0.0 && same_way {
                            return false;
                        }
                        continue;
                    }
                    let (o1, o2) = (orient(a, b, c), orient(a, b, d));
                    let (o3, o4) = (orient(c, d, a), orient(c, d, b));
                    if o1 * o2 < 0.0 && o3 * o4 < 0.0 {
                        return false;
                    }
                    if on_segment(a, b, c)
                        || on_segment(a, b, d)
                        || on_segment(c, d, a)
                        || on_segment(c, d, b)
                    {
                        return false;
                    }
                }
            }
            true
        }
        let mut seed = 7u64;
        let mut rnd = |m: u64| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) % m
        };
        let mut tested = 0;
        for _ in 0..100_000 {
            let k = 4 + rnd(9) as usize;
            let lattice: Vec<P> = (0..k).map(|_| (rnd(5) as f64, rnd(5) as f64)).collect();
            if !simple(&lattice) {
                continue;
            }
            tested += 1;
            for angle in [0.0f64, 0.5] {
                let (s, c) = angle.sin_cos();
                let pts: Vec<P> = lattice
                    .iter()
                    .map(|p| {
                        (
                            (c * p.0 - s * p.1) as f32 as f64,
                            (s * p.0 + c * p.1) as f32 as f64,
                        )
                    })
                    .collect();
                let positions: Vec<f32> = pts
                    .iter()
                    .flat_map(|p| [p.0 as f32, p.1 as f32, 0.0])
                    .collect();
                let corners: Vec<u32> = (0..k as u32).collect();
                let mut tr = Triangulator::default();
                let mut out = Vec::new();
                tr.polygon(&positions, &corners, 0, &mut out, "t");
                assert_eq!(tr.fallbacks, 0, "{lattice:?}");
                assert_eq!(out.len(), 3 * (k - 2), "{lattice:?}");
                let shoelace: f64 = (0..k)
                    .map(|i| orient((0.0, 0.0), pts[i], pts[(i + 1) % k]))
                    .sum();
                let mut covered = 0.0;
                for t in out.chunks(3) {
                    let a = orient(pts[t[0] as usize], pts[t[1] as usize], pts[t[2] as usize])
                        * shoelace.signum();
                    assert!(
                        a > 1e-3,
                        "sliver or flipped triangle {t:?} in {lattice:?} at {angle}"
                    );
                    covered += a;
                }
                assert!(
                    (covered - shoelace.abs()).abs() < 1e-4,
                    "{lattice:?} at {angle}"
                );
            }
        }
        assert!(tested > 1000, "only {tested} simple polygons");
    }

    #[test]
    fn plain_ascii_and_newline_bits() {
        let mut seed = 5u64;
        for len in 0..70 {
            for _ in 0..200 {
                let bytes: Vec<u8> = (0..len)
                    .map(|_| {
                        seed = seed
                            .wrapping_mul(6364136223846793005)
                            .wrapping_add(1442695040888963407);
                        // Rare NUL and non-ASCII bytes among ASCII ones.
                        match (seed >> 40) % 64 {
                            0 => 0,
                            1 => 0x80 | (seed >> 20) as u8,
                            2 => 1,
                            3 => b'\n',
                            r => b' ' + r as u8,
                        }
                    })
                    .collect();
                let expected = bytes.iter().all(|&b| b != 0 && b.is_ascii());
                assert_eq!(plain_ascii(&bytes), expected, "{bytes:?}");
                for bytes in [
                    &bytes[..len.min(64)],
                    &[&bytes[..], &[b'\n'; 64][..]].concat()[..64],
                ] {
                    let mask = bytes
                        .iter()
                        .enumerate()
                        .filter(|&(_, &b)| b == b'\n')
                        .fold(0u64, |m, (i, _)| m | 1 << i);
                    assert_eq!(newline_bits(bytes), mask);
                }
            }
        }
    }

    #[test]
    fn find_newline_matches_a_byte_search() {
        let mut seed = 3u64;
        for len in 0..80 {
            for _ in 0..50 {
                let bytes: Vec<u8> = (0..len)
                    .map(|_| {
                        seed = seed
                            .wrapping_mul(6364136223846793005)
                            .wrapping_add(1442695040888963407);
                        // Mostly bytes near '\n' (0x0A) and 0x0B, 0x09,
                        // 0x8A, which a sloppy bit trick confuses with it.
                        [b'\n', 0x0b, 0x09, 0x8a, 0x00, 0xff, b'a', b' '][(seed >> 40) as usize % 8]
                    })
                    .collect();
                let expected = bytes.iter().position(|&b| b == b'\n');
                assert_eq!(find_newline(&bytes), expected, "{bytes:?}");
            }
        }
    }

    fn debug_models(models: &[tobj::Model]) -> String {
        format!("{models:?}")
    }

    /// The streaming path (pre-scan piece by piece as tobj reads) gives what
    /// the whole-text path gives, also when continued lines, points and
    /// blanked statements straddle the pieces' boundaries.
    #[test]
    fn streaming_matches_whole_text() {
        let mut text = String::from("mtllib a.mtl\nusemtl\tx\n");
        let mut k = 0usize;
        while text.len() < 5 * PIECE {
            k += 1;
            text.push_str(&format!("v {k} {}.5 -{k}e-3\n", k % 7));
            match k % 13 {
                0 => text.push_str(&format!("f {k} \\\n  {} {}\n", k.max(3) - 1, k.max(3) - 2)),
                1 => text.push_str("vt 0.5 0.5\nvn 0 0 1\n"),
                2 => text.push_str("l 1 2 \\\n3\np 1 \\\n 2 3\n"),
                3 => text.push_str(&format!("o part{k}\n# comment \\\n")),
                4 => text.push_str(&format!("\tf {k} {} {}\r\n", k.max(3) - 1, k.max(3) - 2)),
                5 => text.push_str(&format!(
                    "f {k} {} {} {}\n",
                    k.max(4) - 1,
                    k.max(4) - 2,
                    k.max(4) - 3
                )),
                _ => text.push_str(&format!("f {k} {} {}\n", k.max(3) - 1, k.max(3) - 2)),
            }
        }
        let mut texts = vec![
            text,
            String::new(),
            "v 1 2 3".into(),
            "v 1 2 3\nv 4 5 6 \\".into(),
        ];
        // A continued statement whose first line ends just before, at and
        // just after a piece's end.
        let head = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        for tail in [
            "f 1 2 \\\n3\n",
            "p 1 \\\n2\n",
            "l 1 \\\n2 3\n",
            "v 1 2 \\\n3\n",
            "usemtl \\\nm\n",
        ] {
            let first_len = tail.find('\n').unwrap() + 1;
            for shift in 0..5 {
                let k = PIECE + shift - 2 - head.len() - first_len - 2;
                texts.push(format!("{head}#{}\n{tail}f 1 2 3\n", "x".repeat(k)));
            }
        }
        for text in &texts {
            let data = text.as_bytes();
            let streamed = parse_streaming(data, &crate::alloc::arena::open(0))
                .unwrap()
                .expect("fast path");
            let owned = parse_owned(data.to_vec()).unwrap();
            assert_eq!(debug_models(&streamed.models), debug_models(&owned.models));
            assert_eq!(streamed.scan.joins, owned.scan.joins);
            let counts = |s: &Prescan| {
                [
                    s.vertices,
                    s.faces,
                    s.line_statements,
                    s.point_statements,
                    s.point_refs,
                ]
            };
            assert_eq!(counts(&streamed.scan), counts(&owned.scan));
            assert_eq!(streamed.warnings, owned.warnings);
        }
    }

    /// Inputs the streaming path must hand over to the whole-text path.
    #[test]
    fn streaming_declines_what_needs_the_whole_text() {
        let mut long = "v 0 0 0\n".repeat(PIECE / 4);
        long.push_str("# caf\u{e9}\n");
        let mut invalid = long.into_bytes();
        let at = invalid.len() - 3;
        invalid[at] = 0xff;
        for data in [
            &b"\xEF\xBB\xBFv 1 2 3\n"[..],
            b"\xFF\xFEv\x00",
            b"v 1 2 3\rv 4 5 6\r",
            b"v 1 2 3\nv 1 2\n",
            b"v 1 2 3\x00\n",
            &invalid,
        ] {
            let streamed = parse_streaming(data, &crate::alloc::arena::open(0)).unwrap();
            // A UTF-8 byte-order mark is simply skipped.
            assert_eq!(streamed.is_some(), data.starts_with(b"\xEF"), "{data:?}");
        }
    }

    /// What a build reads of a parse: each triangle's corner positions
    /// (bits), the parts, the counters, the warnings and the number of `v`
    /// statements; not the soup's vertex numbers, which blocks and cuts
    /// change (welding merges the copies).
    type ByValue = (
        Vec<[[u32; 3]; 3]>,
        Vec<(String, u32, u32)>,
        [u64; 3],
        Vec<String>,
        u64,
    );

    fn by_value(parsed: Parsed) -> ByValue {
        let soup = finish(parsed).unwrap();
        let corner = |i: u32| soup.positions[i as usize].map(f32::to_bits);
        let triangles = soup
            .indices
            .chunks_exact(3)
            .map(|c| [corner(c[0]), corner(c[1]), corner(c[2])])
            .collect();
        let parts = soup
            .parts
            .iter()
            .map(|p| (p.name.clone(), p.first_triangle, p.triangle_count))
            .collect();
        let st = &soup.stats;
        (
            triangles,
            parts,
            [st.primitives, st.skipped_points, st.skipped_lines],
            st.warnings.clone(),
            soup.input_vertices,
        )
    }

    /// The split parse with the rest claimed by the second reader (`true`,
    /// run first) or by the first (`false`), on this thread; the reader
    /// that did not claim the rest read none of it.
    fn split_join(text: &[u8], split: usize, second_first: bool) -> Split {
        let claim = std::sync::atomic::AtomicBool::new(false);
        if second_first {
            let second = second_part(text, split, &claim);
            let first = first_part(text, split, &claim);
            // The first reader stopped at the cut (unless it failed first).
            assert!(
                first.1 || first.0.models.is_none(),
                "read past a claimed cut"
            );
            join_parts(first, second)
        } else {
            let first = first_part(text, split, &claim);
            let second = second_part(text, split, &claim);
            assert!(second.is_none(), "the rest read twice");
            join_parts(first, second)
        }
    }

    /// [`split_join`]'s parse, if it gives one.
    fn split_parse(text: &[u8], split: usize, second_first: bool) -> Option<Parsed> {
        match split_join(text, split, second_first) {
            Split::Parsed(parsed) => Some(parsed),
            Split::Declined | Split::OneReader => None,
        }
    }

    /// Texts in the layouts a split must keep whole: vertices first (one
    /// object, polygons), objects each with their vertices (relative
    /// indices), groups sharing one pool of vertices (texture and normal
    /// indices, materials), continued lines, points and lines, odd
    /// whitespace and CRLF, `w` and colours, no `o`/`g` at all.
    fn split_texts() -> Vec<String> {
        let mut texts = Vec::new();
        let grid = |n: usize, z: f32| -> String {
            let mut t = String::new();
            for j in 0..n {
                for i in 0..n {
                    t.push_str(&format!("v {i} {j} {}\n", z + 0.25 * ((i * j) % 3) as f32));
                }
            }
            t
        };
        // Vertices first, one object, triangles, quads and pentagons.
        let mut t = String::from("# head\no dragon\n");
        t.push_str(&grid(6, 0.0));
        for j in 0..5 {
            for i in 0..5 {
                let a = j * 6 + i + 1;
                match (i + j) % 3 {
                    0 => t.push_str(&format!("f {a} {} {} {}\n", a + 1, a + 7, a + 6)),
                    1 => t.push_str(&format!(
                        "f {a} {} {}\nf {a} {} {}\n",
                        a + 1,
                        a + 7,
                        a + 7,
                        a + 6
                    )),
                    _ => t.push_str(&format!("f {a} {} {} {} {}\n", a + 1, a + 7, a + 6, a + 6)),
                }
            }
        }
        texts.push(t);
        // Objects with their own vertices, relative indices in one.
        let mut t = String::new();
        for o in 0..4 {
            t.push_str(&format!("o part{o}\n"));
            t.push_str(&grid(3, o as f32));
            for j in 0..2 {
                for i in 0..2 {
                    let a = 9 * o + j * 3 + i + 1;
                    if o == 2 {
                        let r = |k: usize| format!("-{}", 9 * o + 10 - k);
                        t.push_str(&format!("f {} {} {}\n", r(a), r(a + 1), r(a + 4)));
                    } else {
                        t.push_str(&format!(
                            "f {a} {} {}\nf {a} {} {}\n",
                            a + 1,
                            a + 4,
                            a + 4,
                            a + 3
                        ));
                    }
                }
            }
        }
        texts.push(t);
        // One pool of vertices, groups and materials over it.
        let mut t = String::from("mtllib x.mtl\n");
        t.push_str(&grid(5, 0.0));
        t.push_str("vt 0 0\nvn 0 0 1\n");
        for g in 0..4 {
            t.push_str(&format!("g side{}\nusemtl m{g}\n", g % 2));
            for k in 0..4 {
                let a = (g * 5 + k) % 19 + 1;
                t.push_str(&format!("f {a}/1/1 {}/1/1 {}/1/1\n", a + 1, a + 5));
            }
        }
        texts.push(t);
        // Continued lines, points, lines, whitespace, CRLF, w and colours.
        let mut t = String::from("o cont\n");
        t.push_str("v 0 0 0\nv 1 0 \\\n0\n  v 0 1 0\r\n\tv 1 1 0 2\nv 2 2 2\n");
        t.push_str("f 1 2 \\\n3\np 1 2\nl 1 2 3\n\n# note\nf 2 4 3\r\n");
        t.push_str("g other\nv 3 3 3\nf 4 5 6\nf -1 -2 -4\ns 1\nf 1 3 5 2\n");
        texts.push(t);
        // Colours on every vertex.
        let mut t = String::from("o rgb\n");
        for k in 0..12 {
            t.push_str(&format!("v {k} {} 0 0.5 0.25 1\n", k % 3));
        }
        for a in 1..10 {
            t.push_str(&format!("f {a} {} {}\n", a + 1, a + 3));
        }
        texts.push(t);
        // No `o` or `g`.
        let mut t = grid(4, 0.0);
        for a in 1..12 {
            if a % 4 != 0 {
                t.push_str(&format!("f {a} {} {}\n", a + 1, a + 4));
            }
        }
        texts.push(t);
        texts
    }

    /// A text parsed in two parts, cut at every line, gives the triangles,
    /// parts, counters and warnings of the whole parse, and the same models
    /// whichever reader claims the rest. Caught (each broken on purpose and
    /// run, then reverted): the `o`/`g` statement not repeated after the cut
    /// by the second reader (the parts' names) or by the first (the
    /// models), every line of the first part given to the second reader
    /// (its faces twice), the counts of both scans added, and the first
    /// reader reading on past a claimed cut.
    #[test]
    fn a_split_parse_is_the_whole_parse_at_every_cut() {
        for text in split_texts() {
            let data = text.as_bytes();
            // The streaming path takes every one of these texts whole.
            assert!(
                parse_streaming(data, &crate::alloc::arena::open(0))
                    .unwrap()
                    .is_some(),
                "{text:?}"
            );
            let whole = by_value(parse_owned(data.to_vec()).unwrap());
            let mut cuts = 0;
            for split in 1..data.len() {
                if data[split - 1] != b'\n' {
                    continue;
                }
                let (Some(second), Some(first)) = (
                    split_parse(data, split, true),
                    split_parse(data, split, false),
                ) else {
                    // Only a cut inside a continued statement declines.
                    let before = &data[..split - 1];
                    let line = before.rsplit(|&b| b == b'\n').next().unwrap();
                    assert!(continuation(line).is_some(), "cut at {split} of {text:?}");
                    continue;
                };
                // The same models whichever reader read the rest.
                assert_eq!(debug_models(&second.models), debug_models(&first.models));
                assert_eq!(by_value(second), whole, "cut at {split} of {text:?}");
                assert_eq!(by_value(first), whole, "cut at {split} of {text:?}");
                cuts += 1;
            }
            assert!(cuts > 10, "{text:?}");
        }
    }

    /// The same across pieces: a first part of several pieces, some with no
    /// `v` statement at all (nothing of them reaches tobj: an empty piece
    /// must not read as the end), a model cut into blocks, and a second
    /// part of several pieces; and a non-finite position sends the text to
    /// one reader. Caught: `fill_buf` taking one piece where a loop is
    /// needed (the parse ends early); a non-finite position sent to the
    /// whole-text path instead (its models are not cut into blocks).
    #[test]
    fn a_split_parse_of_many_pieces_is_the_whole_parse() {
        let mut text = String::from("o big\n");
        let n = 260;
        for j in 0..n {
            for i in 0..n {
                text.push_str(&format!("v {i} {j} {}\n", (i * 7 + j * 3) % 5));
            }
        }
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let a = j * n + i + 1;
                text.push_str(&format!(
                    "f {a} {} {}\nf {a} {} {}\n",
                    a + 1,
                    a + n + 1,
                    a + n + 1,
                    a + n
                ));
            }
        }
        let data = text.as_bytes();
        assert!(data.len() > 40 * PIECE);
        let whole = by_value(parse_owned(data.to_vec()).unwrap());
        assert!(whole.0.len() as u64 > 2 * MODEL_BLOCK_FACES);
        let mut cuts: Vec<usize> = (1..12).map(|k| k * data.len() / 12).collect();
        cuts.extend(split_point(data));
        for cut in cuts {
            let split = cut + find_newline(&data[cut - 1..]).unwrap();
            let second = split_parse(data, split, true).expect("no continued lines");
            let first = split_parse(data, split, false).expect("no continued lines");
            assert_eq!(debug_models(&second.models), debug_models(&first.models));
            assert_eq!(by_value(second), whole, "cut at {split}");
            assert_eq!(by_value(first), whole, "cut at {split}");
        }
        // A non-finite position: the split gives up, and the text is read
        // by one reader, whose models (cut into blocks) a one-thread build
        // gets, so that its message names the same vertex.
        let nan = text.replacen(&format!("v 3 {} ", n - 1), &format!("v nan {} ", n - 1), 1);
        assert_ne!(nan, text);
        let nan = nan.as_bytes();
        let joined = split_join(nan, data.len() / 2, true);
        assert!(matches!(joined, Split::OneReader));
        let mut one = PrescanReader::new(nan);
        let one = run_tobj(&mut one).unwrap();
        assert!(nan.len() >= SPLIT_MIN);
        let streamed = parse_streaming(nan, &crate::alloc::arena::open(0))
            .unwrap()
            .expect("streamed");
        assert_eq!(debug_models(&streamed.models), debug_models(&one));
    }

    /// An `o`/`g` statement continued on another line cannot be repeated at
    /// a cut after it: either reader that meets the cut gives up, and the
    /// text goes to one reader. Caught: the check left out (the repeated
    /// statement's first line alone names the model).
    #[test]
    fn a_cut_after_a_continued_group_statement_goes_to_one_reader() {
        let text = "o pa\\\nrt\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n";
        let data = text.as_bytes();
        let first_cut = text.find("v 0 0 0").unwrap();
        for split in (first_cut..data.len()).filter(|&i| data[i - 1] == b'\n') {
            for second_first in [true, false] {
                let joined = split_join(data, split, second_first);
                assert!(matches!(joined, Split::OneReader), "cut at {split}");
            }
        }
    }

    /// Where the cut goes: a line's start, past continued lines, at an
    /// `o`/`g` statement close by, and where the two readers' work is about
    /// equal: `2·split − V(split) = n` (vertices first, 40% of the bytes:
    /// 0.70 n; vertices spread evenly, 40%: n / 1.6 = 0.625 n).
    #[test]
    fn the_cut_balances_the_readers_and_starts_a_statement() {
        let v = "v 0.12345 0.23456 0.34567\n";
        let f = "f 123456 234567 345678 12\n";
        assert_eq!(v.len(), f.len());
        let first: String = v.repeat(40_000) + &f.repeat(60_000);
        let spread: String = (0..20_000).map(|_| v.repeat(2) + &f.repeat(3)).collect();
        for (text, lo, hi) in [(first, 0.66, 0.74), (spread, 0.59, 0.66)] {
            let data = text.as_bytes();
            let split = split_point(data).unwrap();
            assert_eq!(data[split - 1], b'\n');
            let at = split as f64 / data.len() as f64;
            assert!((lo..hi).contains(&at), "{at}");
        }
        // An object's start within reach is taken.
        let mut text = v.repeat(40_000) + &f.repeat(60_000);
        let at = (0.72 * text.len() as f64) as usize;
        let at = at + text[at..].find('\n').unwrap() + 1;
        text.insert_str(at, "o next\n");
        assert_eq!(split_point(text.as_bytes()), Some(at));
        // Never after a continued line.
        let cont = "f 1 2 \\\n";
        let text = cont.repeat(100_000) + "f 1 2 3\n";
        assert_eq!(split_point(text.as_bytes()), None);
        for k in 0..12 {
            let text = v.repeat(k) + "v 1 \\\n2 3\n" + &v.repeat(12 - k);
            let continued = text.find("2 3").unwrap();
            if let Some(split) = split_point(text.as_bytes()) {
                assert_ne!(split, continued);
                assert_eq!(text.as_bytes()[split - 1], b'\n');
            }
        }
        assert_eq!(split_point(b""), None);
        assert_eq!(split_point(b"v"), None);
    }

    #[test]
    fn into_triples_keeps_the_points() {
        for n in [0usize, 1, 2, 5, 1000] {
            let mut flat = Vec::with_capacity(3 * n + 7);
            flat.extend((0..3 * n).map(|i| i as f32));
            let points = into_triples(flat);
            assert_eq!(points.len(), n);
            assert!(
                points.iter().enumerate().all(
                    |(i, p)| *p == [3.0 * i as f32, 3.0 * i as f32 + 1.0, 3.0 * i as f32 + 2.0]
                )
            );
        }
    }

    #[test]
    fn convexity() {
        let square = [0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.0, 1.0];
        assert!(is_convex(&square));
        let clockwise = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0];
        assert!(!is_convex(&clockwise));
        // Pentagram: every corner turns left, but it goes round twice.
        let star: Vec<f64> = (0..5)
            .flat_map(|i| {
                let a = std::f64::consts::TAU * (2 * i) as f64 / 5.0;
                [a.cos(), a.sin()]
            })
            .collect();
        assert!(!is_convex(&star));
    }

    #[test]
    fn concave_quad_is_split_at_reflex_corner() {
        // Dart: corner 1 is reflex.
        let q = [
            [0.0, 0.0, 0.0],
            [1.0, 0.5, 0.0],
            [2.0, 0.0, 0.0],
            [1.0, 2.0, 0.0],
        ];
        assert_eq!(split_quad(&q), [1, 2, 3, 3, 0, 1]);
        let q = [
            [1.0, 0.5, 0.0],
            [2.0, 0.0, 0.0],
            [1.0, 2.0, 0.0],
            [0.0, 0.0, 0.0],
        ];
        assert_eq!(split_quad(&q), [0, 1, 2, 0, 2, 3]);
    }
}
