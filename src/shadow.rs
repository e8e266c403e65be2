//! Check 3 of `verify`: shadow truth at sample points.
//!
//! For a sample point P and a light L, the winding number of the emitted
//! volume at P (signed crossings of a ray from P in a generic direction, with
//! the exact predicate of [`crate::exact`]) must equal the exact number of
//! input triangles crossed by the open segment from L to P (for a directional
//! light: the ray from P towards the light). A sample whose truth or ray
//! touches an edge, a vertex or a face exactly is *on a face*: reported
//! separately, not compared.
//!
//! The emitted volume is not the exact one even when every orientation is:
//! the contract extrudes corners to infinity in f32 (`toInf(P) = P − L`,
//! rounded), which moves each side quad of a point light by up to 2^-24 of
//! its extrusion direction, a large angle when the light is nearly on the
//! edge's line. A sample in the wedge between an emitted side quad and its
//! exact position is also *on a face* (within rounding of one): it is
//! recognised exactly, as a sample where the volume with exact extrusions
//! gives the truth and the emitted one does not (see [`check_shadow`]).
//!
//! Filters keep this fast: a bounding-volume hierarchy over the triangles
//! (which are both the truth's occluders and the front caps) answers segment
//! and ray queries conservatively; back caps, which all lie at infinity, are
//! crossed or not depending only on the ray direction, so their contribution
//! is computed once per direction.

use crate::exact::{H, Meet, Point, meet, meet_points, passes_beside};
use crate::hint::prefetch_ptr;
use crate::multiplicity::{Light, side_corner, to_infinity};
use crate::verify::{Decoded, Evaluation, Rng};
use rayon::prelude::*;
use std::sync::OnceLock;

/// Generic ray directions (f32 values), tried in order until a sample's ray
/// touches no edge or vertex exactly.
const DIRECTIONS: [[f32; 3]; 6] = [
    [0.381_966, 0.723_607, 0.575_195],
    [-0.618_034, 0.265_041, 0.740_212],
    [0.835_813, -0.446_554, 0.319_284],
    [-0.225_307, -0.866_025, 0.446_918],
    [0.507_107, 0.129_731, -0.852_116],
    [-0.734_522, -0.352_941, -0.579_571],
];

fn fin(p: [f32; 3]) -> H {
    [p[0] as f64, p[1] as f64, p[2] as f64, 1.0]
}

fn hom(p: [f32; 4]) -> H {
    p.map(|v| v as f64)
}

/// Most triangles in a leaf of [`Bvh`]. Why 8, not 4 as until the
/// forty-fourth round: about half the nodes (the dragon's 651,135 →
/// 353,875, the 5M scene's 3,527,215 → 1,908,137, by a local count), so
/// that scene's `verify` peaked at 1666–1672 MiB instead of 1721–1729
/// and built its index in 526–684 ms instead of 602–780, with the shadow
/// check's queries no slower (443–485 against 477–510 ms for 16 lights;
/// one thread, three alternated runs, local timers; on the dragon, four
/// alternations, 141.6–150.0 ms against 143.7–166.1). 16 saved 30 MiB
/// more, with queries the timers could not tell from 8's; 8 is the
/// smaller change to a query's work.
const LEAF: usize = 8;

/// Bounding-volume hierarchy over triangles given as corner positions, in
/// the order of its leaves (see [`ShadowIndex::new`]).
struct Bvh {
    /// Per node: its box, `[min x, min y, min z, max x, max y, max z]`, in
    /// f32 as the corners are (exact; half the memory of f64 boxes).
    boxes: Vec<[f32; 6]>,
    /// Per node: (first, count, 0) for leaves (count > 0), (left, 0, right)
    /// for inner nodes; leaves hold the triangles `first..first + count`.
    nodes: Vec<(u32, u32, u32)>,
}

impl Bvh {
    /// The hierarchy over `tris`, given in Morton order with their `codes`
    /// (ascending): each node split where the highest bit that differs in
    /// its range turns on, down to leaves of [`LEAF`] or fewer triangles.
    fn new(tris: &[[[f32; 3]; 3]], codes: &[u64]) -> Bvh {
        // At most 2n − 1 nodes (every leaf holds a triangle), reserved so
        // the vectors never move; the pages not written are never touched.
        let mut bvh = Bvh {
            boxes: Vec::with_capacity(2 * tris.len()),
            nodes: Vec::with_capacity(2 * tris.len()),
        };
        if !tris.is_empty() {
            bvh.build(tris, codes, 0, tris.len());
        }
        bvh
    }

    /// The node over `tris[first..first + count]` and its subtree; returns
    /// its index.
    fn build(&mut self, tris: &[[[f32; 3]; 3]], codes: &[u64], first: usize, count: usize) -> u32 {
        let node = self.nodes.len() as u32;
        self.nodes.push((first as u32, count as u32, 0));
        self.boxes.push([0.0; 6]);
        if count <= LEAF {
            let mut b = [
                f32::INFINITY,
                f32::INFINITY,
                f32::INFINITY,
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
                f32::NEG_INFINITY,
            ];
            for p in tris[first..first + count].iter().flatten() {
                for k in 0..3 {
                    b[k] = b[k].min(p[k]);
                    b[k + 3] = b[k + 3].max(p[k]);
                }
            }
            self.boxes[node as usize] = b;
            return node;
        }
        // The codes agree above the highest bit that differs in the range,
        // so the halves are the two boxes of the Morton cell the range
        // spans; equal codes are split in the middle.
        let range = &codes[first..first + count];
        let diff = range[0] ^ range[count - 1];
        let mid = if diff == 0 {
            count / 2
        } else {
            let bit = 1u64 << (63 - diff.leading_zeros());
            range.partition_point(|&c| c & bit == 0)
        };
        let left = self.build(tris, codes, first, mid);
        let right = self.build(tris, codes, first + mid, count - mid);
        // A node's box is its children's together.
        let (l, r) = (self.boxes[left as usize], self.boxes[right as usize]);
        self.boxes[node as usize] = [0, 1, 2, 3, 4, 5].map(|k| {
            if k < 3 {
                l[k].min(r[k])
            } else {
                l[k].max(r[k])
            }
        });
        self.nodes[node as usize] = (left, 0, right);
        node
    }

    /// Calls `f` for every triangle whose box may meet `p + t·dir`, t in [0, t_max].
    fn query(&self, p: [f64; 3], dir: [f64; 3], t_max: f64, f: impl FnMut(u32)) {
        self.query_grown(p, dir, t_max, 0.0, 0.0, f)
    }

    /// [`Bvh::query`] with every box grown by `grow` times its largest
    /// coordinate's magnitude plus `grow_abs` on each side, so that it also
    /// holds triangles whose corners moved by that much.
    fn query_grown(
        &self,
        p: [f64; 3],
        dir: [f64; 3],
        t_max: f64,
        grow: f64,
        grow_abs: f64,
        mut f: impl FnMut(u32),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0u32];
        while let Some(n) = stack.pop() {
            if !hits(&self.boxes[n as usize], p, dir, t_max, grow, grow_abs) {
                continue;
            }
            let (a, count, right) = self.nodes[n as usize];
            if count > 0 {
                (a..a + count).for_each(&mut f);
            } else {
                stack.push(a);
                stack.push(right);
            }
        }
    }
}

