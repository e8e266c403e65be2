//! Lint: report problems in an input asset that affect shadow-volume geometry,
//! without building anything.
//!
//! [`lint_soup`] runs every check on a loaded [`Soup`] and returns one
//! [`Finding`] per code that fired, sorted by code. Each finding carries a
//! count and up to [`MAX_EXAMPLES`] examples naming the input triangle and the
//! [`Part`](crate::load::Part) it belongs to.
//!
//! Order of work: triangles with a non-finite corner are reported
//! (`non-finite`) and excluded from every other check; the rest are welded with
//! [`weld`] exactly as the build does, and edge checks run on
//! [`build_edges`] of the welded triangles.
//!
//! Codes (also listed with severities in [`CODES`]):
//!
//! - `degenerate-triangle` (warning): two corners of a triangle are at the same
//!   welded position (bit-equal after mapping `-0.0` to `+0.0`); build drops
//!   these triangles. Count: triangles.
//! - `empty` (warning): the input has no triangles at all. Count: 1.
//! - `inconsistent-winding` (warning): a manifold edge (exactly 2 triangles)
//!   whose two triangles traverse it in the same direction. Count: edges.
//! - `non-finite` (error): triangles with a NaN or infinite corner coordinate.
//!   Count: triangles.
//! - `non-manifold-edge` (warning): edges with more than 2 opposite vertices.
//!   Count: edges; the message names the largest fan.
//! - `open-edge` (info): boundary edges with exactly 1 opposite vertex.
//!   Count: edges.
//! - `precision` (warning): the f32 spacing (ulp) at the largest |coordinate|
//!   exceeds [`PRECISION_FRACTION`] (1/1000) of the shortest non-zero edge.
//!   Count: edges shorter than `ulp / PRECISION_FRACTION`.
//! - `skipped-lines` / `skipped-points` (info): line / point primitives the
//!   loader skipped (from [`LoadStats`](crate::load::LoadStats)).
//! - `split-edge` (info): edges with more than `max_mult` opposite vertices,
//!   which build splits into several instances. Count: edges.
//! - `unwelded-seam` (warning): (a) positions, among those used by finite
//!   triangles, that the input spells with different signs of zero (build
//!   welds these anyway; count: such positions), and (b) pairs of distinct welded positions whose Euclidean
//!   distance is at most [`SEAM_TOLERANCE`] (1e-6) times the diagonal of the
//!   bounding box of all welded positions, found with a grid hash (count:
//!   pairs).
//! - `zero-area-triangle` (warning): three distinct corners that are exactly
//!   collinear (the cross product of two edge vectors is exactly zero,
//!   decided with the exact `robust::orient2d` predicate on the three axis
//!   projections). Count: triangles.
//!
//! `lint_soup` assumes corner indices are in range (the loaders guarantee
//! it); triangles with an out-of-range index are ignored.

use crate::error::Result;
use crate::load::Soup;
use crate::topology::{Edges, build_edges};
use crate::weld::{Welded, canonical, weld};
use robust::{Coord, orient2d};
use serde::Serialize;
use std::path::Path;

/// How serious a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// Worth knowing; build handles it.
    Info,
    /// Probably an asset problem; build still produces output.
    Warning,
    /// The asset is broken in a way build cannot represent.
    Error,
}

/// One place where a finding occurs.
#[derive(Debug, Clone, Serialize)]
pub struct Example {
    /// Input triangle index (into [`Soup::indices`] / 3).
    pub triangle: u64,
    /// Name of the [`Part`](crate::load::Part) holding the triangle, empty if
    /// no part covers it.
    pub part: String,
    /// Positions involved: triangle corners, edge endpoints or the positions
    /// of a seam, depending on the code.
    pub positions: Vec<[f32; 3]>,
}

/// One lint result: a code that fired, how often, and a few examples.
#[derive(Debug, Clone, Serialize)]
pub struct Finding {
    /// Stable kebab-case code, one of [`CODES`].
    pub code: &'static str,
    /// Severity of the code.
    pub severity: Severity,
    /// Number of occurrences (the unit depends on the code, see module docs).
    pub count: u64,
    /// File the finding is about.
    pub file: String,
    /// One-line human-readable description with the count.
    pub message: String,
    /// At most [`MAX_EXAMPLES`] examples, in a deterministic order.
    pub examples: Vec<Example>,
}

