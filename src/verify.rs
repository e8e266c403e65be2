//! `svpack verify`: replay a file on the CPU and prove its volumes are
//! well-formed.
//!
//! 1. Structure: the (triangle, edge) pairs of the caps section and the (edge
//!    instance, opposite slot) pairs of the sides buckets are in bijection,
//!    with `A < B` and the documented `.w` values.
//! 2. Closedness, per light: the triangles the reference shaders would emit
//!    (|m| copies of each side quad with the winding its sign gives, front
//!    caps, back caps at infinity), as homogeneous world-space vertices, form
//!    a closed oriented surface: every undirected edge is used equally often
//!    in both directions. Vertex identity is the exact f32 4-tuple, so this is
//!    exact and combinatorial.
//!
//! All positions are first replaced by ids into one sorted table, so the
//! checks work on integers.

use crate::evaluate::{Strategy, cap_signs_with, side_multiplicities_with};
use crate::evaluate_indexed::LIGHT_GROUP;
use crate::evaluate_ordered::{GroupScratch, OrderedEvaluation};
use crate::evaluate_simd::{Corner, LANES};
use crate::format::{Floats, SvpkFile};
use crate::multiplicity::{Light, cap_corner, side_corner, to_infinity};
use crate::position_index::{PositionTable, TriangleIndex};
use crate::weld::order_key;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering::Relaxed};

/// One mesh of a file, decoded for checking. Everything is in the mesh's
/// record space (format-spec §4.5), where the shaders compute.
#[derive(Debug, Clone)]
pub struct Decoded {
    /// Record space → world space.
    pub space: crate::quantize::RecordSpace,
    /// Largest `.w` integer the encoding stores (`B.w` saturates there).
    pub w_limit: f32,
    /// Distinct caps positions (by bits), sorted by the order keys of their
    /// coordinates, x first: the lexicographic order of the values, with
    /// `-0.0` just before `+0.0` and NaNs at the ends (by sign bit). Ids
    /// index this.
    pub positions: Vec<[f32; 3]>,
    /// Caps records as floats (12 per triangle), as the GPU reads them.
    pub caps_data: Floats,
    /// Caps corner ids.
    pub caps: Vec<[u32; 3]>,
    /// Per caps triangle: the first caps triangle with the same three
    /// corner ids (itself, or a duplicate before it), or [`UNKNOWN`] when
    /// its corners are not three distinct ids. The triangle each opposite
    /// slot names ([`DecodedBucket::slot_tri`]) is such a first one.
    pub cap_first: Vec<u32>,
    /// Side buckets.
    pub buckets: Vec<DecodedBucket>,
    /// The caps as sorted corner ids into `positions`, numbered in the
    /// order the side records first name them, and the slots as offsets
    /// into their signs: what [`evaluate`] runs per light for the
    /// reference strategy ([`crate::evaluate_ordered`]). `None` when
    /// `positions` is not strictly increasing (a NaN or a ±0.0 pair, see
    /// [`crate::evaluate_indexed`]); then [`evaluate`] reads the records.
    pub ordered: Option<OrderedEvaluation>,
}

/// One sides bucket, decoded.
#[derive(Debug, Clone)]
pub struct DecodedBucket {
    /// Opposite slots per record.
    pub k: usize,
    /// Records as floats, `(2 + k) · 4` per record.
    pub data: Floats,
    /// A, B and opposite ids per record (`2 + k` ids each); `u32::MAX` for a
    /// position that is not a caps corner.
    pub ids: Vec<u32>,
    /// Per opposite slot (`k` per record): the caps triangle with the same
    /// three corners, or [`UNKNOWN`] when there is none.
    pub slot_tri: Vec<u32>,
    /// Per opposite slot: +1 when `(A, B, O)` is an even permutation of that
    /// triangle's stored corners, −1 when odd. Then the slot's contribution
    /// `tri_sign(A, B, O)` is exactly `parity · cap sign`: both evaluate the
    /// same expression on the same sorted corners (the reference edge).
    pub slot_parity: Vec<i8>,
}

impl DecodedBucket {
    /// Number of records.
    pub fn records(&self) -> usize {
        self.ids.len() / (2 + self.k)
    }
}

/// Sentinel id of a sides position that appears in no caps triangle.
pub const UNKNOWN: u32 = u32::MAX;

/// Records per parallel block of [`check_structure`]; fixed, so its report
/// does not depend on the number of threads.
const STRUCTURE_BLOCK: usize = 1 << 14;

/// Ids in increasing order and the parity (+1 even, −1 odd) of the sorting
/// permutation: the contract's network on ids
/// ([`crate::evaluate_indexed::sort_ids`]).
fn sort_ids(v: [u32; 3]) -> ([u32; 3], i8) {
    let (v, odd) = crate::evaluate_indexed::sort_ids(v);
    (v, if odd { -1 } else { 1 })
}

fn bits(p: [f32; 3]) -> [u32; 3] {
    p.map(f32::to_bits)
}

/// Decodes mesh `index` of `file`.
///
/// Positions are identified by their bits. The caps corners are numbered
/// in a hash table (module `position_index`) and only the distinct
/// positions are sorted, by the order keys of their coordinates
/// ([`Decoded::positions`]); every sides position is then looked up in the
/// same table, and every opposite slot's corner set in the caps triangles
/// listed by smallest corner. Each step is in fixed blocks or sequential,
/// so the result does not depend on the number of threads. The steps run
/// as one job on rayon's pool (see `crate::pool`).
pub fn decode(file: &SvpkFile, index: usize) -> Decoded {
    crate::pool::one_job(|| decode_steps(file, index))
}

/// The steps of [`decode`].
fn decode_steps(file: &SvpkFile, index: usize) -> Decoded {
    let m = &file.header.meshes[index];
    let caps_data = file.floats(m.caps.offset, m.caps.length);
    let key = |d: &[f32], i: usize| bits([d[4 * i], d[4 * i + 1], d[4 * i + 2]]);
    // The caps, first in first-occurrence numbers, renumbered in place.
    // The floats once as a slice: through `Floats` (an enum), every key
    // paid for the dereference.
    let caps_flat: &[f32] = &caps_data;
    let mut caps = vec![[0u32; 3]; caps_flat.len() / 12];
    let (mut table, distinct) =
        PositionTable::number(|i| key(caps_flat, i), bytemuck::cast_slice_mut(&mut caps));
    // Distinct bits have distinct order keys: the order is total. Sorted as
    // words of the three keys above the position's number, by the weld's
    // radix sort: a comparison sort of the numbers by their keys took 45–48
    // of the dragon's 340 ms (local timers, benches/ROUNDS.md, Forty-second
    // round).
    let mut words: Vec<u128> = distinct
        .par_iter()
        .enumerate()
        .map(|(i, b)| {
            let k = b.map(|b| order_key(f32::from_bits(b)) as u128);
            k[0] << 96 | k[1] << 64 | k[2] << 32 | i as u128
        })
        .collect();
    crate::weld::sort_position_words(&mut words);
    let mut rank = vec![0u32; distinct.len()];
    let positions: Vec<[f32; 3]> = words
        .iter()
        .enumerate()
        .map(|(r, &w)| {
            let i = w as u32 as usize;
            rank[i] = r as u32;
            distinct[i].map(f32::from_bits)
        })
        .collect();
    drop((words, distinct));
    table.renumber(&rank);
    caps.par_iter_mut()
        .for_each(|c| *c = c.map(|i| rank[i as usize]));
    drop(rank);
    // Each triangle once, by its sorted corner ids, with the parity of the
    // sort (duplicates of a corner set: any of them gives the same sign).
    let by_corners = TriangleIndex::new(&caps, positions.len());
    // (The index's `NONE` is `UNKNOWN`.)
    const { assert!(UNKNOWN == crate::position_index::NONE) };
    let cap_first = by_corners.first_copies(caps.len());
    let buckets: Vec<DecodedBucket> = m
        .buckets
        .iter()
        .map(|b| {
            let k = b.k as usize;
            let data = file.floats(b.offset, b.length);
            let flat: &[f32] = &data;
            let ids = table.ids(flat.len() / 4, |i| key(flat, i));
            // Per slot, written in place by blocks of records (an unzip of
            // a flattened iterator collected each thread's part in lists
            // first and copied them after).
            let records = ids.len() / (2 + k);
            let mut slot_tri = vec![0u32; records * k];
            let mut slot_parity = vec![0i8; records * k];
            if k > 0 {
                slot_tri
                    .par_chunks_mut(STRUCTURE_BLOCK * k)
                    .zip(slot_parity.par_chunks_mut(STRUCTURE_BLOCK * k))
                    .zip(ids.par_chunks(STRUCTURE_BLOCK * (2 + k)))
                    .for_each(|((tri, parity), ids)| {
                        let slots = ids.chunks_exact(2 + k).flat_map(|r| {
                            r[2..].iter().map(|&o| {
                                let (key, p) = sort_ids([r[0], r[1], o]);
                                match by_corners.get(key) {
                                    Some((t, q)) => (t, p * q),
                                    None => (UNKNOWN, 0),
                                }
                            })
                        });
                        for ((t, q), s) in tri.iter_mut().zip(parity.iter_mut()).zip(slots) {
                            (*t, *q) = s;
                        }
                    });
            }
            DecodedBucket {
                k,
                data,
                ids,
                slot_tri,
                slot_parity,
            }
        })
        .collect();
    let slots: Vec<_> = buckets
        .iter()
        .map(|b| (b.k, &b.slot_tri[..], &b.slot_parity[..]))
        .collect();
    let ordered = OrderedEvaluation::new(&positions, &caps, &slots);
    Decoded {
        ordered,
        space: crate::quantize::RecordSpace {
            offset: m.position_offset,
            scale: m.position_scale,
        },
        w_limit: file.encoding().w_limit(),
        positions,
        caps_data,
        caps,
        cap_first,
        buckets,
    }
}

/// Sorts `v`, in one move of each item when it is a few ascending runs:
/// the longest run is moved to the front, the rest is copied out and
/// sorted, and from its largest item down each is put in its place, the
/// run's items above it moved up past it by one `copy_within`.
///
/// Why: check 1 sorts the side records by edge. Each bucket's records come
/// in edge order from the build, so its list of them is a few ascending
/// runs, one per bucket, and a file with open or non-manifold edges has
/// several buckets. Sorted whole, the 5M scene's 7.5M records (five runs)
/// took 216 ms with one thread, this way 45.5–49.7 ms; the dragon's 1.3M
/// (one run) 1.0 and 1.5 ms (local timers, benches/ROUNDS.md, Forty-fourth
/// round).
fn sort_few_runs<T: Ord + Copy + Send>(v: &mut [T]) {
    // The longest run, `v[run.0..run.1]`.
    let (mut run, mut start) = ((0, 0), 0);
    for i in 1..=v.len() {
        if i == v.len() || v[i] < v[i - 1] {
            if i - start > run.1 - run.0 {
                run = (start, i);
            }
            start = i;
        }
    }
    if run.1 - run.0 == v.len() {
        return;
    }
    let mut rest = [&v[..run.0], &v[run.1..]].concat();
    rest.par_sort_unstable();
    v.copy_within(run.0..run.1, 0);
    // The run's items not yet moved to their places: `v[..end]`.
    let mut end = run.1 - run.0;
    for (j, &x) in rest.iter().enumerate().rev() {
        // `x` goes after the run's items not above it and the `j` items
        // of `rest` below it; the run's items above it, after it.
        // Found by galloping down from `end`, where the last search
        // ended: a binary search over the whole run read lines anywhere in
        // it (the 5M scene's 120 MB), and took 136–142 ms.
        let (mut hi, mut step) = (end, 1);
        let lo = loop {
            if hi < step {
                break 0;
            }
            if v[hi - step] <= x {
                break hi - step + 1;
            }
            hi -= step;
            step *= 2;
        };
        let at = lo + v[lo..hi].partition_point(|y| *y <= x);
        v.copy_within(at..end, at + j + 1);
        v[at + j] = x;
        end = at;
    }
}