/// The low 21 bits of `x` spread to every third bit (bit i to bit 3i): one
/// axis of a Morton code.
fn spread3(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

/// Conservative slab test (boxes padded well beyond f64 rounding, and
/// further by `grow` times their largest coordinate's magnitude plus
/// `grow_abs`).
fn hits(b: &[f32; 6], p: [f64; 3], dir: [f64; 3], t_max: f64, grow: f64, grow_abs: f64) -> bool {
    let b = b.map(|v| v as f64);
    let (mut t0, mut t1) = (0.0f64, t_max);
    for k in 0..3 {
        let pad = (1e-9 + grow) * (b[k + 3] - b[k]).abs().max(b[k].abs()).max(b[k + 3].abs())
            + grow_abs
            + 1e-300;
        let (lo, hi) = (b[k] - pad, b[k + 3] + pad);
        if dir[k] == 0.0 {
            if p[k] < lo || p[k] > hi {
                return false;
            }
            continue;
        }
        let (mut a, mut c) = ((lo - p[k]) / dir[k], (hi - p[k]) / dir[k]);
        if a > c {
            std::mem::swap(&mut a, &mut c);
        }
        // Widen by a relative margin: the divisions above round.
        let m = 1e-9 * (a.abs().max(c.abs())) + 1e-300;
        t0 = t0.max(a - m);
        t1 = t1.min(c + m);
        if t0 > t1 {
            return false;
        }
    }
    true
}

/// Per-mesh state reused for every light.
pub struct ShadowIndex {
    /// The caps triangles' corners, in the hierarchy's order.
    tris: Vec<[[f32; 3]; 3]>,
    /// Per entry of `tris`: its caps triangle.
    ids: Vec<u32>,
    bvh: Bvh,
}

impl ShadowIndex {
    /// Indexes the caps triangles of a decoded mesh: sorted by the Morton
    /// code of their corner sums (21 bits per axis over three times the
    /// positions' bounds; ties by id, so the order is fully determined),
    /// then a hierarchy over that order (`Bvh::new`). Why not the median
    /// along each node's widest axis, as before: a selection per node cost
    /// about three comparisons per triangle per level, and with the
    /// triangles read through ids it took 308–346 ms on the 871k-triangle
    /// dragon, against 159–164 ms for this (one thread, local timers;
    /// benches/ROUNDS.md, Forty-first round). Since the forty-third round
    /// the codes are sorted by the weld's radix sort instead of rayon's
    /// comparison sort (30.8–31.3 → 18.7–18.9 ms), over bounds found
    /// without a pass over the triangles (15.0–18.4 → 0.2 ms), and the
    /// hierarchy's boxes are f32 with room reserved for every node (its
    /// build 39.6–41.8 → 32.3–35.4 ms; local timers, benches/ROUNDS.md).
    pub fn new(d: &Decoded) -> ShadowIndex {
        // How far ahead the loops below ask for rows read anywhere.
        const FAR: usize = 16;
        const NEAR: usize = 8;
        // Written out: as maps over the axes they compiled to calls.
        let sum = |t: &[u32; 3]| {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| &d.positions[i as usize]);
            let axis = |k: usize| a[k] as f64 + b[k] as f64 + c[k] as f64;
            [axis(0), axis(1), axis(2)]
        };
        // Bounds of the corner sums: three times the positions' (a pass
        // over the positions in order, where the sums' own bounds took one
        // over every triangle's corners, 15–18 ms of the dragon's). Any
        // bounds give a valid order; these may make it a little coarser.
        let (lo, hi) = crate::build::bounds(&d.positions);
        let (lo, hi) = (lo.map(|v| 3.0 * v as f64), hi.map(|v| 3.0 * v as f64));
        let top = ((1u64 << 21) - 1) as f64;
        let scale = [0, 1, 2].map(|k| {
            if hi[k] > lo[k] {
                top / (hi[k] - lo[k])
            } else {
                0.0
            }
        });
        // Each triangle's code above its number, sorted by the weld's
        // radix sort (which orders by the high 96 bits: here the code and
        // the number, the order of `(code, number)` pairs).
        let mut words = vec![0u128; d.caps.len()];
        words
            .par_chunks_mut(1 << 14)
            .zip(d.caps.par_chunks(1 << 14))
            .enumerate()
            .for_each(|(b, (out, caps))| {
                for (j, (w, t)) in out.iter_mut().zip(caps).enumerate() {
                    // The corners `NEAR` triangles on, read anywhere.
                    if let Some(next) = caps.get(j + NEAR) {
                        for &c in next {
                            crate::hint::prefetch_whole(&d.positions[c as usize]);
                        }
                    }
                    let s = sum(t);
                    let q = |k: usize| ((s[k] - lo[k]) * scale[k]).clamp(0.0, top) as u64;
                    let code = spread3(q(0)) << 2 | spread3(q(1)) << 1 | spread3(q(2));
                    let i = (b << 14) + j;
                    *w = (code as u128) << 64 | (i as u128) << 32;
                }
            });
        crate::weld::sort_position_words(&mut words);
        let codes: Vec<u64> = words.iter().map(|&w| (w >> 64) as u64).collect();
        let ids: Vec<u32> = words.iter().map(|&w| (w >> 32) as u32).collect();
        drop(words);
        // In Morton order the caps rows and their corners are reads
        // anywhere: each row is asked for `FAR` triangles ahead, and its
        // corners `NEAR` ahead, once the row has come.
        let mut tris = vec![[[0f32; 3]; 3]; ids.len()];
        tris.par_chunks_mut(1 << 14)
            .zip(ids.par_chunks(1 << 14))
            .for_each(|(out, ids)| {
                for (j, (o, &i)) in out.iter_mut().zip(ids).enumerate() {
                    if let Some(&far) = ids.get(j + FAR) {
                        crate::hint::prefetch(&d.caps[far as usize]);
                    }
                    if let Some(&near) = ids.get(j + NEAR) {
                        for &c in &d.caps[near as usize] {
                            crate::hint::prefetch_whole(&d.positions[c as usize]);
                        }
                    }
                    let c = &d.caps[i as usize];
                    *o = [
                        d.positions[c[0] as usize],
                        d.positions[c[1] as usize],
                        d.positions[c[2] as usize],
                    ];
                }
            });
        let bvh = Bvh::new(&tris, &codes);
        ShadowIndex { tris, ids, bvh }
    }
}

/// Sample points: half in and around the bounds, half on a receiver plane
/// below the model (y up, as in glTF), all f32.
pub fn choose_samples(d: &Decoded, count: usize, seed: u64) -> Vec<[f32; 3]> {
    let (lo, hi) = crate::build::bounds(&d.positions);
    let c = [0, 1, 2].map(|k| 0.5 * (lo[k] as f64 + hi[k] as f64));
    let size = (0..3)
        .map(|k| hi[k] as f64 - lo[k] as f64)
        .fold(1e-30, f64::max);
    let mut rng = Rng::new(seed ^ 0x5A5A_5A5A);
    (0..count)
        .map(|i| {
            if i % 2 == 0 {
                [0, 1, 2].map(|k| (c[k] + (rng.unit() - 0.5) * 1.5 * size) as f32)
            } else {
                [
                    (c[0] + (rng.unit() - 0.5) * 3.0 * size) as f32,
                    (lo[1] as f64 - 0.25 * size) as f32,
                    (c[2] + (rng.unit() - 0.5) * 3.0 * size) as f32,
                ]
            }
        })
        .collect()
}

/// Result of the shadow-truth check for one light.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ShadowReport {
    /// Samples compared.
    pub samples: u64,
    /// Samples not compared: lying exactly on a volume face, or (see
    /// `extrusion_rounding`) within the f32 rounding of one.
    pub on_faces: u64,
    /// Of `on_faces`: samples whose winding differs from the truth only
    /// because the contract extrudes corners to infinity in f32 (`toInf`):
    /// the volume extruded exactly gives the truth there (see
    /// [`check_shadow`]).
    pub extrusion_rounding: u64,
    /// Samples whose winding number differs from the exact occluder count.
    pub mismatches: u64,
    /// The first mismatch, in words.
    pub first_mismatch: Option<String>,
}

/// For each sample, the side triangles that a ray from it along one
/// direction may cross, for both the emitted and the exactly extruded
/// corners; the exact test decides.
///
/// Two filters, both conservative. First a coarse one: each side triangle
/// visits the samples in its wedge of the [`Fan`] around the light, or,
/// when the fan cannot tell, the cells its projected bounds reach in a grid
/// of the samples' projections along the direction (unbounded where a
/// corner at infinity points). Then, per sample visited,
/// [`passes_beside`] with slack for the exact extrusions. The grid alone
/// visited about 70 samples per side triangle on the dragon (2–4.7M
/// filter calls per light, 23 ms), the fan about 0.1–0.25 (6–16 thousand
/// calls; the candidates 5.7–8.2 ms per point light, 2.2–2.7 ms per
/// directional one, local timers, benches/ROUNDS.md, Forty-second
/// round).
///
/// Side triangles reach far (a corner at infinity makes their projection
/// unbounded), so the grid alone left about 12,000 candidates per sample
/// on the 871k-triangle dragon, each an exact test, and 13M to 38M grid
/// entries per light to build (sides in cells; bucketing the samples
/// instead keeps the grid at one entry per sample).
struct SideCandidates {
    /// Per sample, indices into the side triangles.
    lists: Vec<Vec<u32>>,
}

/// Relative slack of [`passes_beside`] here, so its answer covers the
/// exact extrusion `P − L` of every corner at infinity as well as the
/// emitted f32 one (one rounding: relative 2^-24, within `slack / 4`).
const EXTRUSION_SLACK: f64 = 1.0 / (1u64 << 20) as f64;

/// The samples ordered around the planes that hold their rays, the first
/// filter of [`SideCandidates`].
///
/// Every ray along one direction `d` lies in a plane through the line
/// from the light along `d` (a point light), or in a plane spanned by `d`
/// and the light's direction (a directional light): a pencil of planes,
/// one per sample. A side triangle lies in the wedge of that pencil its
/// corners span, since each of its points is the light plus a positive
/// combination of its corners' offsets from the light and of its
/// directions. So the ray from a sample can meet it only when the
/// sample's plane is in that wedge. Ordered around the pencil, the
/// samples in a wedge are one range, found from a table of bins
/// ([`KeyBins`]): on the dragon a side triangle's wedge holds well under
/// one of 256 samples, where the grid of [`SideCandidates`] visits about
/// 70.
///
/// Keys: for a point light L, the pseudo-angle ([`pseudo_angle`]) of
/// `(P − L) × d` in a basis of the plane normal to `d` (the cross product
/// is the same for every point of the ray, so a far hit point adds no
/// rounding); for a directional light, `P · (L × d)`. A side quad's
/// wedge, for both its triangles, runs between the keys of its finite
/// corners A and B ([`Fan::side_wedge`]: each corner at infinity lies in
/// the plane of its finite corner), widened by their error bounds: f64
/// rounding, and for a point light the f32 rounding of a direction at
/// infinity (relative 2^-24), which covers the exact extrusion too. A quad
/// whose wedge is not certainly narrower than a half-turn (the light
/// about on the line through A and B), or whose keys are uncertain (a
/// corner near the light's line), has no wedge: the grid decides. Samples
/// whose keys are uncertain (near the line) are tested against every
/// wedge.
struct Fan {
    kind: FanKind,
    /// `(key, sample)` of the samples with certain keys, by key.
    sorted: Vec<(f64, u32)>,
    /// The samples every side triangle is tested against.
    always: Vec<u32>,
    /// The largest error of a key in `sorted`.
    sample_slack: f64,
    /// Where a key falls in `sorted`.
    bins: KeyBins,
}

/// Where a key falls among sorted keys, read from a table of equal bins
/// over their range, where a key's bin mostly holds no other key. Why not
/// a binary search: with 256 samples its eight dependent steps, twice per
/// side quad, made [`SideCandidates::new`] take 47.6–53.8 ms for the
/// dragon's 16 lights instead of 38.6–40.3 (one thread, local timers,
/// benches/ROUNDS.md, Forty-third round).
struct KeyBins {
    /// The smallest key.
    low: f64,
    /// Bins per unit of key.
    scale: f64,
    /// `first[b]`: how many keys lie in the bins below `b` (one more entry
    /// than bins).
    first: Vec<u32>,
}