/// Most examples per finding.
pub const MAX_EXAMPLES: usize = 3;

/// `unwelded-seam` tolerance, relative to the bounding-box diagonal.
pub const SEAM_TOLERANCE: f64 = 1e-6;

/// `precision` fires when ulp(largest |coordinate|) exceeds this fraction of the
/// shortest non-zero edge length.
pub const PRECISION_FRACTION: f64 = 1.0 / 1000.0;

/// All codes with severity and one-line description, for docs and `--deny`
/// validation. Sorted by code.
pub const CODES: &[(&str, Severity, &str)] = &[
    (
        "degenerate-triangle",
        Severity::Warning,
        "two corners of a triangle are at the same welded position; build drops it",
    ),
    ("empty", Severity::Warning, "the input has no triangles"),
    (
        "inconsistent-winding",
        Severity::Warning,
        "a manifold edge whose two triangles traverse it in the same direction",
    ),
    (
        "non-finite",
        Severity::Error,
        "a triangle uses a NaN or infinite position",
    ),
    (
        "non-manifold-edge",
        Severity::Warning,
        "an edge shared by more than two triangles",
    ),
    (
        "open-edge",
        Severity::Info,
        "a boundary edge used by only one triangle",
    ),
    (
        "precision",
        Severity::Warning,
        "the f32 spacing at the largest coordinate exceeds 1/1000 of the shortest edge",
    ),
    (
        "skipped-lines",
        Severity::Info,
        "line primitives were skipped by the loader",
    ),
    (
        "skipped-points",
        Severity::Info,
        "point primitives were skipped by the loader",
    ),
    (
        "split-edge",
        Severity::Info,
        "an edge with more than max-mult opposite vertices, which build splits",
    ),
    (
        "unwelded-seam",
        Severity::Warning,
        "distinct positions equal up to the sign of zero or within 1e-6 of the bounds diagonal",
    ),
    (
        "zero-area-triangle",
        Severity::Warning,
        "three distinct but exactly collinear corners",
    ),
];

fn severity_of(code: &str) -> Severity {
    CODES
        .iter()
        .find(|c| c.0 == code)
        .map(|c| c.1)
        .expect("code listed in CODES")
}

/// Collects count and examples for one code.
struct Acc<'a> {
    soup: &'a Soup,
    count: u64,
    examples: Vec<Example>,
}

impl<'a> Acc<'a> {
    fn new(soup: &'a Soup) -> Self {
        Acc {
            soup,
            count: 0,
            examples: Vec::new(),
        }
    }

    /// Counts one occurrence at input triangle `tri`; `positions` is called
    /// only when an example is kept.
    fn hit(&mut self, tri: u32, positions: impl FnOnce() -> Vec<[f32; 3]>) {
        self.count += 1;
        if self.examples.len() < MAX_EXAMPLES {
            self.examples.push(Example {
                triangle: tri as u64,
                part: part_name(self.soup, tri),
                positions: positions(),
            });
        }
    }

    fn finish(self, file: &str, code: &'static str, message: String, out: &mut Vec<Finding>) {
        if self.count > 0 {
            out.push(Finding {
                code,
                severity: severity_of(code),
                count: self.count,
                file: file.to_string(),
                message,
                examples: self.examples,
            });
        }
    }
}

/// Name of the part holding input triangle `tri`, or "" when none does.
fn part_name(soup: &Soup, tri: u32) -> String {
    let parts = &soup.parts;
    let i = parts.partition_point(|p| p.first_triangle <= tri);
    if i == 0 {
        return String::new();
    }
    let p = &parts[i - 1];
    if (tri as u64) < p.first_triangle as u64 + p.triangle_count as u64 {
        p.name.clone()
    } else {
        String::new()
    }
}

fn is_finite(p: [f32; 3]) -> bool {
    p.iter().all(|v| v.is_finite())
}