/// Result of [`check_structure`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StructureReport {
    /// (triangle, edge) pairs and (record, slot) pairs left unmatched.
    pub bijection_errors: u64,
    /// Records with A not lexicographically below B, or wrong `.w` values.
    pub record_errors: u64,
    /// First problem in words, if any.
    pub first_problem: Option<String>,
}

impl StructureReport {
    /// True when nothing is wrong.
    pub fn ok(&self) -> bool {
        self.bijection_errors == 0 && self.record_errors == 0
    }
}

/// Check 1: bijection between caps (triangle, edge) pairs and sides
/// (record, slot) pairs, plus per-record invariants and finite caps
/// positions (each non-finite one is a record error).
pub fn check_structure(d: &Decoded) -> StructureReport {
    let mut rep = StructureReport::default();
    let note = |rep: &mut StructureReport, msg: String| {
        if rep.first_problem.is_none() {
            rep.first_problem = Some(msg);
        }
    };
    // Positions the shaders could not compute with (the geometric checks
    // skip such a mesh, see `verify_decoded`).
    for p in d
        .positions
        .iter()
        .filter(|p| !p.iter().all(|v| v.is_finite()))
    {
        rep.record_errors += 1;
        note(&mut rep, format!("caps position {p:?} is not finite"));
    }
    // Per record, in parallel blocks: the order and .w checks (problems
    // kept per block, so the first one is the first in file order), its
    // edge key with its number and B.w for the per-edge totals below, and
    // its (a, b, o) triples for the bijection after them.
    let records: usize = d.buckets.iter().map(|b| b.records()).sum();
    // (a << 32 | b, record number, B.w bits): sorted, the records of one
    // edge are adjacent and in file order. (16 bytes each: with the three
    // in one u128 they took 32, 42 MB of fresh memory on the dragon.)
    let mut edges = vec![(0u64, 0u32, 0u32); records];
    let mut edge_rest = &mut edges[..];
    // The bijection's sides (see below): regular slots counted per caps
    // corner set and edge, the others listed.
    //
    // The counts are kept by the corner set's evaluation number where the
    // decode made one ([`OrderedEvaluation::rank`]): in the order the
    // records first name the caps, so each record's counts lie near the
    // last record's. By triangle number they were anywhere in the dragon's
    // 10 MB of counts, and the records' pass took 50.4–55.9 ms instead of
    // 44.7–49.1 (one thread, local timers, benches/ROUNDS.md, Forty-third
    // round).
    let ranked = d.ordered.as_ref().map(|o| (o.rank(), o.order()));
    let slot_of = |t: u32| ranked.map_or(t, |(rank, _)| rank[t as usize]) as usize;
    let slot_counts: Vec<AtomicU32> = (0..3 * d.caps.len()).map(|_| AtomicU32::new(0)).collect();
    let mut odd_sides: Vec<[u32; 3]> = Vec::new();
    let mut first_record = 0;
    let mut found: Vec<(u64, Option<String>, Vec<[u32; 3]>)> = Vec::new();
    for b in &d.buckets {
        let (w, k, n) = (2 + b.k, b.k, b.records());
        let (bucket_edges, rest) = edge_rest.split_at_mut(n);
        edge_rest = rest;
        found.par_extend(
            bucket_edges
                .par_chunks_mut(STRUCTURE_BLOCK)
                .enumerate()
                .map(|(blk, out_edges)| {
                    let mut errors = 0u64;
                    let mut first = None;
                    let mut odd = Vec::new();
                    for (j, out_edge) in out_edges.iter_mut().enumerate() {
                        let r = blk * STRUCTURE_BLOCK + j;
                        let ids = &b.ids[w * r..w * (r + 1)];
                        let f = &b.data[4 * w * r..4 * w * (r + 1)];
                        let (a, bb) = (ids[0], ids[1]);
                        let bad_order = a == UNKNOWN || bb == UNKNOWN || a >= bb;
                        let bad_w = f[3] != k as f32 || (0..k).any(|s| f[8 + 4 * s + 3] != 1.0);
                        if bad_order || bad_w {
                            errors += 1;
                            first.get_or_insert_with(|| {
                                format!(
                                    "bucket k={k} record {r}: {}",
                                    if bad_order {
                                        "A is not below B (or not a caps corner)"
                                    } else {
                                        "wrong .w value"
                                    }
                                )
                            });
                        }
                        let key = (a as u64) << 32 | bb as u64;
                        *out_edge = (key, (first_record + r) as u32, f[7].to_bits());
                        for (s, &o) in ids[2..].iter().enumerate() {
                            let t = b.slot_tri[k * r + s];
                            if t != UNKNOWN && a < bb {
                                // Which edge of the corner set: o is its
                                // smallest, middle or largest corner.
                                let e = usize::from(o > a) + usize::from(o > bb);
                                slot_counts[3 * slot_of(t) + e].fetch_add(1, Relaxed);
                            } else {
                                odd.push([a, bb, o]);
                            }
                        }
                    }
                    (errors, first, odd)
                }),
        );
        first_record += n;
    }
    for (errors, first, odd) in found {
        rep.record_errors += errors;
        if let Some(msg) = first {
            note(&mut rep, msg);
        }
        odd_sides.extend(odd);
    }
    // A record number's bucket k and number within its bucket.
    let ends: Vec<usize> = d
        .buckets
        .iter()
        .scan(0, |end, b| {
            *end += b.records();
            Some(*end)
        })
        .collect();
    let locate = |record: u32| {
        let i = ends.partition_point(|&end| end <= record as usize);
        let first = if i == 0 { 0 } else { ends[i - 1] };
        (d.buckets[i].k, record as usize - first)
    };
    // Per edge: every record's B.w equals the first record's (in file
    // order), and that equals the edge's opposite vertices (the sum of its
    // records' k), saturated at the encoding's limit.
    // (Each is unique, so ordered by its key and record number.)
    sort_few_runs(&mut edges);
    for group in edges.chunk_by(|x, y| x.0 == y.0) {
        let bw = |e: &(u64, u32, u32)| f32::from_bits(e.2);
        for e in &group[1..] {
            if bw(e) != bw(&group[0]) {
                rep.record_errors += 1;
                let (k, r) = locate(e.1);
                note(
                    &mut rep,
                    format!("bucket k={k} record {r}: B.w differs between chunks of one edge"),
                );
            }
        }
        let n: u64 = group.iter().map(|e| locate(e.1).0 as u64).sum();
        if (n as f32).min(d.w_limit) != bw(&group[0]) {
            rep.record_errors += 1;
            let (a, b) = ((group[0].0 >> 32) as u32, group[0].0 as u32);
            note(
                &mut rep,
                format!(
                    "edge {a}-{b}: B.w = {} but {n} opposite vertices are stored",
                    bw(&group[0])
                ),
            );
        }
    }
    // Check 1's bijection: the (a, b, o) triples of the sides (a record's
    // A, B and one of its opposite vertices) and of the caps (each edge of
    // a triangle, ends in order, and the third corner) are equal
    // multisets; every triple on one side only is an error, and the first
    // problem is the smallest such triple. A triple of three distinct
    // known ids, a < b, whose corner set is a caps triangle's (what decode
    // found for the slot) is regular: per corner set and edge it is
    // counted, against the number of caps triangles with that set, instead
    // of sorting 3 triples per triangle on both sides. The rest (damaged
    // files only: A not below B, unknown positions, degenerate caps) are
    // compared by sorting, as all triples once were; no regular triple can
    // equal one of them.
    let mut class_size = vec![0u32; d.caps.len()];
    let mut odd_caps: Vec<[u32; 3]> = Vec::new();
    for (t, &first) in d.caps.iter().zip(&d.cap_first) {
        if first != UNKNOWN {
            class_size[slot_of(first)] += 1;
        } else {
            odd_caps.extend((0..3).map(|e| {
                let (p, q, o) = (t[e], t[(e + 1) % 3], t[(e + 2) % 3]);
                [p.min(q), p.max(q), o]
            }));
        }
    }
    // (smallest unmatched triple, whether it is a sides entry)
    let mut first: Option<([u32; 3], bool)> = None;
    let mut keep = |triple: [u32; 3], side: bool| {
        if first.is_none_or(|f| triple < f.0) {
            first = Some((triple, side));
        }
    };
    for (i, &size) in class_size.iter().enumerate().filter(|c| *c.1 > 0) {
        for e in 0..3 {
            let count = slot_counts[3 * i + e].load(Relaxed);
            if count != size {
                let t = ranked.map_or(i, |(_, order)| order[i] as usize);
                let (k, _) = crate::evaluate_indexed::sort_ids(d.caps[t]);
                rep.bijection_errors += u64::from(count.abs_diff(size));
                // The edge opposite corner e, ends in order.
                let ends: Vec<u32> = (0..3).filter(|&i| i != e).map(|i| k[i]).collect();
                keep([ends[0], ends[1], k[e]], count > size);
            }
        }
    }
    // Multiset difference of the rest, sorted (equal triples are
    // identical, so the order does not depend on the sort).
    odd_sides.sort_unstable();
    odd_caps.sort_unstable();
    let (mut i, mut j) = (0, 0);
    while i < odd_sides.len() || j < odd_caps.len() {
        let take_side = j == odd_caps.len() || (i < odd_sides.len() && odd_sides[i] < odd_caps[j]);
        let take_cap = i == odd_sides.len() || (j < odd_caps.len() && odd_caps[j] < odd_sides[i]);
        if take_side {
            rep.bijection_errors += 1;
            keep(odd_sides[i], true);
            i += 1;
        } else if take_cap {
            rep.bijection_errors += 1;
            keep(odd_caps[j], false);
            j += 1;
        } else {
            i += 1;
            j += 1;
        }
    }
    if let Some((triple, side)) = first {
        let points = ids_to_points(d, triple);
        note(
            &mut rep,
            if side {
                format!("sides entry (A, B, O) = {points:?} matches no caps triangle")
            } else {
                format!("caps (triangle, edge) {points:?} has no sides entry")
            },
        );
    }
    rep
}

fn ids_to_points(d: &Decoded, ids: [u32; 3]) -> Vec<Option<[f32; 3]>> {
    ids.iter()
        .map(|&i| d.positions.get(i as usize).copied())
        .collect()
}

