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
//!    tobj does not understand, are joined.
//! 3. **Parse** with `tobj::load_obj_buf` (untriangulated, one index per
//!    attribute). A few recoverable problems are repaired in place and the
//!    parse is retried (see `repair_vertex_lines`); any other failure is turned
//!    into a message naming the offending line (`diagnose`).
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

use super::{InputDigest, Part, Soup};
use crate::error::{Error, Result};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;

/// Loads a `.obj` whose bytes are `data`.
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
pub fn load_obj(path: &Path, data: Vec<u8>) -> Result<Soup> {
    let mut digest = InputDigest::default();
    digest.update(&data);
    let (input_bytes, input_sha256) = digest.finish();

    // tobj and earcutr are third-party parsers fed untrusted input; the known
    // panic causes are avoided by the pre-scan, but a panic must still never
    // take the whole process down.
    let mut soup = match catch_unwind(AssertUnwindSafe(|| load_text(data))) {
        Ok(Ok(soup)) => soup,
        Ok(Err(msg)) => return Err(Error::input(path, msg)),
        Err(payload) => {
            let what = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            return Err(Error::input(
                path,
                format!("internal error while reading OBJ: {what}"),
            ));
        }
    };
    soup.input_bytes = input_bytes;
    soup.input_sha256 = input_sha256;
    Ok(soup)
}

/// The whole pipeline on owned bytes; errors are messages without the path.
fn load_text(data: Vec<u8>) -> Result<Soup, String> {
    let mut warnings = Vec::new();
    let mut text = normalize_encoding(data, &mut warnings)?;
    let scan = prescan(&mut text);
    let models = parse_with_repairs(&mut text, &scan, &mut warnings)?;
    // The text is no longer needed; free it before building the soup, which
    // for big files is the peak of memory use.
    drop(text);

    let mut soup = build_soup(models, &mut warnings)?;
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
        let end = text[start..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(text.len(), |i| start + i);
        self.pos = end + 1;
        Some((start, end))
    }
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
    Other,
}

/// One pass over the text: count, blank unused statements, join continuations.
fn prescan(text: &mut [u8]) -> Prescan {
    let mut scan = Prescan::default();
    let mut lines = Lines::default();
    let mut continued: Option<Kind> = None;
    while let Some((s, e)) = lines.next(text) {
        let line = &mut text[s..e];
        let first_part = continued.is_none();
        let kind = match continued.take() {
            Some(kind) => kind,
            None => classify_and_blank(line, &mut scan),
        };
        if kind != Kind::Comment
            && let Some(backslash) = continuation(line)
        {
            line[backslash..].fill(b' ');
            if e < text.len() {
                text[e] = b' ';
                scan.joins.push(e);
                continued = Some(kind);
            }
        }
        if kind == Kind::Point {
            // The first part starts with the (blanked) keyword, now "#".
            let words = count_words(&text[s..e]);
            scan.point_refs += if first_part {
                words.saturating_sub(1)
            } else {
                words
            };
        }
    }
    scan
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

fn run_tobj(text: &[u8]) -> Result<Vec<tobj::Model>, tobj::LoadError> {
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
    let mut reader = text;
    let (models, _materials) = tobj::load_obj_buf(&mut reader, &options, no_materials)?;
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
        let err = match run_tobj(text) {
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
    soup.positions.reserve_exact(total_positions);
    soup.indices.reserve(total_indices);
    let mut triangulator = Triangulator::default();
    let mut empty_faces = 0u64;

    for model in models {
        let name = model.name;
        let mesh = model.mesh;
        let internal =
            |what: &str| format!("internal error: tobj returned {what} for object {name:?}");
        if !mesh.positions.len().is_multiple_of(3) {
            return Err(internal("a partial position"));
        }
        let vertex_count = mesh.positions.len() / 3;
        // tobj's indices point into the model's own positions; it should
        // never produce one out of range, but a wrong index here would only
        // surface far away, so check (one tight pass).
        if let Some(&bad) = mesh.indices.iter().find(|&&i| i as usize >= vertex_count) {
            return Err(format!(
                "object {name:?}: vertex index {bad} out of range ({vertex_count} vertices)"
            ));
        }
        // Fits: the total was checked above.
        let base = soup.positions.len() as u32;
        soup.positions
            .extend(mesh.positions.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));

        let first_index = soup.indices.len();
        if mesh.face_arities.is_empty() {
            // tobj leaves face_arities empty when every face is a triangle.
            if !mesh.indices.len().is_multiple_of(3) {
                return Err(internal("a partial triangle"));
            }
            soup.indices.extend(mesh.indices.iter().map(|&i| base + i));
        } else {
            let mut offset = 0usize;
            for &arity in &mesh.face_arities {
                let n = arity as usize;
                let Some(corners) = mesh.indices.get(offset..offset + n) else {
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
                        &mesh.positions,
                        corners,
                        base,
                        &mut soup.indices,
                        &name,
                    ),
                }
            }
            if offset != mesh.indices.len() {
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