/// True when `a`, `b`, `c` are exactly collinear: every component of
/// `(b - a) × (c - a)` is exactly zero (each is an exact 2D orientation).
fn collinear(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> bool {
    let o = |i: usize, j: usize| {
        orient2d(
            Coord {
                x: a[i] as f64,
                y: a[j] as f64,
            },
            Coord {
                x: b[i] as f64,
                y: b[j] as f64,
            },
            Coord {
                x: c[i] as f64,
                y: c[j] as f64,
            },
        )
    };
    o(0, 1) == 0.0 && o(1, 2) == 0.0 && o(2, 0) == 0.0
}

/// Spacing between `|v|` and the next larger f32 magnitude (as f64).
fn ulp(v: f32) -> f64 {
    let e = ((v.abs().to_bits() >> 23) & 0xff) as i32;
    if e == 0 {
        2f64.powi(-149)
    } else {
        2f64.powi(e - 127 - 23)
    }
}

fn dist(p: [f32; 3], q: [f32; 3]) -> f64 {
    let d: [f64; 3] = std::array::from_fn(|k| p[k] as f64 - q[k] as f64);
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// Lints a loaded soup. Pure; findings are sorted by code.
pub fn lint_soup(file: &str, soup: &Soup, max_mult: u32) -> Vec<Finding> {
    let mut out = Vec::new();
    let tri_count = soup.triangle_count();
    let npos = soup.positions.len();

    // --- Loader stats and emptiness -------------------------------------
    if tri_count == 0 {
        let mut acc = Acc::new(soup);
        acc.count = 1;
        acc.finish(file, "empty", "the input has no triangles".into(), &mut out);
    }
    for (code, n, what) in [
        ("skipped-points", soup.stats.skipped_points, "point"),
        ("skipped-lines", soup.stats.skipped_lines, "line"),
    ] {
        let mut acc = Acc::new(soup);
        acc.count = n;
        acc.finish(
            file,
            code,
            format!("{n} {what} primitive(s) skipped by the loader"),
            &mut out,
        );
    }

    // --- Non-finite, and the finite sub-soup ------------------------------
    let mut finite_indices: Vec<u32> = Vec::with_capacity(soup.indices.len());
    let mut finite_source: Vec<u32> = Vec::with_capacity(tri_count);
    let mut non_finite = Acc::new(soup);
    let mut degenerate = Acc::new(soup);
    let mut zero_area = Acc::new(soup);
    for (t, c) in soup.indices.chunks_exact(3).enumerate() {
        if c.iter().any(|&i| i as usize >= npos) {
            continue;
        }
        let p = [
            soup.positions[c[0] as usize],
            soup.positions[c[1] as usize],
            soup.positions[c[2] as usize],
        ];
        if !(is_finite(p[0]) && is_finite(p[1]) && is_finite(p[2])) {
            non_finite.hit(t as u32, || p.to_vec());
            continue;
        }
        finite_indices.extend_from_slice(c);
        finite_source.push(t as u32);
        let k = p.map(|q| q.map(|v| canonical(v).to_bits()));
        if k[0] == k[1] || k[1] == k[2] || k[0] == k[2] {
            degenerate.hit(t as u32, || p.to_vec());
        } else if collinear(p[0], p[1], p[2]) {
            zero_area.hit(t as u32, || p.to_vec());
        }
    }
    let n = non_finite.count;
    non_finite.finish(
        file,
        "non-finite",
        format!("{n} triangle(s) use NaN/Inf positions; they are excluded from other checks"),
        &mut out,
    );
    let n = degenerate.count;
    let degenerate_count = n;
    degenerate.finish(
        file,
        "degenerate-triangle",
        format!("{n} triangle(s) have two corners at the same position; build drops them"),
        &mut out,
    );
    let n = zero_area.count;
    zero_area.finish(
        file,
        "zero-area-triangle",
        format!("{n} triangle(s) have three distinct but collinear corners"),
        &mut out,
    );

    // --- Weld and edges ----------------------------------------------------
    let welded = weld(&soup.positions, &finite_indices);
    debug_assert_eq!(welded.degenerate(), degenerate_count);
    let input_tri = |wt: u32| finite_source[welded.source_triangle[wt as usize] as usize];
    let edges = build_edges(&welded.triangles, welded.positions.len());

    edge_checks(file, soup, &welded, &edges, &input_tri, max_mult, &mut out);
    seam_checks(
        file,
        soup,
        &welded,
        &finite_indices,
        &finite_source,
        &input_tri,
        &mut out,
    );
    precision_check(file, soup, &welded, &edges, &input_tri, &mut out);

    out.sort_by_key(|f| f.code);
    out
}

fn edge_tri(edges: &Edges, e: usize) -> u32 {
    edges.opp_tri[edges.opp_start[e] as usize]
}

/// True when welded triangle `t` traverses `a → b` (rather than `b → a`).
fn traverses(welded: &Welded, t: u32, a: u32, b: u32) -> bool {
    let c = &welded.triangles[3 * t as usize..3 * t as usize + 3];
    (0..3).any(|k| c[k] == a && c[(k + 1) % 3] == b)
}

fn edge_checks(
    file: &str,
    soup: &Soup,
    welded: &Welded,
    edges: &Edges,
    input_tri: &dyn Fn(u32) -> u32,
    max_mult: u32,
    out: &mut Vec<Finding>,
) {
    let mut non_manifold = Acc::new(soup);
    let mut open = Acc::new(soup);
    let mut winding = Acc::new(soup);
    let mut split = Acc::new(soup);
    let mut max_fan = 0usize;
    for e in 0..edges.len() {
        let fan = edges.fan(e);
        let (a, b) = (edges.a[e], edges.b[e]);
        let ends = || vec![welded.positions[a as usize], welded.positions[b as usize]];
        if fan == 1 {
            open.hit(input_tri(edge_tri(edges, e)), ends);
        } else if fan == 2 {
            let s = edges.opp_start[e] as usize;
            let (t0, t1) = (edges.opp_tri[s], edges.opp_tri[s + 1]);
            if traverses(welded, t0, a, b) == traverses(welded, t1, a, b) {
                winding.hit(input_tri(t1), ends);
            }
        } else {
            max_fan = max_fan.max(fan);
            non_manifold.hit(input_tri(edge_tri(edges, e)), ends);
        }
        if max_mult > 0 && fan > max_mult as usize {
            split.hit(input_tri(edge_tri(edges, e)), ends);
        }
    }
    let n = non_manifold.count;
    non_manifold.finish(
        file,
        "non-manifold-edge",
        format!("{n} edge(s) shared by more than two triangles (largest fan {max_fan})"),
        out,
    );
    let n = open.count;
    open.finish(
        file,
        "open-edge",
        format!("{n} boundary edge(s) used by only one triangle"),
        out,
    );
    let n = winding.count;
    winding.finish(
        file,
        "inconsistent-winding",
        format!("{n} manifold edge(s) traversed in the same direction by both triangles"),
        out,
    );
    let n = split.count;
    split.finish(
        file,
        "split-edge",
        format!("{n} edge(s) have more than {max_mult} opposite vertices; build splits them"),
        out,
    );
}

#[allow(clippy::too_many_arguments)]
fn seam_checks(
    file: &str,
    soup: &Soup,
    welded: &Welded,
    finite_indices: &[u32],
    finite_source: &[u32],
    input_tri: &dyn Fn(u32) -> u32,
    out: &mut Vec<Finding>,
) {
    let mut acc = Acc::new(soup);

    // (a) Signed zeros: referenced input vertices grouped by canonical bits;
    //     a group with two different raw bit patterns is a seam build welds.
    //     Only positions with a zero coordinate can be in such a group (all
    //     of a group's members share its canonical bits, which differ from
    //     the raw ones only for -0.0), so only those are sorted: on the
    //     dragon, none of 2.6 million corners, whose sort was a quarter of
    //     `lint`'s time.
    let mut signed_zero = 0u64;
    {
        // (canonical bits, raw bits, finite triangle index)
        let mut recs: Vec<([u32; 3], [u32; 3], u32)> = Vec::new();
        for (i, &v) in finite_indices.iter().enumerate() {
            let p = soup.positions[v as usize];
            if !p.contains(&0.0) {
                continue;
            }
            recs.push((
                p.map(|x| canonical(x).to_bits()),
                p.map(f32::to_bits),
                (i / 3) as u32,
            ));
        }
        recs.sort_unstable();
        let mut i = 0;
        while i < recs.len() {
            let mut j = i + 1;
            let mut other = None;
            while j < recs.len() && recs[j].0 == recs[i].0 {
                if other.is_none() && recs[j].1 != recs[i].1 {
                    other = Some(j);
                }
                j += 1;
            }
            if let Some(o) = other {
                signed_zero += 1;
                let (r0, r1) = (recs[i], recs[o]);
                acc.hit(finite_source[r0.2 as usize], || {
                    vec![r0.1.map(f32::from_bits), r1.1.map(f32::from_bits)]
                });
            }
            i = j;
        }
    }

    // (b) Distinct welded positions within tolerance, via a sorted grid.
    let mut near = 0u64;
    let pos = &welded.positions;
    if pos.len() >= 2 {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in pos {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k] as f64);
                hi[k] = hi[k].max(p[k] as f64);
            }
        }
        let diag =
            ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
        let tol = SEAM_TOLERANCE * diag;
        if tol > 0.0 && tol.is_finite() {
            // A triangle using each welded vertex, for examples.
            let mut vtri = vec![u32::MAX; pos.len()];
            for (t, c) in welded.triangles.chunks_exact(3).enumerate() {
                for &v in c {
                    if vtri[v as usize] == u32::MAX {
                        vtri[v as usize] = t as u32;
                    }
                }
            }
            const MASK: u64 = (1 << 21) - 1;
            let cell = |p: &[f32; 3]| -> [u64; 3] {
                std::array::from_fn(|k| (((p[k] as f64 - lo[k]) / tol).floor() as u64).min(MASK))
            };
            let key = |c: [u64; 3]| (c[0] << 42) | (c[1] << 21) | c[2];
            let mut grid: Vec<(u64, u32)> = pos
                .iter()
                .enumerate()
                .map(|(i, p)| (key(cell(p)), i as u32))
                .collect();
            grid.sort_unstable();
            for i in 0..pos.len() {
                let c = cell(&pos[i]);
                for dx in 0..3u64 {
                    for dy in 0..3u64 {
                        for dz in 0..3u64 {
                            let d = [dx, dy, dz];
                            if (0..3).any(|k| c[k] + d[k] == 0 || c[k] + d[k] - 1 > MASK) {
                                continue;
                            }
                            let nk = key(std::array::from_fn(|k| c[k] + d[k] - 1));
                            let start = grid.partition_point(|g| g.0 < nk);
                            for &(gk, j) in &grid[start..] {
                                if gk != nk {
                                    break;
                                }
                                let j = j as usize;
                                if j > i && dist(pos[i], pos[j]) <= tol {
                                    near += 1;
                                    acc.hit(input_tri(vtri[i]), || vec![pos[i], pos[j]]);
                                }
                            }
                        }
                    }
                }
            }
        }
    }

    acc.finish(
        file,
        "unwelded-seam",
        format!(
            "{signed_zero} position(s) differ only in the sign of zero (build welds these); \
             {near} pair(s) of distinct positions within {SEAM_TOLERANCE:e} of the bounds diagonal"
        ),
        out,
    );
}