/// What the shaders decided for one light.
#[derive(Debug, Clone, Default)]
pub struct Evaluation {
    /// Cap orientation per triangle.
    pub caps: Vec<i8>,
    /// Multiplicity per record, per bucket.
    pub sides: Vec<Vec<i8>>,
    /// The scratch of [`OrderedEvaluation::cap_signs`], kept between
    /// lights like the other buffers.
    scratch: Vec<i8>,
    /// The scratch of a group of lights ([`evaluate_many_into`]), in the
    /// group's first evaluation.
    group: GroupScratch,
}

/// Runs the CPU evaluator for `light` over every record.
///
/// For a consistent strategy (every one but Kim's) a slot's contribution is
/// its triangle's cap sign times the slot's parity, exactly (see
/// [`DecodedBucket::slot_parity`]), so each triangle is evaluated once and the
/// sides sum those signs: the same result as evaluating every record as the
/// shader does ([`evaluate_per_record`]), about three times less arithmetic.
/// Slots without a matching triangle (a damaged file) are evaluated directly.
///
/// For [`Strategy::Reference`] both halves run on the tables of
/// [`Decoded::ordered`] ([`crate::evaluate_ordered`]): the caps from corner
/// ids sorted once per file, vectorised
/// ([`crate::evaluate_indexed::IndexedCaps`]), numbered in the order the
/// side records first name them, so that each record's sum reads signs
/// close to the last record's. When the file's table declines that, the
/// caps are evaluated on the records ([`crate::evaluate_simd::cap_signs`])
/// and the sides through the gathers of
/// [`crate::evaluate_simd::try_sides_from_caps`]. Results are bit for bit
/// those of the scalar loops (`crate::evaluate::*_scalar`).
pub fn evaluate(d: &Decoded, light: Light, strategy: Strategy) -> Evaluation {
    let mut ev = Evaluation::default();
    evaluate_into(d, light, strategy, &mut ev);
    ev
}

/// [`evaluate`] into the buffers of `ev`, resized to `d` (every entry is
/// overwritten). A caller that evaluates many lights keeps one
/// [`Evaluation`] and saves two fresh allocations per light: on a large
/// file those are megabytes of pages the kernel must map and zero on first
/// touch, which cost about as much as the evaluation itself (benches/evaluate.rs,
/// `caps+sides/reference_shared` against `…_fresh`).
///
/// Its passes run as one job on rayon's pool (see `crate::pool`): one wait
/// for a pool thread per call from outside the pool, not one per pass.
pub fn evaluate_into(d: &Decoded, light: Light, strategy: Strategy, ev: &mut Evaluation) {
    crate::pool::one_job(|| evaluate_passes(d, light, strategy, ev))
}

/// The passes of [`evaluate_into`].
fn evaluate_passes(d: &Decoded, light: Light, strategy: Strategy, ev: &mut Evaluation) {
    if strategy == Strategy::Kim {
        return evaluate_sides(d, light, strategy, ev, |b, _, m| {
            side_multiplicities_with(strategy, b.k, &b.data, light, m)
        });
    }
    if let (Strategy::Reference, Some(o)) = (strategy, &d.ordered) {
        return evaluate_ordered(d, o, light, ev);
    }
    evaluate_sides(d, light, strategy, ev, |b, caps, m| {
        crate::evaluate::side_multiplicities_shared(
            strategy,
            b.k,
            &b.data,
            &b.slot_tri,
            &b.slot_parity,
            caps,
            light,
            m,
        )
    })
}

/// [`evaluate`] record by record, exactly as the shaders do it.
pub fn evaluate_per_record(d: &Decoded, light: Light, strategy: Strategy) -> Evaluation {
    let mut ev = Evaluation::default();
    evaluate_sides(d, light, strategy, &mut ev, |b, _, m| {
        side_multiplicities_with(strategy, b.k, &b.data, light, m)
    });
    ev
}

/// [`evaluate_into`] for the reference strategy on the tables of `o`
/// (`d.ordered`): the caps, then each bucket's packed blocks, then the
/// records `o` leaves (a bucket's last records, fewer than a block; blocks
/// with a slot that names no triangle or slots more than 16 bits apart)
/// through the shared loop.
fn evaluate_ordered(d: &Decoded, o: &OrderedEvaluation, light: Light, ev: &mut Evaluation) {
    ev.caps.resize(d.caps.len(), 0);
    o.cap_signs(light, &mut ev.scratch, &mut ev.caps);
    ordered_sides(d, o, light, ev);
}

/// [`evaluate_into`] for several lights, `evs[i]` for `lights[i]`, with the
/// same results, bit for bit. For [`Strategy::Reference`] on the tables of
/// [`Decoded::ordered`], each group of [`LIGHT_GROUP`] lights is evaluated
/// together: the caps in one pass over the triangles, which reads and
/// transposes each triangle's corners once for the group and writes the
/// group's signs into one table, and the sides from that table, one load
/// and one add per slot for the whole group
/// ([`OrderedEvaluation::group_cap_signs`],
/// [`OrderedEvaluation::group_sides`]). The lights after the last whole
/// group, the other strategies, and files whose table `decode` declined,
/// are evaluated light by light.
///
/// On the dragon, one thread, 1.22–1.27 ns per side record per light
/// against 2.43–2.55 one light at a time (fastest of 40 rounds, `cargo run
/// --release --example stage_probe -- evaluate target/dragon/dragon.glb`,
/// four runs; benches/ROUNDS.md, twenty-eighth round). `verify` evaluates
/// its lights one by one: there the evaluation is 2–3% of a light's
/// checks, and in groups it measured the same time for 26 MiB more peak
/// memory on the dragon (four evaluations and the group's table per
/// worker). As one job on rayon's pool, as [`evaluate_into`].
pub fn evaluate_many_into(
    d: &Decoded,
    lights: &[Light],
    strategy: Strategy,
    evs: &mut [Evaluation],
) {
    assert_eq!(lights.len(), evs.len(), "one evaluation per light");
    crate::pool::one_job(|| evaluate_many_passes(d, lights, strategy, evs))
}

/// The passes of [`evaluate_many_into`].
fn evaluate_many_passes(d: &Decoded, lights: &[Light], strategy: Strategy, evs: &mut [Evaluation]) {
    let Some(o) = d
        .ordered
        .as_ref()
        .filter(|_| strategy == Strategy::Reference)
    else {
        for (&l, ev) in lights.iter().zip(evs) {
            evaluate_into(d, l, strategy, ev);
        }
        return;
    };
    let mut groups = evs.chunks_exact_mut(LIGHT_GROUP);
    let mut group_lights = lights.chunks_exact(LIGHT_GROUP);
    for (l, evs) in (&mut group_lights).zip(&mut groups) {
        let l: &[Light; LIGHT_GROUP] = l.try_into().expect("a group");
        let evs: &mut [Evaluation; LIGHT_GROUP] = evs.try_into().expect("a group");
        // The group's scratch lives in its first evaluation between calls.
        let mut scratch = std::mem::take(&mut evs[0].group);
        for ev in evs.iter_mut() {
            ev.caps.resize(d.caps.len(), 0);
            ev.sides.resize_with(d.buckets.len(), Vec::new);
            for (m, b) in ev.sides.iter_mut().zip(&d.buckets) {
                m.resize(b.records(), 0);
            }
        }
        o.group_cap_signs(l, &mut scratch, evs.each_mut().map(|ev| &mut ev.caps[..]));
        for (i, b) in d.buckets.iter().enumerate() {
            o.group_sides(i, &scratch, evs.each_mut().map(|ev| &mut ev.sides[i][..]));
            for (&l, ev) in l.iter().zip(evs.iter_mut()) {
                ordered_leftovers(o, i, b, l, ev);
            }
        }
        evs[0].group = scratch;
    }
    for (&l, ev) in group_lights.remainder().iter().zip(groups.into_remainder()) {
        evaluate_into(d, l, strategy, ev);
    }
}

/// The sides of [`evaluate_ordered`] from the scratch that
/// [`OrderedEvaluation::cap_signs`] left in `ev` for `light`.
fn ordered_sides(d: &Decoded, o: &OrderedEvaluation, light: Light, ev: &mut Evaluation) {
    ev.sides.resize_with(d.buckets.len(), Vec::new);
    for (i, b) in d.buckets.iter().enumerate() {
        ev.sides[i].resize(b.records(), 0);
        o.sides(i, &ev.scratch, &mut ev.sides[i]);
        ordered_leftovers(o, i, b, light, ev);
    }
}

/// The records of bucket `i` (`b`) that `o` leaves to the caller, through
/// the shared loop over `ev`'s caps in input order.
fn ordered_leftovers(
    o: &OrderedEvaluation,
    i: usize,
    b: &DecodedBucket,
    light: Light,
    ev: &mut Evaluation,
) {
    let (k, stride) = (b.k, (2 + b.k) * 4);
    let m = &mut ev.sides[i];
    for r in o.leftovers(i) {
        let slots = r.start * k..r.end * k;
        crate::evaluate::side_multiplicities_shared(
            Strategy::Reference,
            k,
            &b.data[r.start * stride..r.end * stride],
            &b.slot_tri[slots.clone()],
            &b.slot_parity[slots],
            &ev.caps,
            light,
            &mut m[r.clone()],
        );
    }
}

/// Cap signs from the records, then every bucket's multiplicities through
/// `sides(bucket, caps, out)`, into `ev`'s buffers.
fn evaluate_sides(
    d: &Decoded,
    light: Light,
    strategy: Strategy,
    ev: &mut Evaluation,
    sides: impl Fn(&DecodedBucket, &[i8], &mut [i8]),
) {
    ev.caps.resize(d.caps.len(), 0);
    cap_signs_with(strategy, &d.caps_data, light, &mut ev.caps);
    ev.sides.resize_with(d.buckets.len(), Vec::new);
    for (b, m) in d.buckets.iter().zip(&mut ev.sides) {
        m.resize(b.records(), 0);
        sides(b, &ev.caps, m);
    }
}

/// Per-light counters of check 2.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Closedness {
    /// Records with m != 0.
    pub silhouette_instances: u64,
    /// Side quads drawn (sum of |m|).
    pub side_quads: u64,
    /// Caps with c != 0 (each draws a front and a back cap).
    pub caps: u64,
    /// Undirected edges of the emitted surface used unequally in the two directions.
    pub violations: u64,
}

/// Check 2 for one light: emits what the shaders draw and counts unbalanced edges.
pub fn check_closedness(d: &Decoded, light: Light, ev: &Evaluation) -> Closedness {
    check_closedness_with(d, light, ev, &mut ClosednessScratch::default())
}

