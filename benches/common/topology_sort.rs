//! The topology method svpack used before the vertex-listing one in
//! `src/topology.rs`: a two-level counting sort of the 3·T half-edges as
//! 16-byte records (partitions of 2048 smaller endpoints, then an in-cache
//! sort per partition). Kept only as the stages bench's baseline
//! (`topology/previous_sort/*`), so the speed-up stays measurable; it gives
//! the same `Edges`, which the bench asserts.

use svpack::topology::Edges;

/// Builds the edge structure of `triangles` (3 vertex ids each, no repeated
/// id within a triangle) over `vertex_count` vertices.
///
/// Method (a cache-conscious counting sort of the 3·T half-edges by their
/// smaller endpoint, then by the larger one):
///
/// 1. Half-edges are scattered into *partitions* of [`PART`] consecutive
///    smaller endpoints. One scatter straight to each vertex's slot would
///    touch a random cache line per half-edge; a few hundred partition write
///    streams stay in cache, and each partition's records then fit in L2.
///    Triangles are cut into fixed blocks counted first, so every (block,
///    partition) pair owns a precomputed output range: the blocks scatter in
///    parallel and the records of each partition stay in triangle order.
/// 2. Each partition (in parallel) is counting-sorted by smaller endpoint,
///    each vertex's few records insertion-sorted by larger endpoint (both
///    stable, so an edge's opposite vertices stay in triangle order), and its
///    edges counted.
/// 3. After a prefix sum over the partitions' edge counts, each partition
///    writes its edges into its own range of the output.
///
/// The result does not depend on the number of threads.
pub fn build_edges(triangles: &[u32], vertex_count: usize) -> Edges {
    use rayon::prelude::*;
    let half_edges = triangles.len();
    let parts = vertex_count.div_ceil(PART);
    let blocks: Vec<&[u32]> = triangles.chunks(3 * TRI_BLOCK).collect();
    let part_of = |v: u32| (v >> PART_SHIFT) as usize;

    // Pass 1: half-edges per (block, partition).
    let block_counts: Vec<Vec<u32>> = blocks
        .par_iter()
        .map(|tris| {
            let mut c = vec![0u32; parts];
            for t in tris.chunks_exact(3) {
                c[part_of(t[0].min(t[1]))] += 1;
                c[part_of(t[1].min(t[2]))] += 1;
                c[part_of(t[2].min(t[0]))] += 1;
            }
            c
        })
        .collect();
    // Partition-major, then block order: each partition's records come out
    // in triangle order.
    let mut part_start = vec![0usize; parts + 1];
    let mut block_at = vec![vec![0usize; parts]; blocks.len()];
    let mut at = 0;
    for p in 0..parts {
        part_start[p] = at;
        for (b, counts) in block_counts.iter().enumerate() {
            block_at[b][p] = at;
            at += counts[p] as usize;
        }
    }
    part_start[parts] = at;
    drop(block_counts);

    // Pass 2: scatter [smaller, larger, opposite, triangle] records.
    let mut recs: Vec<[u32; 4]> = vec![[0; 4]; half_edges];
    struct Out(*mut [u32; 4]);
    // SAFETY: shared only to write disjoint ranges, see below.
    unsafe impl Sync for Out {}
    let out = Out(recs.as_mut_ptr());
    blocks
        .par_iter()
        .zip(block_at.par_iter_mut())
        .enumerate()
        .for_each(|(blk, (tris, at))| {
            let out = &out;
            for (i, t) in tris.chunks_exact(3).enumerate() {
                let tri = (blk * TRI_BLOCK + i) as u32;
                for k in 0..3 {
                    let (u, v, w) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                    let (lo, hi) = if u < v { (u, v) } else { (v, u) };
                    let slot = &mut at[part_of(lo)];
                    // SAFETY: block `blk` writes partition p's records at
                    // block_at[blk][p] .. + its count of them, which pass 1
                    // counted exactly; these ranges are disjoint across all
                    // (block, partition) pairs and lie inside `recs`.
                    unsafe { out.0.add(*slot).write([lo, hi, w, tri]) };
                    *slot += 1;
                }
            }
        });
    drop(block_at);

    // Pass 3: sort each partition by (smaller, larger), stably, and write
    // its opposite vertices and triangles straight into their final place
    // (the partition's records keep their range: `opp` has one entry per
    // half-edge, in the same order). Only the edges themselves wait for the
    // prefix sum of the partitions' edge counts; each partition keeps them
    // in a small list meanwhile.
    let mut opp = vec![0u32; half_edges];
    let mut opp_tri = vec![0u32; half_edges];
    let mut jobs = Vec::with_capacity(parts);
    {
        let mut rest: &[[u32; 4]] = &recs;
        let (mut ro, mut rt) = (&mut opp[..], &mut opp_tri[..]);
        for p in 0..parts {
            let m = part_start[p + 1] - part_start[p];
            let (mine, tail) = rest.split_at(m);
            let (o1, o2) = ro.split_at_mut(m);
            let (t1, t2) = rt.split_at_mut(m);
            jobs.push((mine, o1, t1));
            (rest, ro, rt) = (tail, o2, t2);
        }
    }
    let part_edges: Vec<Vec<[u32; 3]>> = jobs
        .into_par_iter()
        .enumerate()
        .map_init(
            || (Vec::new(), Vec::new(), Vec::new(), Vec::new()),
            |(start, scratch, sorted, ends): &mut Bufs, (p, (recs, oo, ot))| {
                sort_partition(recs, (p * PART) as u32, start, scratch, sorted);
                let sorted = &sorted[..recs.len()];
                // Every record writes an edge slot; only the last record of
                // each (smaller, larger) run advances past it (no branch: it
                // would mispredict on about every other record). Its range
                // ends here, a global position in `opp`.
                if ends.len() < sorted.len() {
                    ends.resize(sorted.len(), [0; 3]);
                }
                let base = part_start[p] as u32;
                let mut e = 0;
                for (i, r) in sorted.iter().enumerate() {
                    oo[i] = r[2];
                    ot[i] = r[3];
                    let last = sorted
                        .get(i + 1)
                        .is_none_or(|n| (n[0] != r[0]) | (n[1] != r[1]));
                    ends[e] = [r[0], r[1], base + i as u32 + 1];
                    e += usize::from(last);
                }
                ends[..e].to_vec()
            },
        )
        .collect();
    drop(recs);

    // Pass 4: the partitions' edges, concatenated in partition order.
    let edge_total: usize = part_edges.iter().map(Vec::len).sum();
    let mut edges = Edges {
        a: vec![0; edge_total],
        b: vec![0; edge_total],
        opp_start: vec![0; edge_total + 1],
        opp,
        opp_tri,
    };
    let mut outs = Vec::with_capacity(parts);
    {
        let (mut ra, mut rb) = (&mut edges.a[..], &mut edges.b[..]);
        let mut rs = &mut edges.opp_start[1..];
        for list in &part_edges {
            let (a1, a2) = ra.split_at_mut(list.len());
            let (b1, b2) = rb.split_at_mut(list.len());
            let (s1, s2) = rs.split_at_mut(list.len());
            outs.push((a1, b1, s1));
            (ra, rb, rs) = (a2, b2, s2);
        }
    }
    outs.into_par_iter()
        .zip(part_edges.par_iter())
        .for_each(|((oa, ob, os), list)| {
            for (i, e) in list.iter().enumerate() {
                oa[i] = e[0];
                ob[i] = e[1];
                os[i] = e[2];
            }
        });
    edges
}