impl KeyBins {
    /// Bins per key.
    const PER_KEY: usize = 4;

    /// The table over `sorted`'s keys (ascending, finite).
    fn new(sorted: &[(f64, u32)]) -> KeyBins {
        let count = Self::PER_KEY * sorted.len() + 1;
        let (low, high) = match (sorted.first(), sorted.last()) {
            (Some(a), Some(b)) => (a.0, b.0),
            _ => (0.0, 0.0),
        };
        let scale = if high > low {
            (count - 1) as f64 / (high - low)
        } else {
            0.0
        };
        let mut bins = KeyBins {
            low,
            scale,
            first: vec![0; count + 1],
        };
        for &(key, _) in sorted {
            let b = bins.bin(key);
            bins.first[b + 1] += 1;
        }
        for b in 0..count {
            bins.first[b + 1] += bins.first[b];
        }
        bins
    }

    /// The bin of `x`, monotone in `x`: a key in a lower bin than `x` is
    /// below `x`, and one in a higher bin is above it (NaN: bin 0).
    #[inline(always)]
    fn bin(&self, x: f64) -> usize {
        ((x - self.low) * self.scale).clamp(0.0, (self.first.len() - 2) as f64) as usize
    }

    /// How many of `sorted`'s keys are below `x` (or, `inclusive`, at most
    /// `x`): `partition_point` of that, by a scan of `x`'s bin.
    #[inline(always)]
    fn count(&self, sorted: &[(f64, u32)], x: f64, inclusive: bool) -> usize {
        let mut i = self.first[self.bin(x)] as usize;
        while i < sorted.len() && (sorted[i].0 < x || inclusive && sorted[i].0 == x) {
            i += 1;
        }
        i
    }
}

#[derive(Clone, Copy)]
enum FanKind {
    /// A point light at `l`: keys are pseudo-angles of `(x − l) × d` in the
    /// basis `u`, `v`.
    Point {
        l: [f64; 3],
        d: [f64; 3],
        u: [f64; 3],
        v: [f64; 3],
    },
    /// A directional light: keys are `x · n`, `n = L × d`, with error at
    /// most `slack · |x|₁`.
    Directional { n: [f64; 3], slack: f64 },
}

/// A monotone stand-in for the angle of `(x, y)` from the positive x axis,
/// in `[0, 4)`: 1 per quarter turn, exact at the axes, and its slope
/// against the angle between 1/2 and 1. So an angle error `e` moves it by
/// at most `e`, and a half-turn is 2 exactly. No `atan2`: a division.
#[inline(always)]
fn pseudo_angle(x: f64, y: f64) -> f64 {
    let a = y / (x.abs() + y.abs());
    if x >= 0.0 {
        if y >= 0.0 { a } else { 4.0 + a }
    } else {
        2.0 - a
    }
}

/// Keys of [`Fan`] whose relative error is above this are uncertain.
const FAN_UNCERTAIN: f64 = 1e-3;

/// Bound on the f64 rounding of the few products and sums that make one
/// key from f32 inputs, relative to the sum of their magnitudes (the
/// largest chain is a difference, a cross product and a dot product: under
/// 12 roundings of 2^-53 each).
const FAN_ROUNDING: f64 = 1e-14;

/// Two unit vectors, about orthogonal, spanning the plane normal to `dir`.
fn plane_basis(dir: [f32; 3]) -> ([f64; 3], [f64; 3]) {
    let d = dir.map(|x| x as f64);
    let n = dot3(d, d).sqrt();
    let d = d.map(|x| x / n);
    let a = if d[0].abs() < 0.5 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let u = cross3(d, a);
    let u = u.map(|x| x / dot3(u, u).sqrt());
    (u, cross3(d, u))
}