/// Buffers of [`check_closedness_with`], kept across lights: on a large file
/// they are tens of megabytes, and fresh pages cost as much as the check.
#[derive(Debug, Default)]
pub struct ClosednessScratch {
    /// Per position, its point at infinity's bits and its id.
    inf: Vec<([u32; 3], u32)>,
    /// Per position, the vertex id of its point at infinity.
    inf_id: Vec<u32>,
    /// Per vertex id, where its edges start in `edges` (then a cursor).
    start: Vec<u32>,
    /// Per emitted edge, grouped by its smaller vertex id: the larger id in
    /// the high half, the signed weight in the low half.
    edges: Vec<u64>,
    /// [`check_closedness_indexed`]: each cap's sign, then each record's
    /// multiplicity, as [`ClosednessIndex`] entries index them.
    signs: Vec<i8>,
    /// [`check_closedness_indexed`]: the two positions of each unbalanced
    /// pair, with its weight taken away from each.
    own: Vec<(u32, i64)>,
    /// [`check_closedness_indexed`]: when some positions share a point at
    /// infinity, the unbalanced pairs' weights there, keyed by the pair of
    /// positions whose points they join.
    at_inf: Vec<(u64, i64)>,
    /// [`infinity_ids`]: one run of positions' extruded (y, z).
    runs: Vec<([u32; 2], u32)>,
    /// [`infinity_ids`]: per position, the smallest one sharing its point
    /// at infinity.
    rep: Vec<u32>,
}

/// [`check_closedness`] with buffers reused across calls.
///
/// Every triangle the shaders draw (front and back caps, side quads as two
/// triangles) is cut into directed edges; an undirected edge is balanced
/// when its signed weights sum to zero. Vertex ids: finite positions
/// `0..n`, points at infinity `n..` by distinct 4-tuple (different positions
/// can extrude to the same point at infinity). The edges are grouped by
/// their smaller id with a counting sort (one pass to count, one to place),
/// and each group, a handful of edges, is sorted by the larger id and
/// summed: linear in the number of edges, where sorting all of them (what
/// this did before) took most of `verify`'s time on large files.
pub fn check_closedness_with(
    d: &Decoded,
    light: Light,
    ev: &Evaluation,
    scratch: &mut ClosednessScratch,
) -> Closedness {
    let ClosednessScratch {
        inf,
        inf_id,
        start,
        edges,
        ..
    } = scratch;
    let n = d.positions.len() as u32;
    inf.clear();
    inf.extend(d.positions.iter().enumerate().map(|(i, &p)| {
        let q = to_infinity(p, light);
        (
            [q[0], q[1], q[2]].map(|v| if v == 0.0 { 0 } else { v.to_bits() }),
            i as u32,
        )
    }));
    inf.sort_unstable();
    inf_id.clear();
    inf_id.resize(d.positions.len(), 0);
    let mut next = n;
    for (i, e) in inf.iter().enumerate() {
        if i > 0 && inf[i - 1].0 != e.0 {
            next += 1;
        }
        inf_id[e.1 as usize] = next;
    }
    // Groups for ids 0..=next. The positions a damaged file's records name
    // but no cap has (`UNKNOWN`), finite or at infinity, get id next + 1:
    // the largest, so never an edge's smaller end, and it needs no group.
    let ids = next as usize + 1;
    let inf_id = &*inf_id;

    // Pass 1 counts each vertex's edges (as the smaller end), pass 2 places
    // them; both walk the same emission.
    start.clear();
    start.resize(ids + 1, 0);
    let unknown = next + 1;
    let mut rep = emit_drawn_edges(d, ev, inf_id, unknown, |x, _, _| start[x as usize + 1] += 1);
    for v in 1..start.len() {
        start[v] += start[v - 1];
    }
    edges.clear();
    edges.resize(start[ids] as usize, 0);
    emit_drawn_edges(d, ev, inf_id, unknown, |x, y, w| {
        let at = &mut start[x as usize];
        edges[*at as usize] = ((y as u64) << 32) | w as u32 as u64;
        *at += 1;
    });
    // `start[v]` now is where vertex v's group ends (the next one's start).
    let mut from = 0usize;
    for &end in start.iter().take(ids) {
        let group = &mut edges[from..end as usize];
        from = end as usize;
        group.sort_unstable();
        let mut i = 0;
        while i < group.len() {
            let other = group[i] >> 32;
            let mut sum = 0i64;
            while i < group.len() && group[i] >> 32 == other {
                sum += group[i] as u32 as i32 as i64;
                i += 1;
            }
            rep.violations += (sum != 0) as u64;
        }
    }
    rep
}

/// Per-mesh numbering of the position pairs that drawn edges join, for
/// [`check_closedness_indexed`]: built once per file, used for every light.
///
/// Every edge the shaders draw joins either two positions (a front cap's
/// edge, a side quad's A–B), the points at infinity of two positions (a back
/// cap's edge, a side quad's A∞–B∞), or a position and its own point at
/// infinity (a side quad's A–A∞ and B–B∞; the quad's diagonal is drawn once
/// each way and cancels). The first two kinds join the same pairs: a cap's
/// three corner pairs, a record's (A, B). The index lists, pair after pair,
/// which caps and records draw an edge of it and in which direction, so a
/// light sums each pair's signed weight by reading its signs in that list's
/// order: a stream, where adding each edge's weight into its pair's slot
/// (what this did until the forty-second round) stored into a table of
/// megabytes at random.
#[derive(Debug, Default)]
pub struct ClosednessIndex {
    /// Per pair, in ascending `(smaller, larger)` order of its ids: one
    /// entry per cap edge or record on it. An entry's low 30 bits index the
    /// light's signs: a cap by its evaluation number
    /// ([`OrderedEvaluation::rank`]), the order the side records first name
    /// the caps, which follows the pairs' order, so the signs one pair
    /// reads lie near the last pair's (in input order they were anywhere in
    /// the dragon's 871 KB of signs: 5.3–5.9 against 7.1–7.6 ms a light
    /// for the sums, for 1.1 ms more putting the signs in that order, local
    /// timers); record `r`, counting over the buckets, by
    /// `caps + r`. [`NEGATE`] is set when the edge's weight from the
    /// smaller id to the larger is minus that sign, and [`LAST`] marks a
    /// pair's last entry. Collapsed edges (both ends one position) have
    /// none.
    ///
    /// Only the pairs with other than three entries are listed here; their
    /// numbers are in `other_pairs`. The pairs with three (on a closed
    /// mesh, every pair: two caps and a record) are in the triples.
    pair_entries: Vec<u32>,
    /// The numbers of the pairs in `pair_entries`, ascending.
    other_pairs: Vec<u32>,
    /// The entries of the pairs with exactly three, as in `pair_entries`
    /// without [`LAST`], in runs of consecutive pair numbers
    /// (`triple_runs`). Why: with three entries known, a light sums a pair
    /// without a branch on [`LAST`] per entry, and checks a block of pairs
    /// for a sum other than zero at once: the dragon's sums took 47.9–49.3
    /// ms of its 16 lights instead of 63.2–64.3 (one thread, local timers,
    /// benches/ROUNDS.md, Forty-third round).
    ///
    /// Stored as the first `3 · triple_count` `u32`s of `triple_words`
    /// ([`ClosednessIndex::triples`]), the vector the entries were sorted
    /// in (see [`ClosednessIndex::new`]).
    triple_words: Vec<u64>,
    /// Number of triples.
    triple_count: usize,
    /// `(first pair, count)` of each run of triples, in order.
    triple_runs: Vec<(u32, u32)>,
    /// Each pair's ids as `(smaller << 32) | larger`, ascending: pair `n`'s
    /// key is `pair_keys[n]`.
    pair_keys: Vec<u64>,
    /// False when some id is [`UNKNOWN`] (a damaged file) or the positions are
    /// not strictly increasing: then only the general check applies.
    usable: bool,
}

/// Flag of a [`ClosednessIndex`] entry: its weight is minus its sign.
const NEGATE: u32 = 1 << 31;
/// Flag of a [`ClosednessIndex`] entry: the last of its pair.
const LAST: u32 = 1 << 30;
/// The sign index of a [`ClosednessIndex`] entry.
const SIGN_INDEX: u32 = LAST - 1;

impl ClosednessIndex {
    /// Lists the pairs of `d`: a counting sort of the drawn pairs by their
    /// smaller id, then each smaller id's few entries (about nine on a
    /// closed mesh) sorted by the larger one, so that pairs come in
    /// ascending `(smaller, larger)` order. Why not one sort of every
    /// pair's key, as before: the dragon's 3.9M pairs took 240–259 ms to
    /// number that way on one thread, against 88–100 ms for this (local
    /// timers; benches/ROUNDS.md, Forty-first round).
    pub fn new(d: &Decoded) -> ClosednessIndex {
        let unknown_cap = d.caps.iter().flatten().any(|&i| i == UNKNOWN);
        let unknown_record = d.buckets.iter().any(|b| {
            b.ids
                .chunks_exact(2 + b.k)
                .any(|r| r[0] == UNKNOWN || r[1] == UNKNOWN)
        });
        if unknown_cap || unknown_record || d.ordered.is_none() {
            return ClosednessIndex::default();
        }
        let records: usize = d.buckets.iter().map(|b| b.records()).sum();
        assert!(
            d.caps.len() + records <= SIGN_INDEX as usize,
            "verify: 2^30 caps and records or more"
        );
        // Per smaller id, first the count of its entries, then (after the
        // prefix sums) the end of its range, which the scatter walks back
        // to the range's start. Collapsed edges (one position) are left
        // out.
        let mut start = vec![0u32; d.positions.len() + 1];
        for_each_drawn_pair(d, d.caps.iter().copied(), |x, y, _| {
            if x != y {
                start[x.min(y) as usize] += 1;
            }
        });
        let mut sum = 0;
        for s in start.iter_mut() {
            sum += *s;
            *s = sum;
        }
        // Each entry: the larger id above, the entry of `pair_entries`
        // below. A cap's sign is its edges' weight along its winding, a
        // record's m is minus its A → B weight (`side_corner`).
        //
        // The caps are taken in evaluation order, which follows the pairs'
        // order: in input order each cap's entries went anywhere in the
        // dragon's 31 MB of entries, and this pass took 28.4–29.9 ms
        // instead of 24.9–27.9, the lists' pass below 35.7–38.1 instead of
        // 31.7–33.6 (one thread, local timers, benches/ROUNDS.md,
        // Forty-third round). Each list is sorted below, so the order of
        // this pass does not change the index.
        let caps = d.caps.len() as u32;
        let order = d.ordered.as_ref().expect("usable").order();
        let in_order = order.iter().enumerate().map(|(r, &t)| {
            // Input order is far from this one.
            if let Some(&ahead) = order.get(r + 16) {
                crate::hint::prefetch(&d.caps[ahead as usize]);
            }
            d.caps[t as usize]
        });
        let mut entries = vec![0u64; start[d.positions.len()] as usize];
        for_each_drawn_pair(d, in_order, |x, y, o| {
            if x != y {
                let at = &mut start[x.min(y) as usize];
                *at -= 1;
                let negate = if (x > y) != (o >= caps) { NEGATE } else { 0 };
                entries[*at as usize] = ((x.max(y) as u64) << 32) | (o | negate) as u64;
            }
        });
        // Reserved for every entry (pages never written are never
        // touched), so that neither moves as it grows.
        let mut index = ClosednessIndex {
            pair_entries: Vec::with_capacity(entries.len()),
            pair_keys: Vec::with_capacity(entries.len()),
            usable: true,
            ..Default::default()
        };
        // The triples are written over the entries already read, as `u32`s:
        // each reads three entries and writes half their bytes, so `at`,
        // the `u32`s written, never passes `i`, the entries read, and the
        // entries not yet read are never written. In a vector of their own
        // they were fresh memory, a third of the entries' (the 5M scene's
        // 90 MB), faulted in a page at a time.
        let mut at = 0;
        for (smaller, range) in start.windows(2).enumerate() {
            let (first, end) = (range[0] as usize, range[1] as usize);
            entries[first..end].sort_unstable();
            let mut i = first;
            while i < end {
                let larger = entries[i] >> 32;
                let run = entries[i..end]
                    .iter()
                    .take_while(|&&e| e >> 32 == larger)
                    .count();
                let n = index.pair_keys.len() as u32;
                index.pair_keys.push(((smaller as u64) << 32) | larger);
                if run == 3 {
                    let t = [entries[i], entries[i + 1], entries[i + 2]].map(|e| e as u32);
                    bytemuck::cast_slice_mut::<u64, u32>(&mut entries)[at..at + 3]
                        .copy_from_slice(&t);
                    at += 3;
                    match index.triple_runs.last_mut() {
                        Some((first, count)) if *first + *count == n => *count += 1,
                        _ => index.triple_runs.push((n, 1)),
                    }
                } else {
                    index.other_pairs.push(n);
                    let pair = &entries[i..i + run];
                    index.pair_entries.extend(pair.iter().map(|&e| e as u32));
                    *index.pair_entries.last_mut().expect("a run has entries") |= LAST;
                }
                i += run;
            }
        }
        entries.truncate(at.div_ceil(2));
        entries.shrink_to_fit();
        index.triple_words = entries;
        index.triple_count = at / 3;
        index
    }
}