/// Per-thread buffers of pass 3: counting-sort offsets, the records by
/// smaller endpoint, the records fully sorted, the partition's edges.
type Bufs = (Vec<u32>, Vec<[u32; 4]>, Vec<[u32; 4]>, Vec<[u32; 3]>);

/// Sorts one partition's records (smaller endpoints `base .. base + PART`)
/// by (smaller, larger) endpoint, stably, into `sorted` (its first
/// `recs.len()` entries). `start`, `scratch` and `sorted` are reusable
/// buffers.
fn sort_partition(
    recs: &[[u32; 4]],
    base: u32,
    start: &mut Vec<u32>,
    scratch: &mut Vec<[u32; 4]>,
    sorted: &mut Vec<[u32; 4]>,
) {
    // Counting sort by smaller endpoint into `scratch` (stable).
    start.clear();
    start.resize(PART + 1, 0);
    for r in recs.iter() {
        start[(r[0] - base) as usize + 1] += 1;
    }
    for v in 0..PART {
        start[v + 1] += start[v];
    }
    // Both buffers are read and written SMALL_RUN records past the last
    // run (see below). Every entry is written before it is read, so they
    // only grow, never refill (zeroing 200 KB per partition showed).
    let len = recs.len() + SMALL_RUN;
    if scratch.len() < len {
        scratch.resize(len, [0; 4]);
        sorted.resize(len, [0; 4]);
    }
    {
        let mut fill = [0u32; PART];
        fill.copy_from_slice(&start[..PART]);
        for r in recs.iter() {
            let slot = &mut fill[(r[0] - base) as usize];
            scratch[*slot as usize] = *r;
            *slot += 1;
        }
    }
    // Per smaller endpoint, order the records by larger endpoint, keeping
    // triangle order among equal ones. The runs are the vertex valence, a
    // handful of records on real meshes, and their lengths vary: any loop
    // or copy over a run's own length mispredicts at its end, every run, so
    // runs of up to SMALL_RUN records are sorted as fixed blocks of
    // SMALL_RUN ([`rank_sort_block`]): the block is read whole (the records
    // past the run are ignored) and written whole into `sorted` at the run's
    // start; what lands past the run is overwritten by the next runs, which
    // start there, or lies in the padding. Longer runs (fans, dense CAD
    // vertices) use the standard library's unstable sort on (larger
    // endpoint, triangle), which gives the same order because a triangle has
    // at most one half-edge per vertex pair, so the keys are distinct.
    for v in 0..PART {
        let (s, e) = (start[v] as usize, start[v + 1] as usize);
        if e - s <= SMALL_RUN {
            let src: &[[u32; 4]; SMALL_RUN] = scratch[s..s + SMALL_RUN].try_into().unwrap();
            let dst: &mut [[u32; 4]; SMALL_RUN] =
                (&mut sorted[s..s + SMALL_RUN]).try_into().unwrap();
            rank_sort_block(src, e - s, dst);
        } else {
            let run = &mut scratch[s..e];
            run.sort_unstable_by_key(|r| (u64::from(r[1]) << 32) | u64::from(r[3]));
            sorted[s..e].copy_from_slice(run);
        }
    }
}