fn cross3(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot3(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm1(a: [f64; 3]) -> f64 {
    a[0].abs() + a[1].abs() + a[2].abs()
}

impl Fan {
    /// The fan of `light` and the ray direction `dir`, with `samples`
    /// keyed; `None` when the light's `w` is neither 0 nor 1, or a
    /// directional light is about parallel to `dir`.
    fn new(light: Light, dir: [f32; 3], samples: &[[f32; 3]]) -> Option<Fan> {
        let d = dir.map(|x| x as f64);
        let (u, v) = plane_basis(dir);
        let lh = hom(light);
        let l = [lh[0], lh[1], lh[2]];
        let kind = if lh[3] == 1.0 {
            FanKind::Point { l, d, u, v }
        } else if lh[3] == 0.0 {
            let n = cross3(l, d);
            // |n − L × d| and the dot's rounding, per unit of |x|₁.
            let slack = FAN_ROUNDING * norm1(l) * norm1(d);
            // (NaN too: an overflowed product has no fan.)
            let sure = norm1(n) > FAN_UNCERTAIN * norm1(l) * norm1(d);
            if !sure {
                return None;
            }
            FanKind::Directional { n, slack }
        } else {
            return None;
        };
        let mut fan = Fan {
            kind,
            sorted: Vec::with_capacity(samples.len()),
            always: Vec::new(),
            sample_slack: 0.0,
            bins: KeyBins::new(&[]),
        };
        let directional = matches!(kind, FanKind::Directional { .. });
        for (j, s) in samples.iter().enumerate() {
            // Near the line of a point light, where a sample's turn is
            // uncertain beyond 1e-9 (about 1e-5 rad from it), a sample is
            // tested against everything rather than widen every wedge.
            match fan.key(fin(*s), 0.0) {
                Some((key, err)) if directional || err <= 1e-9 => {
                    fan.sorted.push((key, j as u32));
                    fan.sample_slack = fan.sample_slack.max(err);
                }
                _ => fan.always.push(j as u32),
            }
        }
        fan.sorted.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        fan.bins = KeyBins::new(&fan.sorted);
        Some(fan)
    }

    /// The key of the homogeneous point `c` (a direction when `c[3]` is 0)
    /// and a bound on its error, given a relative error `rel` of the
    /// direction's components besides the f64 rounding; `None` when the
    /// key is uncertain (for a directional light, a direction has none:
    /// `None` too, and [`Fan::wedge`] skips it).
    #[inline(always)]
    fn key(&self, c: H, rel: f64) -> Option<(f64, f64)> {
        match self.kind {
            FanKind::Point { l, d, u, v } => {
                let x = if c[3] == 1.0 {
                    [c[0] - l[0], c[1] - l[1], c[2] - l[2]]
                } else if c[3] == 0.0 {
                    [c[0], c[1], c[2]]
                } else {
                    return None;
                };
                let m = cross3(x, d);
                let (a, b) = (dot3(m, u), dot3(m, v));
                // Per component of (a, b): the rounding, and the
                // direction's own error moved through the cross product.
                let err = (FAN_ROUNDING + 2.0 * rel) * norm1(x) * norm1(d) * 2.0;
                let size = a.abs().max(b.abs());
                // An error of `err` per component turns (a, b) by at most
                // about √2 · err / size, and the pseudo-angle by no more.
                let turn = 2.0 * err / size;
                (turn.is_finite() && turn <= FAN_UNCERTAIN).then(|| (pseudo_angle(a, b), turn))
            }
            FanKind::Directional { n, slack } => {
                if c[3] != 1.0 {
                    return None;
                }
                let x = [c[0], c[1], c[2]];
                let key = dot3(x, n);
                let err = slack * norm1(x);
                (key.is_finite() && err.is_finite()).then_some((key, err))
            }
        }
    }

    /// The range of keys a ray must have to meet either triangle of the
    /// side quad on `a`, `b` (as emitted, or extruded exactly), or `None`
    /// when the fan cannot tell. For a point light the range starts in
    /// `[0, 4)` and may run past 4, around the turn.
    ///
    /// Every point of the quad is the light plus a positive combination of
    /// `a − L` and `b − L` (a point light: its corners at infinity are those
    /// directions, rounded by `toInf` by a relative 2^-24 at most) or
    /// spanned by `a`, `b` and the direction `−L` (a directional light, the
    /// pencil's own direction: the same key): so its keys run between the
    /// keys of `a` and `b`, for a point light the shorter way round. Each
    /// finite corner's key, with the error of a direction so rounded, also
    /// holds the key of its corner at infinity, emitted or exact. One wedge
    /// from two keys for both triangles: six keys, one per corner of each
    /// triangle, took about twice as long (local timers, benches/ROUNDS.md,
    /// Forty-third round).
    fn side_wedge(&self, a: [f32; 3], b: [f32; 3]) -> Option<(f64, f64)> {
        match self.kind {
            FanKind::Point { .. } => {
                let rel = 1.0 / (1u64 << 24) as f64;
                let (ka, ea) = self.key(fin(a), rel)?;
                let (kb, eb) = self.key(fin(b), rel)?;
                let err = ea.max(eb) + self.sample_slack;
                let (lo, hi) = (ka.min(kb), ka.max(kb));
                // The shorter way round, which must stay under a half-turn
                // (2) even with both keys off by their error.
                let (lo, hi) = if hi - lo <= 2.0 {
                    (lo, hi)
                } else {
                    (hi, lo + 4.0)
                };
                // Around the turn from a start in [0, 4).
                let (lo, hi) = if lo - err < 0.0 {
                    (lo - err + 4.0, hi + err + 4.0)
                } else {
                    (lo - err, hi + err)
                };
                (hi - lo < 2.0).then_some((lo, hi))
            }
            FanKind::Directional { .. } => {
                let (ka, ea) = self.key(fin(a), 0.0)?;
                let (kb, eb) = self.key(fin(b), 0.0)?;
                Some((
                    (ka - ea).min(kb - eb) - self.sample_slack,
                    (ka + ea).max(kb + eb) + self.sample_slack,
                ))
            }
        }
    }

    /// Calls `f` with each sample whose key is in `[lo, hi]` (for a point
    /// light, around the turn: `hi` may be 4 or more, `lo` is below 4 and
    /// `hi − lo` under 2), then with every sample of [`Fan::always`].
    fn for_each_in(&self, (lo, hi): (f64, f64), mut f: impl FnMut(u32)) {
        let mut range = |lo: f64, hi: f64| {
            let from = self.bins.count(&self.sorted, lo, false);
            let to = self.bins.count(&self.sorted, hi, true);
            for e in &self.sorted[from..to.max(from)] {
                f(e.1);
            }
        };
        match self.kind {
            FanKind::Point { .. } if hi >= 4.0 => {
                range(lo, 4.0);
                range(0.0, hi - 4.0);
            }
            _ => range(lo, hi),
        }
        for &j in &self.always {
            f(j);
        }
    }
}

impl SideCandidates {
    fn new(sides: &[Emitted], light: Light, dir: [f32; 3], samples: &[[f32; 3]]) -> SideCandidates {
        let dh = [dir[0] as f64, dir[1] as f64, dir[2] as f64, 0.0];
        let (u, v) = plane_basis(dir);
        let proj = |q: [f64; 3]| [dot3(q, u), dot3(q, v)];
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for s in samples {
            let q = proj(s.map(|x| x as f64));
            for k in 0..2 {
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
        }
        let span = (0..2)
            .map(|k| hi[k] - lo[k])
            .fold(0.0, f64::max)
            .max(1e-300);
        for k in 0..2 {
            lo[k] -= 1e-6 * span;
            hi[k] += 1e-6 * span;
        }
        // About one sample per cell.
        let grid = (samples.len() as f64).sqrt().ceil().clamp(1.0, 64.0) as usize;
        let cell = [0, 1].map(|k| (hi[k] - lo[k]) / grid as f64);
        let cell_of =
            |q: f64, k: usize| (((q - lo[k]) / cell[k]).floor().max(0.0) as usize).min(grid - 1);
        let mut cells = vec![Vec::new(); grid * grid];
        for (j, s) in samples.iter().enumerate() {
            let q = proj(s.map(|x| x as f64));
            cells[cell_of(q[1], 1) * grid + cell_of(q[0], 0)].push(j as u32);
        }
        let points: Vec<H> = samples.iter().map(|&s| fin(s)).collect();
        let origin = [0, 1, 2].map(|k| {
            let (lo, hi) = samples
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), p| {
                    (a.min(p[k]), b.max(p[k]))
                });
            (0.5 * (lo as f64 + hi as f64)) as f32 as f64
        });
        let moved: Vec<([f64; 3], [f64; 3])> = samples
            .iter()
            .map(|s| {
                let q = [0, 1, 2].map(|k| s[k] as f64 - origin[k]);
                (q, q.map(f64::abs))
            })
            .collect();
        let fan = Fan::new(light, dir, samples);
        let mut lists = vec![Vec::new(); samples.len()];
        // The quad's wedge, shared by its two triangles (`emitted_sides`
        // lists them one after the other).
        let mut quad_wedge: Option<(&Emitted, Option<(f64, f64)>)> = None;
        for (i, e) in sides.iter().enumerate() {
            // Made when first needed: most triangles' wedges hold no sample.
            let mut corners = None;
            let mut linear = None;
            let mut test = |j: u32| {
                let (q, q_abs) = &moved[j as usize];
                let corners = corners.get_or_insert_with(|| e.corners(light));
                let linear = linear.get_or_insert_with(|| {
                    EdgeFunctions::new(corners, [dh[0], dh[1], dh[2]], origin)
                });
                if linear.as_ref().is_some_and(|f| f.beside(q, q_abs)) {
                    return;
                }
                let p = &points[j as usize];
                if !passes_beside(p, &dh, corners, EXTRUSION_SLACK) {
                    lists[j as usize].push(i as u32);
                }
            };
            if let Some(fan) = &fan {
                let wedge = match quad_wedge {
                    Some((q, w)) if q.a == e.a && q.b == e.b => w,
                    _ => fan.side_wedge(e.a, e.b),
                };
                quad_wedge = Some((e, wedge));
                if let Some(wedge) = wedge {
                    fan.for_each_in(wedge, &mut test);
                    continue;
                }
            }
            let corners = e.corners(light);
            let mut blo = [f64::INFINITY; 2];
            let mut bhi = [f64::NEG_INFINITY; 2];
            for c in &corners {
                let q = proj([c[0], c[1], c[2]]);
                let scale = c[0].abs().max(c[1].abs()).max(c[2].abs());
                if c[3] == 0.0 {
                    // A direction: the region is unbounded where it points.
                    // The tolerance also covers the exact extrusion (`exact`
                    // corners), which differs from this rounded one by at
                    // most 2^-24 of each component: under 1.1e-7 · scale in
                    // projection.
                    for k in 0..2 {
                        let tol = 1e-6 * scale;
                        if q[k] > -tol {
                            bhi[k] = f64::INFINITY;
                        }
                        if q[k] < tol {
                            blo[k] = f64::NEG_INFINITY;
                        }
                    }
                } else {
                    for k in 0..2 {
                        let pad = 1e-9 * scale + 1e-300;
                        blo[k] = blo[k].min(q[k] - pad);
                        bhi[k] = bhi[k].max(q[k] + pad);
                    }
                }
            }
            if (0..2).any(|k| bhi[k] < lo[k] || blo[k] > hi[k]) {
                continue;
            }
            let range = |k: usize| {
                let a = ((blo[k] - lo[k]) / cell[k]).floor().max(0.0) as usize;
                let b = ((bhi[k] - lo[k]) / cell[k]).floor().min((grid - 1) as f64) as usize;
                a.min(grid - 1)..=b
            };
            for y in range(1) {
                for x in range(0) {
                    for &j in &cells[y * grid + x] {
                        test(j);
                    }
                }
            }
        }
        SideCandidates { lists }
    }
}

/// [`passes_beside`]'s three edge determinants for one side triangle and a
/// fixed ray direction `r`, as affine functions of the ray's start `p`, so
/// that each sample costs two dot products per edge.
///
/// With `u = t − p` for a finite corner and `u = t` for a direction,
/// `F(p) = r · (u_k × u_l)` is exactly `c + n · p`, where `c = r · (t_k ×
/// t_l)` and `n = [t_k finite] (r × t_l) − [t_l finite] (r × t_k)` (the
/// term `r · (p × p)` is zero). Coordinates are taken from `origin` (the
/// samples' centre), so the bound below does not grow with the distance of
/// the model from the world's origin.
///
/// The bound: every value here is a sum of at most a few products of f32
/// values, so the f64 rounding of `c`, `n`, `n · p` and the moves to the
/// origin stays below `32 · 2^-53 · (P_c + P_n · |p|)`, with `P_c = |r| ·
/// (|t_k| × |t_l|)` and `P_n` the same sum of absolute terms for `n`
/// (absolute values taken before multiplying). The exact extrusion of a
/// corner at infinity moves it by a relative 2^-24 or less in each
/// component, which changes `F` by less than `2 · 2^-24 · (P_c + P_n ·
/// |p|)`; [`EXTRUSION_SLACK`] (2^-20) covers that. So `F > B` is certainly
/// positive for both the emitted and the exactly extruded triangle, and
/// one certainly positive with one certainly negative edge is
/// [`passes_beside`]'s "beside" (its proof holds for any valid bound): such
/// a pair is dropped without the permanents and branches of the full
/// filter, which decides every other pair as before.
///
/// Why: the candidate lists of the dragon make 2–4.7M filter calls per
/// light, of which 2,000–7,400 (under 0.3%) are candidates; the full filter
/// was a quarter of `verify`'s samples.
struct EdgeFunctions {
    /// Per edge: `c`, `n`, `P_c`, `P_n` (already multiplied by the bound's
    /// factor).
    edges: [(f64, [f64; 3], f64, [f64; 3]); 3],
}

impl EdgeFunctions {
    /// `None` when a corner's `w` is neither 0 nor 1 (the full filter
    /// declines those too).
    fn new(t: &[H; 3], r: [f64; 3], origin: [f64; 3]) -> Option<EdgeFunctions> {
        if !t.iter().all(|c| c[3] == 0.0 || c[3] == 1.0) {
            return None;
        }
        let finite = t.map(|c| c[3] == 1.0);
        let u = [0, 1, 2].map(|i| {
            [0, 1, 2].map(|k| {
                if finite[i] {
                    t[i][k] - origin[k]
                } else {
                    t[i][k]
                }
            })
        });
        let (cross, dot) = (cross3, dot3);
        // The absolute counterpart of `cross`: what bounds its rounding.
        let cross_abs = |a: [f64; 3], b: [f64; 3]| {
            let (a, b) = (a.map(f64::abs), b.map(f64::abs));
            [
                a[1] * b[2] + a[2] * b[1],
                a[2] * b[0] + a[0] * b[2],
                a[0] * b[1] + a[1] * b[0],
            ]
        };
        let r_abs = r.map(f64::abs);
        let factor = EXTRUSION_SLACK + 32.0 * f64::EPSILON / 2.0;
        let edges = [(0, 1), (1, 2), (2, 0)].map(|(k, l)| {
            let c = dot(r, cross(u[k], u[l]));
            let pc = dot(r_abs, cross_abs(u[k], u[l]));
            let mut n = [0.0; 3];
            let mut pn = [0.0; 3];
            if finite[k] {
                let (x, xa) = (cross(r, u[l]), cross_abs(r, u[l]));
                n = [0, 1, 2].map(|a| n[a] + x[a]);
                pn = [0, 1, 2].map(|a| pn[a] + xa[a]);
            }
            if finite[l] {
                let (x, xa) = (cross(r, u[k]), cross_abs(r, u[k]));
                n = [0, 1, 2].map(|a| n[a] - x[a]);
                pn = [0, 1, 2].map(|a| pn[a] + xa[a]);
            }
            (c, n, factor * pc, pn.map(|v| factor * v))
        });
        Some(EdgeFunctions { edges })
    }

    /// True when the ray from `q` (a sample, from the origin; `q_abs` its
    /// absolute values) certainly passes beside the triangle.
    #[inline(always)]
    fn beside(&self, q: &[f64; 3], q_abs: &[f64; 3]) -> bool {
        let (mut pos, mut neg) = (false, false);
        for (c, n, pc, pn) in &self.edges {
            let f = c + (n[0] * q[0] + n[1] * q[1] + n[2] * q[2]);
            let b = pc + (pn[0] * q_abs[0] + pn[1] * q_abs[1] + pn[2] * q_abs[2]);
            pos |= f > b;
            neg |= f < -b;
        }
        pos && neg
    }
}

/// A side triangle the shaders emit: which one of the side quad of edge
/// (A, B) with multiplicity `m` (nonzero), whose stencil weight is |m|.
/// Its corners are made where they are used ([`Emitted::corners`],
/// [`Emitted::exact`]): kept, they were 320 bytes per triangle, 35 MB of
/// fresh memory per light on the dragon.
struct Emitted {
    a: [f32; 3],
    b: [f32; 3],
    m: i32,
    /// The quad's second triangle (draw vertices 3, 4, 5).
    second: bool,
}

impl Emitted {
    /// The triangle's corners as indices into (A, B, A∞, B∞).
    fn ids(&self) -> [usize; 3] {
        let tri = if self.second { [3, 4, 5] } else { [0, 1, 2] };
        tri.map(|v| side_corner(v, self.m) as usize)
    }

    /// The corners as emitted (corners at infinity rounded by the
    /// contract's `toInf`).
    ///
    /// Written out rather than read from an array of the quad's corners by
    /// [`Emitted::ids`]: that array, stored and at once read back at a
    /// computed place, stalled the CPU on every triangle (the loads waited
    /// for the stores; `perf annotate` of [`SideCandidates::new`]). A test
    /// checks both give the same.
    #[inline(always)]
    fn corners(&self, light: Light) -> [H; 3] {
        let (a, b, a_inf) = (fin(self.a), fin(self.b), inf(self.a, light));
        match (self.second, self.m > 0) {
            (false, true) => [a_inf, b, a],
            (true, true) => [b, a_inf, inf(self.b, light)],
            (false, false) => [a, b, a_inf],
            (true, false) => [inf(self.b, light), a_inf, b],
        }
    }

    /// The same triangle with its corners at infinity extruded exactly.
    fn exact(&self, light: Light) -> [Point; 3] {
        let quad = [
            Point::H(fin(self.a)),
            Point::H(fin(self.b)),
            inf_exact(self.a, light),
            inf_exact(self.b, light),
        ];
        self.ids().map(|i| quad[i])
    }

    /// The stencil weight.
    fn weight(&self) -> i32 {
        self.m.abs()
    }
}

/// Exact shadow truth at `p`: the number of triangles the open segment from
/// `p` to the light crosses (the ray towards a directional light), or `None`
/// when `p` lies on a triangle or the segment touches one degenerately (an
/// edge, a vertex, or lying in its plane), where "in shadow" has no single
/// answer.
pub fn occluders(index: &ShadowIndex, light: Light, p: [f32; 3]) -> Option<u32> {
    let lh = hom(light);
    let ph = fin(p);
    let (dir, t_max) = if light[3] == 0.0 {
        ([lh[0], lh[1], lh[2]], f64::INFINITY)
    } else {
        ([lh[0] - ph[0], lh[1] - ph[1], lh[2] - ph[2]], 1.0)
    };
    let mut count = 0u32;
    let mut ambiguous = false;
    index.bvh.query([ph[0], ph[1], ph[2]], dir, t_max, |i| {
        match meet(ph, lh, index.tris[i as usize].map(fin)) {
            Meet::Cross(_) => count += 1,
            Meet::None => {}
            Meet::AOnTriangle | Meet::Degenerate => ambiguous = true,
        }
    });
    (!ambiguous).then_some(count)
}

/// What a ray from a sample to infinity meets.
enum Cast {
    /// The winding number of the volume at the sample.
    Winding(i32),
    /// The sample lies on a triangle of the volume.
    OnFace,
    /// The ray touches an edge or vertex: try the next direction.
    Degenerate,
}

/// Corner `p` extruded to infinity as the shaders do (`toInf`, rounded).
fn inf(p: [f32; 3], light: Light) -> H {
    hom(to_infinity(p, light))
}

/// Corner `p` extruded to infinity exactly: `P − L` for a point light.
fn inf_exact(p: [f32; 3], light: Light) -> Point {
    if light[3] == 1.0 {
        Point::Away(fin(p), hom(light))
    } else {
        Point::H(inf(p, light))
    }
}

/// False for a triangle with two equal corners or a corner that is no point.
///
/// Triangles with two equal corners (e.g. every back cap of a directional
/// light) have no area and no boundary: no ray crosses them. A corner
/// (0, 0, 0, 0) cannot occur (the contract gives 0 when the light is on a
/// corner), but would be no point at all. (`meet` answers `None` for both:
/// every determinant with such a triangle is 0. So a triangle kept for one
/// of its two versions is harmless in the other.)
fn usable(c: &[H; 3]) -> bool {
    c[0] != c[1] && c[1] != c[2] && c[0] != c[2] && !c.iter().any(|h| h.iter().all(|&v| v == 0.0))
}

/// [`usable`] for exactly extruded corners.
fn usable_exact(c: &[Point; 3]) -> bool {
    c[0] != c[1]
        && c[1] != c[2]
        && c[0] != c[2]
        && !c.iter().any(|p| match p {
            Point::H(h) => h.iter().all(|&v| v == 0.0),
            Point::Away(p, l) => p == l,
        })
}

/// The side triangles the shaders draw for `light` under `ev`, each with its
/// stencil weight, as emitted and as extruded exactly.
fn emitted_sides(d: &Decoded, light: Light, ev: &Evaluation) -> Vec<Emitted> {
    let mut sides: Vec<Emitted> = Vec::new();
    let mut silhouette: Vec<u32> = Vec::new();
    for (b, ms) in d.buckets.iter().zip(&ev.sides) {
        // The silhouette is a few percent of the records, scattered over
        // megabytes: listed first, so each record's row is asked for
        // `SIDES_AHEAD` records before it is read. Read during the scan,
        // each was a cache miss waited for in turn (the scan between two
        // of them outran the CPU's window): this function took 82 ms of
        // the dragon's 16 lights instead of 41 (one thread, local timers,
        // benches/ROUNDS.md, Forty-third round).
        silhouette.clear();
        silhouette.extend(
            ms.iter()
                .enumerate()
                .filter(|&(_, &m)| m != 0)
                .map(|(i, _)| i as u32),
        );
        let row = 4 * (2 + b.k);
        sides.reserve(2 * silhouette.len());
        for (n, &i) in silhouette.iter().enumerate() {
            if let Some(&next) = silhouette.get(n + SIDES_AHEAD) {
                // A and B: the row's first 28 bytes, which may cross a line.
                let at = b.data.as_ptr().wrapping_add(next as usize * row);
                prefetch_ptr(at);
                prefetch_ptr(at.wrapping_add(6));
            }
            // A and B as the record stores them, what the shader extrudes
            // (in a damaged file they may be no cap's corner, and have no
            // id).
            let r = &b.data[i as usize * row..][..7];
            for second in [false, true] {
                let e = Emitted {
                    a: [r[0], r[1], r[2]],
                    b: [r[4], r[5], r[6]],
                    m: ms[i as usize] as i32,
                    second,
                };
                // A light exactly on A or B extrudes it to (0,0,0,0), which is
                // no point at all: such a triangle has no area to cross.
                if usable(&e.corners(light)) || usable_exact(&e.exact(light)) {
                    sides.push(e);
                }
            }
        }
    }
    sides
}

/// How many silhouette records ahead [`emitted_sides`] prefetches a row.
const SIDES_AHEAD: usize = 16;

/// Relative growth of the hierarchy's boxes for the back caps' query:
/// twice `toInf`'s rounding (see [`back_term`]).
const BACK_GROW: f64 = 1.0 / (1u64 << 23) as f64;

/// Which back caps [`back_term`] tests.
#[derive(Debug, Clone, Copy, PartialEq)]
enum BackCaps {
    /// Every back cap (the definition; tests compare with it).
    #[cfg(test)]
    All,
    /// A point light's: only the caps the hierarchy finds along the ray from
    /// the light; a directional light's: none (both explained in
    /// [`back_term`]).
    Indexed,
}

/// The back caps' term of the winding along direction `k` (the sum of
/// their signed crossings with a ray's end at infinity, the same for every
/// sample), for the emitted volume or (`exact`) the exactly extruded one;
/// `None` when the ray's end touches a back cap's edge or corner.
///
/// The back caps are made on the fly (kept, they were about 300 bytes per
/// triangle for each light, 260 MB on the 871k-triangle dragon), each
/// version only for the pass that needs it, and only those usable in that
/// version are tested (an unusable one meets no ray, see `usable`).
///
/// With [`BackCaps::Indexed`], a point light's back cap (every corner
/// extruded from the light) holds the direction in its cone only if the ray
/// from the light along it meets the cap moved to `L + toInf(P)` for each
/// corner P. `toInf` rounds `P − L` by a relative 2^-24 or less per
/// component, which moves a corner by at most 2^-24 · (|P| + |L|) per
/// component: boxes grown by twice that ([`BACK_GROW`]) hold the moved
/// caps, so the hierarchy finds every cap whose term is not `Meet::None`
/// (a flat cone's is None, and a direction outside the closed cone gives
/// None). The exact extrusion moves no corner. A directional light extrudes
/// every corner to `−L` (`0·P − L`, zeros of either sign): no back cap is
/// usable, and the term is 0. Why: the loop over every back cap took 29 ms
/// per point light and 15 ms per directional one on the dragon, a quarter
/// of `verify`'s time per light.
fn back_term(
    index: &ShadowIndex,
    ev: &Evaluation,
    light: Light,
    k: usize,
    exact: bool,
    caps: BackCaps,
) -> Option<i32> {
    let dk = DIRECTIONS[k];
    let dh = [dk[0] as f64, dk[1] as f64, dk[2] as f64, 0.0];
    let lh = hom(light);
    let finite_light = lh.iter().all(|v| v.is_finite());
    if caps == BackCaps::Indexed && light[3] == 0.0 && finite_light {
        return Some(0);
    }
    // Back caps meet the ray only at its end at infinity, where the answer
    // does not depend on the ray's start: any finite point will do.
    let origin = [0.0, 0.0, 0.0, 1.0];
    let mut sum = 0;
    // Adds cap `i`'s term; false when it is degenerate.
    let mut term = |i: usize| {
        let c = ev.caps[index.ids[i] as usize];
        if c == 0 {
            return true;
        }
        let t = index.tris[i];
        let t = if c < 0 {
            [t[2], t[0], t[1]]
        } else {
            [t[2], t[1], t[0]]
        };
        let m = if exact {
            let corners = t.map(|p| inf_exact(p, light));
            if !usable_exact(&corners) {
                return true;
            }
            meet_points(Point::H(origin), Point::H(dh), corners)
        } else {
            let corners = t.map(|p| inf(p, light));
            if !usable(&corners) {
                return true;
            }
            meet(origin, dh, corners)
        };
        match m {
            Meet::Cross(sg) => sum += sg,
            Meet::None => {}
            _ => return false,
        }
        true
    };
    let mut ok = true;
    if caps == BackCaps::Indexed && light[3] == 1.0 && finite_light {
        let grow_abs = BACK_GROW * lh[0].abs().max(lh[1].abs()).max(lh[2].abs());
        let (l3, d3) = ([lh[0], lh[1], lh[2]], [dh[0], dh[1], dh[2]]);
        index
            .bvh
            .query_grown(l3, d3, f64::INFINITY, BACK_GROW, grow_abs, |i| {
                ok = ok && term(i as usize);
            });
    } else {
        ok = (0..index.tris.len()).all(term);
    }
    ok.then_some(sum)
}

/// Checks `samples` against the volume emitted under `ev` for `light`.
///
/// A sample whose winding differs from the truth is compared with a second
/// volume first: the same triangles with the corners at infinity extruded
/// exactly (`P − L`, [`Point::Away`]) instead of the contract's f32
/// `toInf(P)`. If that volume's winding is the truth, the mismatch is the
/// rounding of the extrusion alone: the sample lies between an emitted side
/// quad and where the quad would be without rounding. Such a sample is
/// counted in [`ShadowReport::on_faces`] (and in
/// [`ShadowReport::extrusion_rounding`]), not compared. The wedge between the
/// two is normally about 2^-24 rad wide; it is wide when a point light is
/// nearly on an edge's line, where the side plane through the light and the
/// edge is ill-conditioned (its angle error is about the rounding of `B − L`
/// over the light's distance from the line). Directional lights extrude
/// exactly (`toInf(P) = −L`), so only point lights have such samples.
pub fn check_shadow(
    d: &Decoded,
    index: &ShadowIndex,
    light: Light,
    ev: &Evaluation,
    samples: &[[f32; 3]],
) -> ShadowReport {
    let rounds = light[3] == 1.0;
    // Side triangles; the front caps are the indexed triangles.
    let sides = emitted_sides(d, light, ev);
    // Per-direction data, built on first use (by whichever thread needs it);
    // back-cap terms for the emitted and for the exactly extruded volume.
    let back_terms: [Vec<OnceLock<Option<i32>>>; 2] =
        [0, 1].map(|_| (0..DIRECTIONS.len()).map(|_| OnceLock::new()).collect());
    let candidates: Vec<OnceLock<SideCandidates>> =
        (0..DIRECTIONS.len()).map(|_| OnceLock::new()).collect();
    // Winding of the emitted volume (`exact` false) or of the exactly
    // extruded one at sample `s`, along direction `k`.
    let cast = |j: usize, k: usize, exact: bool| -> Cast {
        let p = fin(samples[j]);
        let p3 = [p[0], p[1], p[2]];
        let dk = DIRECTIONS[k];
        let dh = [dk[0] as f64, dk[1] as f64, dk[2] as f64, 0.0];
        let meet_e = |a: H, e: &Emitted| {
            if exact {
                meet_points(Point::H(a), Point::H(dh), e.exact(light))
            } else {
                meet(a, dh, e.corners(light))
            }
        };
        let Some(back) = *back_terms[exact as usize][k]
            .get_or_init(|| back_term(index, ev, light, k, exact, BackCaps::Indexed))
        else {
            return Cast::Degenerate;
        };
        let mut w = back;
        let mut ok = true;
        let mut on_face = false;
        let lists = candidates[k].get_or_init(|| SideCandidates::new(&sides, light, dk, samples));
        for &i in &lists.lists[j] {
            let e = &sides[i as usize];
            match meet_e(p, e) {
                Meet::Cross(sg) => w += sg * e.weight(),
                Meet::None => {}
                Meet::AOnTriangle => on_face = true,
                Meet::Degenerate => ok = false,
            }
        }
        index
            .bvh
            .query(p3, [dh[0], dh[1], dh[2]], f64::INFINITY, |i| {
                let c = ev.caps[index.ids[i as usize] as usize];
                if c == 0 {
                    return;
                }
                let t = index.tris[i as usize];
                let (p0, p1) = if c < 0 { (t[1], t[0]) } else { (t[0], t[1]) };
                match meet(p, dh, [fin(p0), fin(p1), fin(t[2])]) {
                    Meet::Cross(sg) => w += sg,
                    Meet::None => {}
                    Meet::AOnTriangle => on_face = true,
                    Meet::Degenerate => ok = false,
                }
            });
        if on_face {
            Cast::OnFace
        } else if ok {
            Cast::Winding(w)
        } else {
            Cast::Degenerate
        }
    };
    // First direction whose ray touches nothing degenerately; `None` when
    // the sample is on a face (or every direction is degenerate).
    let winding = |j: usize, exact: bool| -> Option<i32> {
        for k in 0..DIRECTIONS.len() {
            match cast(j, k, exact) {
                Cast::Winding(w) => return Some(w),
                Cast::OnFace => return None,
                Cast::Degenerate => {}
            }
        }
        None
    };
    // Per sample: the emitted winding (None: on a face), the truth (None:
    // ambiguous), and whether a mismatch is the extrusion's rounding alone.
    let outcomes: Vec<(Option<i32>, Option<i32>, bool)> = samples
        .par_iter()
        .enumerate()
        .map(|(j, &s)| {
            let truth = occluders(index, light, s).map(|n| n as i32);
            let w = truth.and(winding(j, false));
            let rounding = rounds
                && matches!((w, truth), (Some(w), Some(t)) if w != t)
                && winding(j, true) == truth;
            (w, truth, rounding)
        })
        .collect();
    let mut rep = ShadowReport::default();
    for (&s, &(winding, truth, rounding)) in samples.iter().zip(&outcomes) {
        match (winding, truth) {
            (Some(_), Some(_)) if rounding => {
                rep.on_faces += 1;
                rep.extrusion_rounding += 1;
            }
            (Some(w), Some(truth)) => {
                rep.samples += 1;
                if w != truth {
                    rep.mismatches += 1;
                    if rep.first_mismatch.is_none() {
                        rep.first_mismatch = Some(format!(
                            "sample ({}, {}, {}): volume winding {w}, but {truth} triangles lie between it and the light",
                            s[0], s[1], s[2]
                        ));
                    }
                }
            }
            _ => rep.on_faces += 1,
        }
    }
    rep
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::evaluate::Strategy;
    use crate::verify::{decode, evaluate, orientation_errors};

    /// The fan's wedges hold every sample whose ray meets a triangle in any
    /// way (crossing, touching, starting on it), and list no sample twice:
    /// random triangles with zero to two corners at infinity around point
    /// lights (whose corners often span a half-turn or more around the
    /// light's line along the ray, and whose wedges often wrap past the
    /// turn's start), side triangles as emitted and as extruded exactly
    /// (some extruding nearly along the rays, where the rounding of `toInf`
    /// turns them most), and side triangles of directional lights; with
    /// random samples, samples next to the light's line, and samples on
    /// the triangles' edges.
    #[test]
    fn fan_side_wedges_hold_every_ray_that_meets() {
        let mut rng = crate::verify::Rng::new(11);
        // A uniform value in (−scale, scale), as f32.
        let sym =
            |rng: &mut crate::verify::Rng, scale: f64| ((rng.unit() - 0.5) * 2.0 * scale) as f32;
        let (mut met, mut wedged, mut wrapped, mut listed, mut pairs, mut count) =
            (0, 0, 0, 0, 0, 0);
        let (trials, per_trial) = (240, 24);
        for trial in 0..trials {
            let dir = DIRECTIONS[trial % DIRECTIONS.len()];
            let dv = dir.map(|x| x as f64);
            let dh = [dv[0], dv[1], dv[2], 0.0];
            let point = trial % 3 != 2;
            let l = [0; 3].map(|_| sym(&mut rng, 1.0));
            let light: Light = [l[0], l[1], l[2], if point { 1.0 } else { 0.0 }];
            // A point about `s` along the light's line, `off` from it.
            let near = |rng: &mut crate::verify::Rng, s: f32, off: f64| {
                [0, 1, 2].map(|k| l[k] + s * dir[k] + sym(rng, off))
            };
            let (u, v) = plane_basis(dir);
            // `l + a·u + b·v + s·dir`, as f32.
            let at = |a: f64, b: f64, s: f64| {
                [0, 1, 2].map(|k| (l[k] as f64 + a * u[k] + b * v[k] + s * dv[k]) as f32)
            };
            // Side quads (A, B, m), each with its two triangles: as emitted
            // and, for a point light, as extruded exactly.
            let mut quads = Vec::new();
            for t in 0..per_trial {
                let (a, b) = if point && t % 8 == 4 {
                    // A's key about 0 (a little over, or just under 4), B's
                    // under 2: a wedge starting at the turn's start.
                    let a = at(
                        sym(&mut rng, 1e-3) as f64,
                        0.1 + rng.unit(),
                        sym(&mut rng, 2.0) as f64,
                    );
                    let b = at(
                        -0.1 - rng.unit(),
                        sym(&mut rng, 1.0) as f64,
                        sym(&mut rng, 2.0) as f64,
                    );
                    (a, b)
                } else if point && t % 8 == 6 {
                    // L nearly on the segment AB: the keys half a turn
                    // apart, up to B's rounding to f32.
                    let s = sym(&mut rng, 2.0);
                    let a = near(&mut rng, s, 1.0);
                    let c = 0.2 + 2.0 * rng.unit();
                    let b =
                        [0, 1, 2].map(|k| (l[k] as f64 - c * (a[k] as f64 - l[k] as f64)) as f32);
                    (a, b)
                } else {
                    // Some extrude A nearly along the rays: A − L about
                    // along `dir`.
                    let a = if point && t % 5 == 1 {
                        let s = 1.0 + rng.unit() as f32;
                        near(&mut rng, s, 1e-3)
                    } else {
                        let s = sym(&mut rng, 2.0);
                        near(&mut rng, s, 1.0)
                    };
                    let s = sym(&mut rng, 2.0);
                    (a, near(&mut rng, s, 1.0))
                };
                let m = if rng.unit() < 0.5 { 1 } else { -2 };
                let tris = [false, true].map(|second| {
                    let e = Emitted { a, b, m, second };
                    (e.corners(light), point.then(|| e.exact(light)))
                });
                quads.push((a, b, tris));
            }
            let mut samples: Vec<[f32; 3]> = (0..120)
                .map(|_| [0; 3].map(|_| sym(&mut rng, 3.0)))
                .map(|q| [0, 1, 2].map(|k| l[k] + q[k]))
                .collect();
            for _ in 0..12 {
                let (s, off) = (sym(&mut rng, 3.0), 10f64.powf(-1.0 - 7.0 * rng.unit()));
                samples.push(near(&mut rng, s, off));
            }
            // On the triangles' edges, from a finite corner to the next
            // corner (a point or a direction; for a point light also the
            // exact extrusion), then back along the ray.
            for (t, exact) in quads.iter().flat_map(|q| &q.2) {
                for (i, j) in [(0, 1), (1, 2), (2, 0)] {
                    if t[i][3] != 1.0 {
                        continue;
                    }
                    let mut to = vec![([0, 1, 2].map(|k| t[j][k] - t[j][3] * t[i][k]), 1.0)];
                    if let Some([.., Point::Away(p, l)]) = exact.map(|x| [x[j]]) {
                        // Far along it too, where the exact edge and the
                        // emitted one part most.
                        let to_exact = [0, 1, 2].map(|k| p[k] - l[k]);
                        to.push((to_exact, 1.0));
                        to.push((to_exact, 10f64.powf(3.0 + 6.0 * rng.unit())));
                    }
                    for (to, far) in to {
                        let (f, back) = (far * rng.unit(), rng.unit() * 3.0);
                        samples
                            .push([0, 1, 2].map(|k| (t[i][k] + f * to[k] - back * dv[k]) as f32));
                    }
                }
            }
            let fan = Fan::new(light, dir, &samples).expect("a fan");
            count += quads.len();
            for (a, b, tris) in &quads {
                let mut list = Vec::new();
                match fan.side_wedge(*a, *b) {
                    Some(w) => {
                        wedged += 1;
                        wrapped += point as usize * (w.1 >= 4.0) as usize;
                        fan.for_each_in(w, |j| list.push(j));
                    }
                    None => list.extend(0..samples.len() as u32),
                }
                let mut once = list.clone();
                once.sort_unstable();
                once.dedup();
                assert_eq!(once.len(), list.len(), "a sample listed twice");
                listed += list.len();
                pairs += samples.len();
                for (j, s) in samples.iter().enumerate() {
                    let p = fin(*s);
                    for (t, exact) in tris {
                        let hit = meet(p, dh, *t) != Meet::None
                            || exact.is_some_and(|x| {
                                usable_exact(&x)
                                    && meet_points(Point::H(p), Point::H(dh), x) != Meet::None
                            });
                        if hit {
                            met += 1;
                            assert!(
                                list.contains(&(j as u32)),
                                "trial {trial}, light {light:?}, dir {dir:?}, triangle {t:?}, sample {s:?}: met but not listed"
                            );
                        }
                    }
                }
            }
        }
        // Not vacuous: rays meet triangles, most triangles have a wedge,
        // some wrap, and the wedges leave most pairs out.
        assert!(met > 2000, "{met}");
        assert!(wrapped > 100, "{wrapped}");
        assert!(wedged * 10 > 8 * count, "{wedged} of {count}");
        assert!(listed * 2 < pairs, "{listed} of {pairs}");
    }

    /// `KeyBins::count` answers what `partition_point` answers, on keys
    /// with ties and clusters, at the keys, between and beyond them.
    #[test]
    fn key_bins_count_what_a_binary_search_counts() {
        let mut rng = crate::verify::Rng::new(5);
        let mut checked = 0;
        for trial in 0..200 {
            let n = trial % 40;
            let mut keys: Vec<(f64, u32)> = (0..n)
                .map(|j| {
                    let x = match rng.below(4) {
                        0 => rng.below(3) as f64,
                        1 => 1.0 + 1e-12 * rng.unit(),
                        2 => -1e6 * rng.unit(),
                        _ => 4.0 * rng.unit(),
                    };
                    (x, j as u32)
                })
                .collect();
            keys.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
            let bins = KeyBins::new(&keys);
            let mut queries: Vec<f64> = keys.iter().map(|k| k.0).collect();
            queries.extend(keys.iter().map(|k| k.0 + 1e-13));
            queries.extend(keys.iter().map(|k| k.0 - 1e-13));
            queries.extend([-1e9, 1e9, -0.0, 0.5, f64::NAN, f64::INFINITY]);
            for x in queries {
                for inclusive in [false, true] {
                    let want = keys.partition_point(|e| e.0 < x || inclusive && e.0 == x);
                    assert_eq!(
                        bins.count(&keys, x, inclusive),
                        want,
                        "{n} keys, x {x}, inclusive {inclusive}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(checked > 10_000, "{checked}");
    }

    /// `Emitted::corners`, written out per case, picks the quad's corners
    /// in the order `side_corner` gives the draws.
    #[test]
    fn emitted_corners_follow_the_draw_order() {
        for light in [[0.3, -0.2, 0.9, 1.0], [0.3, -0.2, 0.9, 0.0]] {
            for m in [1, 2, -1, -3] {
                for second in [false, true] {
                    let e = Emitted {
                        a: [1.0, 2.0, 3.0],
                        b: [-0.5, 0.25, 4.0],
                        m,
                        second,
                    };
                    let quad = [fin(e.a), fin(e.b), inf(e.a, light), inf(e.b, light)];
                    let bits = |t: [H; 3]| t.map(|c| c.map(f64::to_bits));
                    assert_eq!(
                        bits(e.corners(light)),
                        bits(e.ids().map(|i| quad[i])),
                        "m {m}, second {second}"
                    );
                }
            }
        }
    }

    /// The candidate lists against every side triangle: a side that a
    /// sample's ray meets in any way (crossing, touching, starting on it),
    /// as emitted or as extruded exactly, is on the sample's list. On the
    /// folded pair of the test below (a point light 3.5e-7 from an edge's
    /// line, whose rounded extrusion turns a side triangle by 1.19°) and on
    /// a bumpy grid, with samples from `choose_samples` and samples placed
    /// on the lines of the exact and the rounded side edges, where rays
    /// touch and the two versions differ.
    #[test]
    fn side_candidates_hold_every_side_a_ray_meets() {
        let folded = (
            vec![
                [-1.0, -8.727_353_7e-7, 0.5],
                [2.173_373_6e-7, 1.907_575_3e-7, -0.5],
                [26.664_402, -0.5, 1.0],
                [243.194_99, 8.764_287e-7, 1.0],
                [718.601_9, -4.526_546_6e-7, 740.013_24],
            ],
            vec![[1, 0, 2], [0, 4, 1]],
            vec![[-0.5, 0.0, 0.0, 1.0], [0.3, 1.0, -0.2, 0.0]],
        );
        let bumpy = crate::hardcases::grid(12, |x, y| [x, y, 0.3 * (7.0 * x).sin() * y]);
        let bumpy = (
            bumpy.0,
            bumpy.1,
            vec![
                [0.5, 0.5, 2.0, 1.0],
                [0.31, 0.27, 0.05, 1.0],
                [0.2, -0.3, 1.0, 0.0],
            ],
        );
        let (mut met, mut listed, mut pairs) = (0usize, 0usize, 0usize);
        for (v, f, lights) in [folded, bumpy] {
            let d = built(&v, &f);
            for light in lights {
                let ev = evaluate(&d, light, Strategy::Reference);
                let sides = emitted_sides(&d, light, &ev);
                assert!(!sides.is_empty());
                let mut samples = choose_samples(&d, 200, 7);
                // Points on the lines of the side triangles' edges, rounded
                // to f32: on or next to the emitted and the exact edges,
                // which differ where an extrusion rounds.
                for e in &sides {
                    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
                        let (p, q) = (e.exact(light)[i], e.exact(light)[j]);
                        let (Point::H(p), q) = (p, q) else { continue };
                        if p[3] != 1.0 {
                            continue;
                        }
                        let dirs = match q {
                            Point::H(q) if q[3] == 1.0 => {
                                vec![[q[0] - p[0], q[1] - p[1], q[2] - p[2]]]
                            }
                            Point::H(q) => vec![[q[0], q[1], q[2]]],
                            Point::Away(a, l) => vec![[a[0] - l[0], a[1] - l[1], a[2] - l[2]], {
                                let c = e.corners(light)[j];
                                [c[0], c[1], c[2]]
                            }],
                        };
                        for dv in dirs {
                            for t in [0.25, 0.5, 3.0, 50.0, 1000.0] {
                                samples.push([0, 1, 2].map(|k| (p[k] + t * dv[k]) as f32));
                            }
                        }
                    }
                }
                for (k, &dir) in DIRECTIONS.iter().enumerate().take(2) {
                    let lists = SideCandidates::new(&sides, light, dir, &samples);
                    let dh = [dir[0] as f64, dir[1] as f64, dir[2] as f64, 0.0];
                    for (j, &s) in samples.iter().enumerate() {
                        let p = fin(s);
                        listed += lists.lists[j].len();
                        for (i, e) in sides.iter().enumerate() {
                            pairs += 1;
                            let rounded = meet(p, dh, e.corners(light)) != Meet::None;
                            let exact = meet_points(Point::H(p), Point::H(dh), e.exact(light))
                                != Meet::None;
                            if rounded || exact {
                                met += 1;
                                assert!(
                                    lists.lists[j].contains(&(i as u32)),
                                    "light {light:?}, direction {k}, sample {s:?}: side {i} met but not listed"
                                );
                            }
                        }
                    }
                }
            }
        }
        // Not vacuous: rays meet sides, and the lists leave most pairs out.
        assert!(met > 1000, "{met}");
        assert!(listed * 4 < pairs, "{listed} of {pairs}");
    }

    /// The shrunk case of `random_soups_verify` (tests/hard_cases.rs): two
    /// triangles folded over the edge A = v0, B = v1, and a point light
    /// 3.5e-7 from that edge's line, between A and B. Both orientations are
    /// exact, but the side plane through L, A and B is ill-conditioned: the
    /// f32 extrusion `toInf(B) = B − L` rounds x by 2.1e-8, which turns the
    /// emitted side triangle (B, A∞, B∞) 1.19° about B. The sample lies in
    /// that wedge (6.6 units from the exact plane, 5.1 from the emitted one):
    /// the emitted volume gives winding 0 there, exactly 2 triangles lie
    /// between it and the light.
    /// Builds the mesh `v`, `f` with the default options and decodes it.
    fn built(v: &[[f32; 3]], f: &[[usize; 3]]) -> Decoded {
        let tmp = tempfile::tempdir().unwrap();
        let (input, output) = (tmp.path().join("m.obj"), tmp.path().join("m.svpk"));
        std::fs::write(&input, crate::hardcases::obj(v, f)).unwrap();
        crate::build::build_file(&input, &output, &Default::default()).unwrap();
        decode(&crate::format::read_file(&output).unwrap(), 0)
    }

    /// The back caps' terms the hierarchy finds equal those of every back
    /// cap. Caught: the query's boxes not grown for `toInf`'s rounding (the
    /// first case), and a directional light's term not 0.
    #[test]
    fn indexed_back_terms_are_every_back_cap_s() {
        let term = |d: &Decoded, index: &ShadowIndex, light: Light| {
            let ev = evaluate(d, light, Strategy::Reference);
            let all: Vec<_> = (0..DIRECTIONS.len())
                .flat_map(|k| {
                    [false, true].map(|x| back_term(index, &ev, light, k, x, BackCaps::All))
                })
                .collect();
            let indexed: Vec<_> = (0..DIRECTIONS.len())
                .flat_map(|k| {
                    [false, true].map(|x| back_term(index, &ev, light, k, x, BackCaps::Indexed))
                })
                .collect();
            assert_eq!(indexed, all, "{light:?}");
            all
        };
        // The light at −1024 · D0 and a corner p0 so close to the origin
        // that `toInf(p0)` rounds to exactly 1024 · D0: the first ray ends
        // on that back cap's corner (degenerate). The ray from the light
        // passes the triangle's box 3.4e-6 away (far beyond the boxes' own
        // padding): only boxes grown for the rounding find the cap.
        let d0 = DIRECTIONS[0];
        let light = [-1024.0 * d0[0], -1024.0 * d0[1], -1024.0 * d0[2], 1.0];
        let e = 1e-5;
        let tri = [[e, e, e], [1.0, e, e], [e, 1.0, e]];
        let d = built(&tri, &[[0, 1, 2]]);
        let index = ShadowIndex::new(&d);
        let p0 = d.positions.iter().find(|p| p[0] == e && p[1] == e).unwrap();
        assert_eq!(
            crate::multiplicity::to_infinity(*p0, light),
            [-light[0], -light[1], -light[2], 0.0]
        );
        let terms = term(&d, &index, light);
        assert_eq!(terms[0], None, "the first ray ends on the cap's corner");
        // A closed box under point lights around and inside it, and
        // directional ones.
        let (v, f) = crate::hardcases::closed_box(3, 1.0, [0.0; 3]);
        let d = built(&v, &f);
        let index = ShadowIndex::new(&d);
        let mut rng = crate::verify::Rng::new(7);
        let mut crossed = 0;
        for i in 0..40 {
            let mut l: Light = [0, 1, 2, 3].map(|_| (rng.unit() * 6.0 - 3.0) as f32);
            l[3] = (i % 4 != 0) as u8 as f32;
            crossed += term(&d, &index, l)
                .iter()
                .filter(|t| t.is_some_and(|t| t != 0))
                .count();
        }
        assert!(crossed > 0, "some ray ends inside a back cap");
    }

    #[test]
    fn back_caps_count_where_the_rays_end_inside_the_shadow() {
        // A closed box and point lights placed so that the rays of the
        // first directions, cast from the samples, end at infinity inside
        // the box's shadow: there the back caps give the winding its
        // count (elsewhere their term is 0, and a wrong one goes unseen).
        let (v, f) = crate::hardcases::closed_box(3, 1.0, [0.0; 3]);
        let d = built(&v, &f);
        let index = ShadowIndex::new(&d);
        let (lo, hi) = crate::build::bounds(&d.positions);
        let c = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        let mut compared = 0;
        for dir in &DIRECTIONS[..2] {
            for t in [3.0, 10.0] {
                let light: Light = [
                    c[0] - t * dir[0],
                    c[1] - t * dir[1] + 0.013,
                    c[2] - t * dir[2] + 0.026,
                    1.0,
                ];
                let ev = evaluate(&d, light, Strategy::Reference);
                let samples = choose_samples(&d, 300, 3);
                let r = check_shadow(&d, &index, light, &ev, &samples);
                // Nothing excused as the extrusion's rounding either: a
                // wrong back-cap term would pass as that (the exactly
                // extruded volume, counted apart, would still be right).
                assert_eq!(
                    (r.mismatches, r.extrusion_rounding),
                    (0, 0),
                    "{light:?}: {r:?}"
                );
                compared += r.samples;
            }
        }
        assert!(compared > 1000, "{compared}");
    }

    #[test]
    fn sample_in_the_rounding_wedge_of_an_extrusion_is_not_compared() {
        let v = [
            [-1.0, -8.727_353_7e-7, 0.5],
            [2.173_373_6e-7, 1.907_575_3e-7, -0.5],
            [26.664_402, -0.5, 1.0],
            [243.194_99, 8.764_287e-7, 1.0],
            [718.601_9, -4.526_546_6e-7, 740.013_24],
        ];
        let f = [[1, 0, 2], [0, 4, 1]];
        let light: Light = [-0.5, 0.0, 0.0, 1.0];
        let sample = [49.957_226, -550.836, 134.612_49];
        let d = built(&v, &f);
        let index = ShadowIndex::new(&d);
        let ev = evaluate(&d, light, Strategy::Reference);
        assert_eq!(orientation_errors(&d, light, &ev), 0);
        assert_eq!(occluders(&index, light, sample), Some(2));
        let r = check_shadow(&d, &index, light, &ev, &[sample]);
        assert_eq!((r.samples, r.on_faces, r.mismatches), (0, 1, 0), "{r:?}");
        assert_eq!(r.extrusion_rounding, 1);
        // The rounded side quad: B∞ is off the plane through A, B and the
        // light, and the sample is on opposite sides of the two.
        let (a, b) = (fin(v[0]), fin(v[1]));
        let (l, p) = (hom(light), fin(sample));
        let b_inf = hom(to_infinity(v[1], light));
        assert_ne!(b_inf[0], 0.5 + v[1][0] as f64);
        let exact_side = crate::exact::det4_sign([a, b, l, p]);
        assert_ne!(exact_side, 0);
        // (A, B, B − L) spans the same plane as (A, B, L), with w reversed.
        let exact_b_inf = Point::Away(b, l);
        assert_eq!(
            crate::exact::det4_sign_points([Point::H(a), Point::H(b), exact_b_inf, Point::H(p)]),
            -exact_side
        );
        assert_eq!(crate::exact::det4_sign([a, b, b_inf, p]), exact_side);

        // Not a licence for wrong volumes: the inverted volume (every sign
        // negated) is wrong there with exact extrusions too, and is reported.
        let mut inverted = ev.clone();
        inverted.caps.iter_mut().for_each(|c| *c = -*c);
        inverted.sides.iter_mut().flatten().for_each(|m| *m = -*m);
        let r = check_shadow(&d, &index, light, &inverted, &[sample]);
        assert_eq!((r.samples, r.on_faces, r.mismatches), (1, 0, 1), "{r:?}");
    }
}