/// Calls `f(x, y, sign index)` for every pair a light may draw: the edges
/// (corner e to corner e + 1) of each caps triangle `caps` yields (every
/// triangle once), the sign index counting them, then each record's
/// (A, B), its sign index counting on from the caps'.
#[inline(always)]
fn for_each_drawn_pair(
    d: &Decoded,
    caps: impl Iterator<Item = [u32; 3]>,
    mut f: impl FnMut(u32, u32, u32),
) {
    let mut o = 0u32;
    for c in caps {
        f(c[0], c[1], o);
        f(c[1], c[2], o);
        f(c[2], c[0], o);
        o += 1;
    }
    for b in &d.buckets {
        for ids in b.ids.chunks_exact(2 + b.k) {
            f(ids[0], ids[1], o);
            o += 1;
        }
    }
}

impl ClosednessIndex {
    /// The entries of the pairs with three, pair after pair.
    fn triples(&self) -> &[[u32; 3]] {
        let words: &[u32] = bytemuck::cast_slice(&self.triple_words);
        words[..3 * self.triple_count].as_chunks().0
    }

    /// Calls `f` with the number and signed weight of each pair whose
    /// weight is not 0: the sum of the signs its entries index, negated
    /// where they say so. Integer sums, so the order of the additions does
    /// not matter; the pairs come in no particular order.
    #[inline(always)]
    fn nonzero_pair_sums(&self, signs: &[i8], mut f: impl FnMut(usize, i64)) {
        let weight = |e: u32| {
            let v = signs[(e & SIGN_INDEX) as usize] as i64;
            // 0 or −1: (v ^ −1) − (−1) = −v.
            let negate = -((e >> 31) as i64);
            (v ^ negate) - negate
        };
        let sum3 = |t: &[u32; 3]| weight(t[0]) + weight(t[1]) + weight(t[2]);
        let mut triples = self.triples();
        for &(first, count) in &self.triple_runs {
            let (run, rest) = triples.split_at(count as usize);
            triples = rest;
            for (b, block) in run.chunks(TRIPLE_BLOCK).enumerate() {
                // Any sum not 0 leaves a bit set.
                let any = block.iter().fold(0, |any, t| any | sum3(t));
                if any != 0 {
                    let first = first as usize + b * TRIPLE_BLOCK;
                    for (j, t) in block.iter().enumerate() {
                        let s = sum3(t);
                        if s != 0 {
                            f(first + j, s);
                        }
                    }
                }
            }
        }
        let (mut pair, mut sum) = (0, 0i64);
        for &e in &self.pair_entries {
            sum += weight(e);
            if e & LAST != 0 {
                if sum != 0 {
                    f(self.other_pairs[pair] as usize, sum);
                }
                (pair, sum) = (pair + 1, 0);
            }
        }
    }
}

/// Pairs of three entries that [`ClosednessIndex::nonzero_pair_sums`]
/// checks together.
const TRIPLE_BLOCK: usize = 32;

/// How the points at infinity of one light relate to the positions.
#[derive(Debug, Clone, Copy, PartialEq)]
enum InfinityIds {
    /// Every position has its own (a point light, usually).
    Distinct,
    /// All positions share one (a directional light).
    One,
    /// Some, not all, share one: `rep[p]` is the smallest position with
    /// p's point at infinity.
    Merged,
}

/// Classifies the points at infinity of `light` over the positions of `d`
/// (strictly increasing), filling `rep` when some are shared. A directional
/// light extrudes every position to `−L` (`0·P − L`, the zeros canonical).
/// For a point light the positions' x are increasing and `toInf` rounds
/// `x − l_x`, monotone in x, so equal points lie within one run of equal
/// extruded x. Within a run the extruded (y, z) usually still increase, as
/// the positions' do; only a run where they do not is sorted and searched
/// for a repeated (y, z). (Shared points are common: a point light half a
/// unit from the 871k-triangle dragon merges near-coincident scan
/// vertices.) One pass computes each position's point once: sorting every
/// run with more than one position, as until the forty-second round, took
/// 4–5 ms of the dragon's 14 ms check under a light merging none.
fn infinity_ids(
    d: &Decoded,
    light: Light,
    run: &mut Vec<([u32; 2], u32)>,
    rep: &mut Vec<u32>,
) -> InfinityIds {
    if light[3] == 0.0 {
        return if d.positions.is_empty() {
            InfinityIds::Distinct
        } else {
            InfinityIds::One
        };
    }
    // Increasing with the value; −0.0 and +0.0 one key (`+ 0.0` makes −0.0
    // +0.0), so equal keys are equal points.
    let key = |p: [f32; 3]| to_infinity(p, light).map(|v| order_key(v + 0.0));
    let mut kind = InfinityIds::Distinct;
    let n = d.positions.len();
    let (mut from, mut sorted) = (0, true);
    let mut last = [0; 4];
    for i in 0..=n {
        let q = if i < n { key(d.positions[i]) } else { [0; 4] };
        if i < n && i > from && q[0] == last[0] {
            sorted &= (q[1], q[2]) > (last[1], last[2]);
            last = q;
            continue;
        }
        // The run from..i has ended.
        if !sorted {
            run.clear();
            run.extend((from..i).map(|p| {
                let q = key(d.positions[p]);
                ([q[1], q[2]], p as u32)
            }));
            run.sort_unstable();
            for group in run.chunk_by(|a, b| a.0 == b.0).filter(|g| g.len() > 1) {
                if kind == InfinityIds::Distinct {
                    kind = InfinityIds::Merged;
                    rep.clear();
                    rep.extend(0..n as u32);
                }
                for &(_, p) in group {
                    rep[p as usize] = group[0].1;
                }
            }
        }
        (from, sorted, last) = (i, true, q);
    }
    kind
}

/// [`check_closedness_with`], the same counts, with the pairs listed once
/// per file ([`ClosednessIndex`]): each pair's weight is the sum of its
/// entries' signs, read in order, with no grouping of edges per light. A
/// damaged file (unknown ids, positions not strictly increasing) goes to
/// the general check.
///
/// At infinity the pairs are those of the positions' points, which a light
/// may merge (`infinity_ids`). When every position has its own point, the
/// back caps and the A∞–B∞ edges join the same pairs as the front caps and
/// the A–B edges, each with the opposite direction (a back cap is its front
/// cap reversed at infinity; a side quad runs B → A and A∞ → B∞ for m > 0,
/// the reverse for m < 0), so the pairs at infinity are unbalanced exactly
/// where the finite ones are. When all share one point (a directional
/// light), every edge there is collapsed. Otherwise each unbalanced pair's
/// weight moves to the pair of its positions' points (the pair itself when
/// both keep their own), and those few are grouped by sorting.
///
/// The edges from a position P to its own point at infinity (a side
/// quad's A–A∞ with weight m, B–B∞ with −m) weigh, in all, minus the sum of
/// P's pairs' weights taken away from P: each cap passes through P as often
/// as it leaves it, so its edges there cancel, and a record's A → B edge
/// (weight −m) leaves A and enters B. So those weights are summed from the
/// unbalanced pairs alone, none in a closed volume, instead of from every
/// record's two ends (2.6M on the dragon: 3.5 ms of a light's 13, local
/// timers, benches/ROUNDS.md, Forty-second round).
pub fn check_closedness_indexed(
    d: &Decoded,
    index: &ClosednessIndex,
    light: Light,
    ev: &Evaluation,
    scratch: &mut ClosednessScratch,
) -> Closedness {
    if !index.usable {
        return check_closedness_with(d, light, ev, scratch);
    }
    let ClosednessScratch {
        signs,
        runs,
        rep: reps,
        at_inf,
        own,
        ..
    } = scratch;
    let kind = infinity_ids(d, light, runs, reps);
    let mut rep = Closedness::default();
    // The signs the entries index: each cap's in evaluation order, then
    // each record's m.
    signs.clear();
    let order = d.ordered.as_ref().expect("usable").order();
    signs.extend(order.iter().map(|&t| ev.caps[t as usize].signum()));
    rep.caps = nonzero_and_magnitudes(&ev.caps).0;
    for ms in &ev.sides {
        signs.extend_from_slice(ms);
        let (nonzero, magnitudes) = nonzero_and_magnitudes(ms);
        rep.silhouette_instances += nonzero;
        rep.side_quads += magnitudes;
    }
    own.clear();
    at_inf.clear();
    let merged = kind == InfinityIds::Merged;
    let mut finite = 0;
    index.nonzero_pair_sums(signs, |n, s| {
        finite += 1;
        let key = index.pair_keys[n];
        let (x, y) = ((key >> 32) as u32, key as u32);
        own.push((x, -s));
        own.push((y, s));
        if merged {
            // At infinity the pair weighs −s (its edges there run the
            // other way), on the pair of its positions' points: its own
            // when both keep theirs, another pair, or none when they
            // share one.
            let (rx, ry) = (reps[x as usize], reps[y as usize]);
            if rx != ry {
                let key = ((rx.min(ry) as u64) << 32) | rx.max(ry) as u64;
                at_inf.push((key, if rx < ry { -s } else { s }));
            }
        }
    });
    let at_infinity = match kind {
        InfinityIds::Distinct => finite,
        InfinityIds::One => 0,
        InfinityIds::Merged => nonzero_sums(at_inf),
    };
    rep.violations = finite + at_infinity + nonzero_sums(own);
    rep
}