/// Longest run of records [`rank_sort_block`] sorts.
const SMALL_RUN: usize = 8;

/// Sorts the first `m` records of `src` by larger endpoint (`r[1]`),
/// stably, into the first `m` of `dst`, without data-dependent branches:
/// each record goes to its rank, the number of records with a smaller key or
/// an equal key and a smaller index. Records at `m` and beyond get the
/// largest key and so rank after every real one (larger key, or equal key
/// and larger index): the real ones take ranks `0..m`, the rest fill
/// `dst[m..]` with don't-cares, and the fixed-size loops unroll.
#[inline(always)]
fn rank_sort_block(src: &[[u32; 4]; SMALL_RUN], m: usize, dst: &mut [[u32; 4]; SMALL_RUN]) {
    let keys: [u32; SMALL_RUN] = std::array::from_fn(|i| if i < m { src[i][1] } else { u32::MAX });
    for i in 0..SMALL_RUN {
        let mut rank = 0;
        for (j, &k) in keys.iter().enumerate() {
            rank += usize::from((k < keys[i]) | ((k == keys[i]) & (j < i)));
        }
        // The ranks are a permutation of 0..SMALL_RUN; the mask only spares
        // the bounds check.
        dst[rank & (SMALL_RUN - 1)] = src[i];
    }
}

/// log2 of the vertices per partition: 2048 smaller endpoints carry about
/// 6 · 2048 half-edges of 16 bytes on a closed mesh, ~200 KB, which stays
/// in L2 while the partition is sorted.
const PART_SHIFT: u32 = 11;
/// Vertices per partition.
const PART: usize = 1 << PART_SHIFT;
/// Triangles per block of the counting and scatter passes.
const TRI_BLOCK: usize = 1 << 14;