fn precision_check(
    file: &str,
    soup: &Soup,
    welded: &Welded,
    edges: &Edges,
    input_tri: &dyn Fn(u32) -> u32,
    out: &mut Vec<Finding>,
) {
    let pos = &welded.positions;
    let Some(max_abs) = pos.iter().flatten().map(|v| v.abs()).reduce(f32::max) else {
        return;
    };
    let u = ulp(max_abs);
    let limit = u / PRECISION_FRACTION;
    let mut shortest = f64::INFINITY;
    let mut acc = Acc::new(soup);
    for e in 0..edges.len() {
        let (a, b) = (edges.a[e] as usize, edges.b[e] as usize);
        let len = dist(pos[a], pos[b]);
        if len > 0.0 {
            shortest = shortest.min(len);
            if len < limit {
                acc.hit(input_tri(edge_tri(edges, e)), || vec![pos[a], pos[b]]);
            }
        }
    }
    let n = acc.count;
    acc.finish(
        file,
        "precision",
        format!(
            "f32 spacing {u:e} at the largest |coordinate| {max_abs:e} exceeds 1/1000 of \
             {n} edge length(s) (shortest {shortest:e})"
        ),
        out,
    );
}

/// Loads `path` with [`crate::load::load`] and lints it; load errors propagate.
pub fn lint_file(path: &Path, max_mult: u32) -> Result<Vec<Finding>> {
    let soup = crate::load::load(path)?;
    Ok(lint_soup(&path.display().to_string(), &soup, max_mult))
}