/// How many of `v` are not 0, and the sum of their magnitudes. In chunks
/// of 256 with 16-bit sums (at most 256 · 128), which the compiler keeps
/// in vector registers: with 64-bit sums per value, these counts and the
/// copy of the records' signs took 20.9–21.0 ms of the dragon's 16 lights
/// instead of 5.8 (one thread, local timers, benches/ROUNDS.md,
/// Forty-third round).
fn nonzero_and_magnitudes(v: &[i8]) -> (u64, u64) {
    let (mut nonzero, mut magnitudes) = (0u64, 0u64);
    for chunk in v.chunks(256) {
        let (mut n, mut m) = (0u16, 0u16);
        for &x in chunk {
            n += (x != 0) as u16;
            m += x.unsigned_abs() as u16;
        }
        nonzero += n as u64;
        magnitudes += m as u64;
    }
    (nonzero, magnitudes)
}

/// Sorts `(key, weight)` entries and counts the keys whose weights do not
/// sum to zero.
fn nonzero_sums<K: Ord + Copy>(v: &mut [(K, i64)]) -> u64 {
    v.sort_unstable();
    v.chunk_by(|a, b| a.0 == b.0)
        .filter(|g| g.iter().map(|e| e.1).sum::<i64>() != 0)
        .count() as u64
}

/// Walks every triangle the shaders draw for `ev` and calls
/// `edge(smaller id, larger id, weight)` for each of its edges that is not
/// collapsed, the weight signed by the edge's direction (positive from the
/// smaller id to the larger). Position ids come from the file (`inf_id` maps
/// each to its point at infinity); any without a position, finite or at
/// infinity, becomes `unknown`. Returns the counters of [`Closedness`] except
/// `violations`.
fn emit_drawn_edges(
    d: &Decoded,
    ev: &Evaluation,
    inf_id: &[u32],
    unknown: u32,
    mut edge: impl FnMut(u32, u32, i32),
) -> Closedness {
    let mut rep = Closedness::default();
    let n = inf_id.len() as u32;
    let finite = |v: u32| if v < n { v } else { unknown };
    let at_inf = |v: u32| inf_id.get(v as usize).copied().unwrap_or(unknown);
    let mut emit = |tri: [u32; 3], weight: i32| {
        for e in 0..3 {
            let (x, y) = (tri[e], tri[(e + 1) % 3]);
            if x == y {
                continue; // a collapsed edge is its own reverse
            }
            edge(x.min(y), x.max(y), if x < y { weight } else { -weight });
        }
    };
    for (t, &c) in d.caps.iter().zip(&ev.caps) {
        if c == 0 {
            continue;
        }
        rep.caps += 1;
        let corner = |v: u32| {
            let (i, infinite) = cap_corner(v, c as i32);
            let p = t[i as usize];
            if infinite { at_inf(p) } else { finite(p) }
        };
        emit([corner(0), corner(1), corner(2)], 1);
        emit([corner(3), corner(4), corner(5)], 1);
    }
    for (b, ms) in d.buckets.iter().zip(&ev.sides) {
        for (ids, &m) in b.ids.chunks_exact(2 + b.k).zip(ms) {
            if m == 0 {
                continue;
            }
            rep.silhouette_instances += 1;
            rep.side_quads += m.unsigned_abs() as u64;
            let quad = [
                finite(ids[0]),
                finite(ids[1]),
                at_inf(ids[0]),
                at_inf(ids[1]),
            ];
            let corner = |v: u32| quad[side_corner(v, m as i32) as usize];
            let w = m.unsigned_abs() as i32;
            emit([corner(0), corner(1), corner(2)], w);
            emit([corner(3), corner(4), corner(5)], w);
        }
    }
    rep
}

/// Deterministic generator (SplitMix64) for light placement.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator for `seed`.
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Uniform index below `n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
}

/// Chooses `count` lights deterministically from `seed`: point lights around
/// and inside the bounds, directional lights, and hard placements — on
/// vertices, on edge lines, in triangle planes, directional lights parallel to
/// faces. Placements are computed in f32 and kept only when they are exact
/// (e.g. `2·B − A` is on the line AB only if no rounding happened).
pub fn choose_lights(d: &Decoded, count: usize, seed: u64) -> Vec<Light> {
    let mut rng = Rng::new(seed);
    let (lo, hi) = crate::build::bounds(&d.positions);
    let c = [0, 1, 2].map(|k| 0.5 * (lo[k] as f64 + hi[k] as f64));
    let ext = [0, 1, 2].map(|k| (hi[k] as f64 - lo[k] as f64).max(1e-30));
    let size = ext.iter().cloned().fold(0.0, f64::max);
    let mut out = Vec::with_capacity(count);
    let tri = |rng: &mut Rng| -> [[f32; 3]; 3] {
        let t = d.caps[rng.below(d.caps.len())];
        t.map(|i| d.positions[i as usize])
    };
    let mut i = 0usize;
    while out.len() < count {
        let kind = i % 8;
        i += 1;
        let l: Option<Light> = match kind {
            // Around the model, up to 3 sizes away.
            0 | 1 => Some([0, 1, 2].map(|k| (c[k] + (rng.unit() - 0.5) * 6.0 * size) as f32))
                .map(|p| [p[0], p[1], p[2], 1.0]),
            // Inside the bounds.
            2 => Some([0, 1, 2].map(|k| (lo[k] as f64 + rng.unit() * ext[k]) as f32))
                .map(|p| [p[0], p[1], p[2], 1.0]),
            // Directional, random direction.
            3 => {
                let v = [0, 1, 2].map(|_| (rng.unit() * 2.0 - 1.0) as f32);
                (v != [0.0; 3]).then_some([v[0], v[1], v[2], 0.0])
            }
            // On a vertex.
            4 => {
                let p = tri(&mut rng)[rng.below(3)];
                Some([p[0], p[1], p[2], 1.0])
            }
            // On the line of an edge, beyond B: exactly in the plane of every triangle on it.
            5 => {
                let t = tri(&mut rng);
                let (a, b) = (t[0], t[1]);
                let p = [0, 1, 2].map(|k| 2.0 * b[k] - a[k]);
                let exact = (0..3).all(|k| p[k] as f64 == 2.0 * b[k] as f64 - a[k] as f64);
                exact.then_some([p[0], p[1], p[2], 1.0])
            }
            // In a triangle's plane: A + (B − A) + (C − A), when exact.
            6 => {
                let t = tri(&mut rng);
                let p = [0, 1, 2].map(|k| t[1][k] + t[2][k] - t[0][k]);
                let exact =
                    (0..3).all(|k| p[k] as f64 == t[1][k] as f64 + t[2][k] as f64 - t[0][k] as f64);
                exact.then_some([p[0], p[1], p[2], 1.0])
            }
            // Directional, parallel to a face (along one of its edges), when exact.
            _ => {
                let t = tri(&mut rng);
                let v = [0, 1, 2].map(|k| t[1][k] - t[0][k]);
                let exact = (0..3).all(|k| v[k] as f64 == t[1][k] as f64 - t[0][k] as f64);
                exact.then_some([v[0], v[1], v[2], 0.0])
            }
        };
        if let Some(l) = l.filter(|l| l.iter().all(|v| v.is_finite())) {
            out.push(l);
        } else if i > 64 * count + 64 {
            // Model too degenerate for exact hard placements: fill with generic lights.
            let p = [0, 1, 2].map(|k| (c[k] + (rng.unit() - 0.5) * 6.0 * size) as f32);
            out.push([p[0], p[1], p[2], 1.0]);
        }
    }
    out
}

/// A light to verify under: in world space (moved into each mesh's record
/// space with [`crate::quantize::RecordSpace::light_to_record`], as a renderer
/// does), or already in record space (generated lights, whose hard placements
/// are exact only there). For f32 files the two spaces are the same.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum VerifyLight {
    /// World-space light.
    World(Light),
    /// Record-space light, used as is for every mesh.
    Record(Light),
}

impl From<Light> for VerifyLight {
    fn from(l: Light) -> Self {
        VerifyLight::World(l)
    }
}

impl VerifyLight {
    /// The light in `d`'s record space.
    pub fn in_record_space(self, d: &Decoded) -> Light {
        match self {
            VerifyLight::World(l) => d.space.light_to_record(l),
            VerifyLight::Record(l) => l,
        }
    }
}

/// Per-light line of a verify report.
#[derive(Debug, Clone, serde::Serialize)]
pub struct LightReport {
    /// The light (x, y, z, w), in the space `space` names.
    pub light: [f32; 4],
    /// "world", or "record" for a light given in record space.
    pub space: &'static str,
    /// Side records with m != 0.
    pub silhouette_instances: u64,
    /// Side quads drawn (sum of |m|).
    pub side_quads: u64,
    /// Triangles whose caps are drawn (c != 0).
    pub caps: u64,
    /// Unbalanced edges of the emitted surface.
    pub closedness_violations: u64,
    /// Sample points compared with the exact shadow truth.
    pub samples: u64,
    /// Sample points exactly on a volume face, or within the f32 rounding of
    /// a side quad's extrusion to infinity (a wedge that is wide only for a
    /// point light nearly on the edge's line; see
    /// [`crate::shadow::check_shadow`]): reported, not compared.
    pub samples_on_faces: u64,
    /// Samples whose volume winding number differs from the exact count of
    /// triangles between them and the light.
    pub sample_mismatches: u64,
    /// Triangles whose f32 orientation (the contract's) differs from the exact
    /// one: where f32 precision runs out (a light within rounding distance of
    /// a triangle's plane). Informational: it explains shadow mismatches but
    /// is not itself a failure, since the volume stays closed.
    pub orientation_errors: u64,
    /// Wall time for this light in milliseconds.
    pub time_ms: f64,
}

/// Counts caps whose evaluated orientation differs from the exact orientation
/// of the triangle towards the light.
///
/// For a point light, the f64 evaluation of the determinant decides the
/// sign whenever it clears Shewchuk's error bound (`orient3d_filtered` in
/// [`crate::exact`]), which is almost always; only the rest go to the exact
/// [`crate::exact::det4_sign`]. Why: calling the exact predicate for each
/// of the dragon's 871k triangles and 16 lights was 13% of `verify`'s
/// profile samples.
///
/// The triangles are taken in the evaluation's order with their corners
/// sorted ([`OrderedEvaluation`]'s caps), whose position rows follow that
/// order, rather than in input order, where each corner is a read anywhere
/// in the position table (larger than L2); an odd sort flips the exact
/// sign. The dragon, one thread, 16 lights: 115–124 → 88–109 ms (local
/// timers, benches/ROUNDS.md, Forty-second round).
pub fn orientation_errors(d: &Decoded, light: Light, ev: &Evaluation) -> u64 {
    let l = light.map(|v| v as f64);
    if let Some(o) = &d.ordered {
        // Whole blocks in lanes for a light with `w` 0 or 1 (every light
        // `verify` makes), the rest one at a time.
        let whole = o.order().len() / LANES * LANES;
        let (blocks, rest) = if l[3] == 1.0 {
            (orientation_blocks::<true>(o, l, ev), whole)
        } else if l[3] == 0.0 {
            (orientation_blocks::<false>(o, l, ev), whole)
        } else {
            (0, 0)
        };
        return blocks + ordered_orientation_errors(o, l, ev, rest);
    }
    // The corners of the triangle AHEAD on are prefetched: the caps are in
    // input order, scattered over a position table larger than L2.
    const AHEAD: usize = 16;
    let ahead = d.caps.get(AHEAD..).unwrap_or(&[]);
    d.caps
        .iter()
        .zip(&ev.caps)
        .enumerate()
        .filter(|(i, (t, c))| {
            if let Some(f) = ahead.get(*i) {
                for &v in f {
                    if let Some(q) = d.positions.get(v as usize) {
                        crate::hint::prefetch(q);
                    }
                }
            }
            exact_orientation(t.map(|i| &d.positions[i as usize]), l) != **c as i32
        })
        .count() as u64
}

/// The orientation errors of the ordered caps from evaluation number
/// `first` on, one triangle at a time.
fn ordered_orientation_errors(
    o: &OrderedEvaluation,
    l: [f64; 4],
    ev: &Evaluation,
    first: usize,
) -> u64 {
    let caps = o.caps();
    let order = o.order();
    (first..order.len())
        .filter(|&r| {
            // The sign of the triangle 32 on: input order is far from this
            // order.
            if let Some(&u) = order.get(r + 32) {
                crate::hint::prefetch(&ev.caps[u as usize]);
            }
            let (p, odd) = caps.sorted_corners(r);
            let exact = exact_orientation(p, l);
            let exact = if odd { -exact } else { exact };
            exact != ev.caps[order[r] as usize] as i32
        })
        .count() as u64
}

/// The orientation errors of the ordered caps in whole blocks of
/// [`LANES`] (those before `order().len() / LANES * LANES`), for a point
/// light (`POINT`, `l[3] == 1`) or a directional one (`l[3] == 0`): each
/// block's corners gathered into lanes, filtered in vectors
/// ([`filtered_lanes`]), and only the undecided lanes through
/// [`exact_orientation`]. One triangle at a time, the dragon's 16 lights
/// took 83.9–84.7 ms here, in blocks 69.2–71.5 (one thread, local timers,
/// benches/ROUNDS.md, Forty-fourth round).
fn orientation_blocks<const POINT: bool>(
    o: &OrderedEvaluation,
    l: [f64; 4],
    ev: &Evaluation,
) -> u64 {
    #[cfg(target_arch = "x86_64")]
    if crate::evaluate_simd::have_avx2() {
        // SAFETY: the CPU has AVX2.
        return unsafe { orientation_blocks_avx2::<POINT>(o, l, ev) };
    }
    // SAFETY: without AVX2 the corners are copied element by element.
    unsafe { orientation_blocks_impl::<false, POINT>(o, l, ev) }
}

/// [`orientation_blocks_impl`] compiled with AVX2.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn orientation_blocks_avx2<const POINT: bool>(
    o: &OrderedEvaluation,
    l: [f64; 4],
    ev: &Evaluation,
) -> u64 {
    // SAFETY: the caller's.
    unsafe { orientation_blocks_impl::<true, POINT>(o, l, ev) }
}

/// The loop of [`orientation_blocks`].
///
/// # Safety
/// With `AVX2`, the CPU must have AVX2.
#[inline(always)]
unsafe fn orientation_blocks_impl<const AVX2: bool, const POINT: bool>(
    o: &OrderedEvaluation,
    l: [f64; 4],
    ev: &Evaluation,
) -> u64 {
    let caps = o.caps();
    let order = o.order();
    let mut errors = 0;
    let mut p = [[[0f32; LANES]; 3]; 3];
    for first in (0..order.len() / LANES).map(|b| b * LANES) {
        // SAFETY: the caller's.
        unsafe { caps.sorted_corner_lanes::<AVX2>(first, &mut p) };
        let fast = filtered_lanes::<POINT>(&p, l);
        for (r, s) in (first..).zip(fast) {
            // The sign of the triangle 32 on: input order is far from this
            // order.
            if let Some(&u) = order.get(r + 32) {
                crate::hint::prefetch(&ev.caps[u as usize]);
            }
            let s = if s != 0 {
                s
            } else {
                exact_orientation(caps.sorted_corners(r).0, l)
            };
            let s = if caps.odd(r) { -s } else { s };
            errors += u64::from(s != ev.caps[order[r] as usize] as i32);
        }
    }
    errors
}

/// [`exact_orientation`]'s f64 filter on [`LANES`] triangles given as
/// lanes of their corners (`p[c][a][i]`), for a point light (`POINT`) or a
/// directional one: per lane its answer, or 0 when the filter cannot tell.
/// A fixed-count loop over a straight-line body, which LLVM vectorises;
/// every lane evaluates the same expression as the scalar filter.
#[inline(always)]
fn filtered_lanes<const POINT: bool>(p: &[Corner; 3], l: [f64; 4]) -> [i32; LANES] {
    let l3 = [l[0], l[1], l[2]];
    let mut out = [0; LANES];
    for (i, o) in out.iter_mut().enumerate() {
        let c = |q: &Corner| [q[0][i] as f64, q[1][i] as f64, q[2][i] as f64];
        let t3 = [c(&p[0]), c(&p[1]), c(&p[2])];
        let fast = if POINT {
            crate::exact::orient3d_filtered(t3, l3)
        } else {
            crate::exact::directional_filtered(t3, l3)
        };
        // The sign of det[P0; P1; P2; L] negated, as `exact_orientation`.
        *o = -fast.unwrap_or(0);
    }
    out
}

/// The exact sign of `det[P0; P1; P2; L]` negated (the contract's cap
/// sign when f32 does not round it wrong), for the corners `p` and the
/// homogeneous light `l` (f32 values): the f64 filters first, the exact
/// predicate when they cannot tell. The corners come as references to
/// their rows: copied into arrays, they went through the stack and were
/// read back by loads wider than their stores, which the CPU cannot
/// forward (the dragon's 16 lights took 174–183 against 88–109 ms in
/// evaluation order, local timers).
#[inline(always)]
fn exact_orientation(p: [&[f32; 3]; 3], l: [f64; 4]) -> i32 {
    let f = |q: &[f32; 3]| [q[0] as f64, q[1] as f64, q[2] as f64];
    let t3 = [f(p[0]), f(p[1]), f(p[2])];
    let l3 = [l[0], l[1], l[2]];
    let fast = if l[3] == 1.0 {
        crate::exact::orient3d_filtered(t3, l3)
    } else if l[3] == 0.0 {
        crate::exact::directional_filtered(t3, l3)
    } else {
        None
    };
    // det[P0; P1; P2; L] = −N·(L − P0·w): negative when L sees (P0, P1,
    // P2) counter-clockwise. With every w = 1 it is orient3d(P0, P1, P2,
    // L) (`det4_sign`).
    -fast.unwrap_or_else(|| {
        let h = |q: [f64; 3]| [q[0], q[1], q[2], 1.0];
        crate::exact::det4_sign([h(t3[0]), h(t3[1]), h(t3[2]), l])
    })
}

/// Whole verify report (`svpack verify --json`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct VerifyReport {
    /// True when every check holds.
    pub ok: bool,
    /// Meshes checked.
    pub meshes: u64,
    /// Triangles (caps records).
    pub triangles: u64,
    /// Side records.
    pub edge_instances: u64,
    /// Structure: unmatched (triangle, edge) / (record, slot) pairs.
    pub bijection_errors: u64,
    /// Structure: records with bad order or `.w` values, and non-finite caps
    /// positions.
    pub record_errors: u64,
    /// First structural problem, in words.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_problem: Option<String>,
    /// Closedness violations summed over lights and meshes.
    pub closedness_violations: u64,
    /// Samples compared, summed over lights.
    pub samples: u64,
    /// Samples on volume faces (exactly or within extrusion rounding),
    /// summed over lights.
    pub samples_on_faces: u64,
    /// Shadow-truth mismatches, summed over lights.
    pub sample_mismatches: u64,
    /// First mismatch, in words.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_mismatch: Option<String>,
    /// Orientation errors (f32 against exact), summed over lights.
    pub orientation_errors: u64,
    /// Lights with any violation or mismatch.
    pub failing_lights: u64,
    /// Per light (summed over meshes).
    pub lights: Vec<LightReport>,
    /// Total wall time in milliseconds.
    pub time_ms: f64,
}

/// Runs checks 1, 2 and 3 on every mesh of `file` for every light, evaluating
/// the volumes with `strategy` (the format's is [`Strategy::Reference`]);
/// check 3 uses `samples` points per mesh (0 skips it).
pub fn verify<L: Copy + Into<VerifyLight> + Sync>(
    file: &SvpkFile,
    lights: &[L],
    strategy: Strategy,
    samples: usize,
) -> VerifyReport {
    verify_with(file, lights, strategy, samples, &|| {})
}

/// [`verify`], calling `light_done` after each light (for progress display;
/// lights run in parallel, so from any worker thread).
pub fn verify_with<L: Copy + Into<VerifyLight> + Sync>(
    file: &SvpkFile,
    lights: &[L],
    strategy: Strategy,
    samples: usize,
    light_done: &(dyn Fn() + Sync),
) -> VerifyReport {
    let start = std::time::Instant::now();
    let mut rep = verify_decoded(&decode_all(file), lights, strategy, samples, light_done);
    rep.time_ms = start.elapsed().as_secs_f64() * 1e3;
    rep
}

/// Every mesh of `file` decoded ([`decode`]), in order.
pub fn decode_all(file: &SvpkFile) -> Vec<Decoded> {
    (0..file.header.meshes.len())
        .map(|i| decode(file, i))
        .collect()
}

/// [`verify_with`] on meshes already decoded ([`decode_all`]): a caller
/// that also needs them (to choose lights) decodes once. `time_ms` covers
/// this call only.
pub fn verify_decoded<L: Copy + Into<VerifyLight> + Sync>(
    decoded: &[Decoded],
    lights: &[L],
    strategy: Strategy,
    samples: usize,
    light_done: &(dyn Fn() + Sync),
) -> VerifyReport {
    let start = std::time::Instant::now();
    let mut rep = VerifyReport {
        ok: true,
        meshes: decoded.len() as u64,
        triangles: decoded.iter().map(|d| d.caps.len() as u64).sum(),
        edge_instances: decoded
            .iter()
            .flat_map(|d| d.buckets.iter().map(|b| b.records() as u64))
            .sum(),
        bijection_errors: 0,
        record_errors: 0,
        first_problem: None,
        closedness_violations: 0,
        samples: 0,
        samples_on_faces: 0,
        sample_mismatches: 0,
        first_mismatch: None,
        orientation_errors: 0,
        failing_lights: 0,
        lights: Vec::new(),
        time_ms: 0.0,
    };
    // Check 1, the pair numbering of check 2 and the shadow-truth index
    // (only needed when samples are asked for), side by side: independent,
    // and each mostly one thread's work.
    //
    // A mesh with a non-finite position (a damaged file; check 1 counts
    // them) gets no shadow samples and no orientation check: the exact
    // predicates those run need finite values.
    let finite: Vec<bool> = decoded
        .iter()
        .map(|d| d.positions.iter().flatten().all(|v| v.is_finite()))
        .collect();
    let ((structures, closedness), indexes) = rayon::join(
        || {
            rayon::join(
                || decoded.iter().map(check_structure).collect::<Vec<_>>(),
                || decoded.iter().map(ClosednessIndex::new).collect::<Vec<_>>(),
            )
        },
        || {
            decoded
                .iter()
                .zip(&finite)
                .map(|(d, &f)| (samples > 0 && f).then(|| crate::shadow::ShadowIndex::new(d)))
                .collect::<Vec<_>>()
        },
    );
    for s in structures {
        rep.bijection_errors += s.bijection_errors;
        rep.record_errors += s.record_errors;
        if rep.first_problem.is_none() {
            rep.first_problem = s.first_problem;
        }
    }
    let meshes: Vec<MeshChecks> = decoded
        .iter()
        .zip(finite)
        .zip(closedness.into_iter().zip(indexes))
        .map(|((d, finite), (closedness, index))| MeshChecks {
            finite,
            closedness,
            points: if finite {
                crate::shadow::choose_samples(d, samples, 1)
            } else {
                Vec::new()
            },
            index,
        })
        .collect();
    // Lights run in parallel, each on one worker (the evaluator's own
    // parallel loops then mostly stay on that worker); their reports are
    // collected in light order, so the totals and the first mismatch are
    // those of a sequential run. Each worker takes a set of output and
    // scratch buffers (one per file) from `spare` and returns it, so they
    // are reused across lights instead of faulting in fresh pages.
    let spare: std::sync::Mutex<Vec<Vec<(Evaluation, ClosednessScratch)>>> = Default::default();
    let per_light: Vec<(LightReport, Option<String>)> = lights
        .par_iter()
        .map(|&given| {
            let mut evs = spare
                .lock()
                .expect("no panics while held")
                .pop()
                .unwrap_or_else(|| decoded.iter().map(|_| Default::default()).collect());
            let out = check_light(decoded, &meshes, &mut evs, given.into(), strategy);
            spare.lock().expect("no panics while held").push(evs);
            light_done();
            out
        })
        .collect();
    for (lr, first_mismatch) in per_light {
        rep.closedness_violations += lr.closedness_violations;
        rep.samples += lr.samples;
        rep.samples_on_faces += lr.samples_on_faces;
        rep.sample_mismatches += lr.sample_mismatches;
        rep.orientation_errors += lr.orientation_errors;
        rep.failing_lights += (lr.closedness_violations > 0 || lr.sample_mismatches > 0) as u64;
        if rep.first_mismatch.is_none() {
            rep.first_mismatch = first_mismatch;
        }
        rep.lights.push(lr);
    }
    rep.ok = rep.bijection_errors == 0
        && rep.record_errors == 0
        && rep.closedness_violations == 0
        && rep.sample_mismatches == 0;
    rep.time_ms = start.elapsed().as_secs_f64() * 1e3;
    rep
}

/// What [`verify_decoded`] prepares once per mesh for the per-light checks.
struct MeshChecks {
    /// Every position is finite (else no orientation or shadow check).
    finite: bool,
    /// Check 2's pair numbering.
    closedness: ClosednessIndex,
    /// The shadow check's samples (none when not finite).
    points: Vec<[f32; 3]>,
    /// The shadow check's index, when samples are asked for.
    index: Option<crate::shadow::ShadowIndex>,
}

/// Checks 2 and 3 of one light on every file: its report and its first
/// shadow mismatch, in words.
fn check_light(
    decoded: &[Decoded],
    meshes: &[MeshChecks],
    evs: &mut [(Evaluation, ClosednessScratch)],
    given: VerifyLight,
    strategy: Strategy,
) -> (LightReport, Option<String>) {
    let t = std::time::Instant::now();
    let (light, space) = match given {
        VerifyLight::World(l) => (l, "world"),
        VerifyLight::Record(l) => (l, "record"),
    };
    let mut lr = LightReport {
        light,
        space,
        silhouette_instances: 0,
        side_quads: 0,
        caps: 0,
        closedness_violations: 0,
        samples: 0,
        samples_on_faces: 0,
        sample_mismatches: 0,
        orientation_errors: 0,
        time_ms: 0.0,
    };
    let mut first_mismatch = None;
    for ((d, m), (ev, scratch)) in decoded.iter().zip(meshes).zip(evs) {
        let light = given.in_record_space(d);
        evaluate_into(d, light, strategy, ev);
        let c = check_closedness_indexed(d, &m.closedness, light, ev, scratch);
        if m.finite {
            lr.orientation_errors += orientation_errors(d, light, ev);
        }
        if let Some(index) = &m.index {
            let sh = crate::shadow::check_shadow(d, index, light, ev, &m.points);
            lr.samples += sh.samples;
            lr.samples_on_faces += sh.on_faces;
            lr.sample_mismatches += sh.mismatches;
            if first_mismatch.is_none() {
                first_mismatch = sh.first_mismatch.map(|m| {
                    format!(
                        "light ({}, {}, {}, {}): {m}",
                        light[0], light[1], light[2], light[3]
                    )
                });
            }
        }
        lr.silhouette_instances += c.silhouette_instances;
        lr.side_quads += c.side_quads;
        lr.caps += c.caps;
        lr.closedness_violations += c.violations;
    }
    lr.time_ms = t.elapsed().as_secs_f64() * 1e3;
    (lr, first_mismatch)
}

/// Parses `x,y,z,w` (w must be 0 or 1) into a light.
pub fn parse_light(s: &str) -> Result<Light, String> {
    let v: Vec<&str> = s.split(',').map(str::trim).collect();
    if v.len() != 4 {
        return Err(format!("light `{s}`: expected x,y,z,w"));
    }
    let mut l = [0f32; 4];
    for (k, t) in v.iter().enumerate() {
        l[k] = t
            .parse::<f32>()
            .map_err(|e| format!("light `{s}`: `{t}`: {e}"))?;
        if !l[k].is_finite() {
            return Err(format!("light `{s}`: `{t}` is not finite"));
        }
    }
    if l[3] != 0.0 && l[3] != 1.0 {
        return Err(format!(
            "light `{s}`: w must be 1 (point) or 0 (directional)"
        ));
    }
    if l[3] == 0.0 && l[..3] == [0.0; 3] {
        return Err(format!(
            "light `{s}`: a directional light needs a nonzero direction"
        ));
    }
    // -0.0 and +0.0 are the same light; keep the file's convention.
    Ok(l.map(|v| if v == 0.0 { 0.0 } else { v }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The orientation check's blocks give the counts of the one-at-a-time
    /// loop with either copy of the corners into lanes (the element-by-element
    /// one, which this CPU would not otherwise run, and the AVX2 one), on
    /// the hard cases under their own lights (on and next to triangle
    /// planes, where the filter cannot tell) and with signs flipped or
    /// zeroed. Caught: an exact answer left out for the undecided lanes.
    #[test]
    fn orientation_blocks_count_what_the_scalar_loop_counts() {
        let tmp = tempfile::tempdir().unwrap();
        let (input, output) = (tmp.path().join("m.obj"), tmp.path().join("m.svpk"));
        let (mut checked, mut errors, mut undecided) = (0, 0, 0);
        for case in crate::hardcases::cases() {
            std::fs::write(&input, crate::hardcases::obj(&case.v, &case.f)).unwrap();
            crate::build::build_file(&input, &output, &Default::default()).unwrap();
            let d = decode(&crate::format::read_file(&output).unwrap(), 0);
            let Some(o) = &d.ordered else { continue };
            let finite = d.positions.iter().flatten().all(|v| v.is_finite());
            if !finite || o.order().len() < LANES {
                continue;
            }
            let whole = o.order().len() / LANES * LANES;
            for (n, &light) in case.lights.iter().enumerate() {
                let l = light.map(|v| v as f64);
                let mut ev = evaluate(&d, light, Strategy::Reference);
                for (i, c) in ev.caps.iter_mut().enumerate() {
                    match (i * 7 + n) % 13 {
                        0 => *c = -*c,
                        1 => *c = 0,
                        _ => {}
                    }
                }
                let want = ordered_orientation_errors(o, l, &ev, 0);
                let rest = ordered_orientation_errors(o, l, &ev, whole);
                let caps = o.caps();
                // SAFETY: without AVX2 the copy is element by element.
                let (plain, undecided_here) = if l[3] == 1.0 {
                    let p = unsafe { orientation_blocks_impl::<false, true>(o, l, &ev) };
                    (p, count_undecided::<true>(caps, whole, l))
                } else {
                    let p = unsafe { orientation_blocks_impl::<false, false>(o, l, &ev) };
                    (p, count_undecided::<false>(caps, whole, l))
                };
                assert_eq!(plain + rest, want, "{} light {n}", case.name);
                assert_eq!(orientation_errors(&d, light, &ev), want, "{}", case.name);
                checked += whole;
                errors += want;
                undecided += undecided_here;
            }
        }
        assert!(checked > 1000 && errors > 100, "{checked} {errors}");
        assert!(undecided > 10, "{undecided}");
    }

    /// `sort_few_runs` sorts as a sort does: lists of one to nine runs
    /// ascending in their first field, of any lengths (some empty, some of
    /// one item, the longest anywhere), some with many equal first fields
    /// (the second field then breaks them into more runs), and lists in
    /// random order. Caught: the run's items moved one place short, and a
    /// search that skipped the run's first item.
    #[test]
    fn sort_few_runs_sorts() {
        let mut rng = Rng::new(5);
        let mut below = |n: usize| (rng.unit() * n as f64) as usize;
        for trial in 0..3000 {
            let mut v: Vec<(u32, u32)> = Vec::new();
            let runs = 1 + trial % 9;
            for _ in 0..runs {
                let len = [0, 1, 2, 5, 40, 300][below(6)];
                let mut run: Vec<(u32, u32)> = (0..len)
                    .map(|_| (below(if trial % 4 == 0 { 4 } else { 1000 }) as u32, 0))
                    .collect();
                run.sort_unstable();
                v.extend(run);
            }
            if trial % 10 == 0 {
                for i in (1..v.len()).rev() {
                    v.swap(i, below(i + 1));
                }
            }
            // Distinct items that compare equal on the first field alone
            // still sort as wholes.
            for (i, x) in v.iter_mut().enumerate() {
                x.1 = (i % 3) as u32;
            }
            let mut want = v.clone();
            want.sort_unstable();
            sort_few_runs(&mut v);
            assert!(v == want, "trial {trial}");
        }
    }

    /// Lanes the filter leaves undecided in the first `whole` caps.
    fn count_undecided<const POINT: bool>(
        caps: &crate::evaluate_indexed::IndexedCaps,
        whole: usize,
        l: [f64; 4],
    ) -> usize {
        let mut p = [[[0f32; LANES]; 3]; 3];
        (0..whole / LANES)
            .map(|b| {
                // SAFETY: without AVX2 the copy is element by element.
                unsafe { caps.sorted_corner_lanes::<false>(b * LANES, &mut p) };
                filtered_lanes::<POINT>(&p, l)
                    .iter()
                    .filter(|&&s| s == 0)
                    .count()
            })
            .sum()
    }
}
