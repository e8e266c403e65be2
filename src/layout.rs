//! Layout: the WebGL 1 instancing buffers of the paper (Milet et al. 2015,
//! §2.6), bucketed by opposite-vertex count instead of padded to one maxMult.
//!
//! Sides, bucket k: one instance per edge (chunk), `2 + k` vec4 of f32:
//! `A.xyz, A.w = k` (opposite vertices used in this instance), `B.xyz,
//! B.w = n` (the edge's total opposite-vertex count before splitting),
//! `O_j.xyz, O_j.w = 1`. Every instance of bucket k uses all k slots, so there
//! is no padding anywhere.
//!
//! Caps: one instance per triangle, 3 vec4 `(P0, 1), (P1, 1), (P2, 1)` in
//! input winding.
//!
//! Splitting: an edge with n > K opposite vertices becomes ⌊n/K⌋ instances in
//! bucket K and, if n mod K > 0, one more in bucket n mod K, all with the same
//! A and B. Stencil counting is additive, so drawing the chunks separately
//! adds up to the edge's multiplicity.

use crate::format::PayloadSource;
use crate::hint::{prefetch_stream, prefetch_whole};
use crate::topology::{EdgeSlices, Edges, EmitFeed};
use crate::weld::Welded;

/// Largest `--max-mult` accepted: the sides shader needs 3 + K vertex
/// attributes and 16 is the most any WebGL 1 implementation we know exposes.
pub const MAX_MAX_MULT: u32 = 13;

/// Default `--max-mult`: 3 + 5 = 8 attributes, the minimum WebGL 1 guarantees
/// (`MAX_VERTEX_ATTRIBS >= 8`), so every file built with defaults draws on
/// every WebGL 1 device. See format-spec/README.md, "Choice of K".
pub const DEFAULT_MAX_MULT: u32 = 5;

/// One bucket of side instances.
#[derive(Debug, Clone, PartialEq)]
pub struct SideBucket {
    /// Opposite vertices per instance.
    pub k: u32,
    /// Number of instances.
    pub instances: u64,
    /// `instances · (2 + k) · 4` floats.
    pub data: Vec<f32>,
}

/// Sides and caps buffers of one mesh.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Layout {
    /// Caps: 12 floats per triangle.
    pub caps: Vec<f32>,
    /// Non-empty side buckets in increasing k.
    pub buckets: Vec<SideBucket>,
}

impl Layout {
    /// Total side instances.
    pub fn edge_instances(&self) -> u64 {
        self.buckets.iter().map(|b| b.instances).sum()
    }

    /// Bytes of all side buckets.
    pub fn sides_bytes(&self) -> u64 {
        self.buckets.iter().map(|b| b.data.len() as u64 * 4).sum()
    }

    /// Bytes of the caps section.
    pub fn caps_bytes(&self) -> u64 {
        self.caps.len() as u64 * 4
    }
}

/// Size of the paper's uniform layout, `16·(2 + maxMult)·e + 48·t`, with
/// maxMult the largest opposite count (no splitting).
pub fn paper_bytes(edges: u64, triangles: u64, max_fan: u32) -> u64 {
    16 * (2 + max_fan as u64) * edges + 48 * triangles
}

/// Payload bytes (caps and side buckets) a mesh of `triangles` triangles
/// over `vertices` positions is expected to take, in vec4 of `vec4_bytes`
/// bytes: 3 vec4 of caps a triangle, and for the sides one vec4 per record
/// (3 a triangle) and two (the edge's ends) per instance. The edges are
/// counted by Euler's formula as `vertices + triangles`, exact for a
/// closed mesh of genus 1 and 2 edges over for a sphere, and at most one
/// per record (every edge open, as for separate triangles, where the
/// figure is exact). Instances beyond one per edge (an edge with more
/// opposite vertices than `max_mult`) are not counted: they are rare. A
/// build reserves this much page cache for its output
/// (`alloc::PageCacheReservation`) once its input's triangles are loaded.
pub fn expected_payload_bytes(triangles: u64, vertices: u64, vec4_bytes: u64) -> u64 {
    let edges = vertices.saturating_add(triangles).min(3 * triangles);
    (6 * triangles + 2 * edges).saturating_mul(vec4_bytes)
}

/// Number of instances an edge with `n` opposite vertices adds to each bucket:
/// `(full chunks in bucket K, size of the remainder chunk or 0)`.
#[inline]
pub fn split(n: u32, max_mult: u32) -> (u32, u32) {
    // Nearly every edge has fewer opposite vertices than K: skip the integer
    // division (a divisor known only at run time costs tens of cycles, and
    // was a quarter of the layout's counting pass on the dragon).
    if n < max_mult {
        (0, n)
    } else {
        (n / max_mult, n % max_mult)
    }
}

/// Edges (or caps triangles) per block of the fill pass, which is also the
/// unit the writer fills and then copies into the file with one `pwrite`:
/// large enough that the per-block bookkeeping (one counter per bucket)
/// costs nothing, and that the copies take the page cache in large folios.
///
/// Why 32,768 and not 16,384 (until the fortieth round): a write that
/// starts mid-page gets its folios in a ramp of sizes (1, 2, 4, ... pages,
/// as the file offset's alignment allows) before the large ones, and every
/// unit's write starts such a ramp again. The dragon's output took 1,298
/// folios in 1 MiB writes, 671 in 2 MiB ones (`perf stat -e
/// filemap:mm_filemap_add_to_page_cache` on a one-thread build), and the
/// writes got faster: `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run --release
/// --example stage_probe -- fill-write target/dragon/dragon.glb`, the
/// writes alone 18.6–18.7 → 13.4–13.7 ms (65,536: 13.0–13.1 ms, with the
/// caps' fills slower), the fills unchanged (two alternations). Whole one-thread builds
/// (`python3 benches/compare_binaries.py OLD NEW FILE ROUNDS`): the
/// dragon 53.8 / 57.1 → 52.7 / 54.9 ms after parsing, fastest / median
/// (24 rounds), the 5M scene's write stage 128.7 / 131.5 → 120.7 / 122.7
/// ms (6 rounds). Two threads unchanged (32.6 / 33.7 against 32.5 / 33.8
/// ms): the caps go in faster, but the last block, copied after the last
/// edge is made, is twice as long. Units filled two to sixteen at a time
/// and written in one call had been slower in the fifteenth round, on the
/// earlier host and kernel (benches/ROUNDS.md).
pub const BLOCK: usize = 1 << 15;

/// Records ahead of the one being written whose corner positions are
/// prefetched: the position table is larger than L2 and an edge's or a
/// triangle's corners are scattered over it (1.5× faster on the dragon,
/// `layout/ours` in benches/stages.rs).
///
/// Why 64 and not 16: between the streamed writer's copies into the page
/// cache, which carry the whole output through the caches, the positions
/// come from memory rather than L2 or L3, and 16 records did not cover
/// that. The dragon's fills unit by unit with each unit written, one
/// thread, fastest of 6, three alternations: caps 4.6–6.8 → 4.2–4.4 ms
/// (`stage_probe -- fill-write`), sides 7.4–7.6 → 6.5–7.1 ms (16 against
/// 48 records; 48 and 64 did not differ); alone the caps also went 3.7–4.0
/// → 3.1–3.4 ms. Layout + write in the one-thread build: 39.8 / 41.2 →
/// 37.7 / 39.2 ms, fastest / median (`benches/compare_binaries.py`, 21
/// rounds); with two threads unchanged, the copy being that stage's length.
const AHEAD: usize = 64;

/// The layout's counting pass: how many instances each bucket gets, in
/// total and per fill block, so that every block knows where its records go
/// before any is written. [`layout`] fills buffers in memory from a plan;
/// `format::write_file_streamed` fills the file block by block from one,
/// without the buffers.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    max_mult: u32,
    triangles: usize,
    /// Instances per bucket `k` (index `k`, `0..=K`; bucket 0 is always empty).
    counts: Vec<u64>,
    /// `counts`, per block of [`BLOCK`] edges.
    block_counts: Vec<Vec<u64>>,
    /// Edges per opposite-vertex count (`fans[n]` edges with n).
    fans: Vec<u64>,
}

impl Plan {
    /// Counts the instances of every bucket, per block of edges.
    /// `max_mult` must be in `1..=MAX_MAX_MULT`.
    pub fn new(edges: &Edges, triangles: usize, max_mult: u32) -> Plan {
        use rayon::prelude::*;
        assert!(
            (1..=MAX_MAX_MULT).contains(&max_mult),
            "max_mult out of range"
        );
        let k_max = max_mult as usize;
        let blocks = edges.len().div_ceil(BLOCK);
        let (block_counts, hists): (Vec<Vec<u64>>, Vec<Vec<u64>>) = (0..blocks)
            .into_par_iter()
            .map(|blk| {
                // From the block's histogram of fans, whose common fans are
                // summed in vector lanes: counting each edge into its bucket
                // waited on the previous increment of the same counter,
                // through memory (2.9 ms on the dragon, against 0.4 ms).
                let end = ((blk + 1) * BLOCK).min(edges.len());
                let hist = crate::topology::fan_histogram(&edges.opp_start[blk * BLOCK..=end]);
                let mut counts = vec![0u64; k_max + 1];
                for (n, &c) in hist.iter().enumerate() {
                    let (full, rem) = split(n as u32, max_mult);
                    counts[k_max] += u64::from(full) * c;
                    if rem > 0 {
                        counts[rem as usize] += c;
                    }
                }
                (counts, hist)
            })
            .unzip();
        let mut counts = vec![0u64; k_max + 1];
        for c in &block_counts {
            for k in 0..=k_max {
                counts[k] += c[k];
            }
        }
        let mut fans = Vec::new();
        for h in &hists {
            crate::topology::add_histogram(&mut fans, h);
        }
        Plan {
            max_mult,
            triangles,
            counts,
            block_counts,
            fans,
        }
    }

    /// The statistics of the edges the plan was made from, from the fan
    /// histogram its counting pass made anyway. Why: a build needs both,
    /// and `topology::edge_stats` read all of `opp_start` again (0.6 ms of
    /// the dragon's build with one thread, local timers).
    pub fn edge_stats(&self) -> crate::topology::EdgeStats {
        crate::topology::EdgeStats::from_histogram(&self.fans)
    }

    /// The records of this plan for `welded` and `edges` (those it was made
    /// from), to be written by `format::write_file_streamed`.
    pub fn records<'a>(&'a self, welded: &'a Welded, edges: &'a Edges) -> Records<'a> {
        Records {
            plan: self,
            welded,
            edges,
            ks: self.buckets().map(|(k, _)| k).collect(),
        }
    }

    /// `(k, instances)` of the non-empty buckets, in increasing k.
    pub fn buckets(&self) -> impl Iterator<Item = (u32, u64)> + '_ {
        self.counts
            .iter()
            .enumerate()
            .filter(|&(_, &n)| n > 0)
            .map(|(k, &n)| (k as u32, n))
    }

    /// Total side instances.
    pub fn edge_instances(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Number of caps triangles (the welded mesh's kept triangles).
    pub fn triangles(&self) -> usize {
        self.triangles
    }

    /// Number of side fill blocks ([`BLOCK`] edges each).
    pub fn side_blocks(&self) -> usize {
        self.block_counts.len()
    }

    /// Number of caps fill blocks ([`BLOCK`] triangles each).
    pub fn cap_blocks(&self) -> usize {
        self.triangles.div_ceil(BLOCK)
    }

    /// Floats that side block `blk` writes into bucket `k`.
    pub fn side_block_floats(&self, blk: usize, k: u32) -> usize {
        let k = k as usize;
        self.block_counts[blk][k] as usize * (2 + k) * 4
    }

    /// Floats that caps block `blk` writes.
    pub fn cap_block_floats(&self, blk: usize) -> usize {
        cap_block_floats(self.triangles, blk)
    }

    /// Writes side block `blk`'s records: `outs[k]` receives bucket k's,
    /// exactly [`Plan::side_block_floats`]`(blk, k)` floats (`outs` has
    /// K + 1 entries, entry 0 unused).
    pub fn fill_sides(&self, welded: &Welded, edges: &Edges, blk: usize, outs: &mut [&mut [f32]]) {
        fill_sides(self.max_mult, welded, edges.slices(), blk, outs);
    }

    /// Writes caps block `blk`'s records into `out`
    /// ([`Plan::cap_block_floats`]`(blk)` floats).
    pub fn fill_caps(&self, welded: &Welded, blk: usize, out: &mut [f32]) {
        fill_caps(&welded.positions, &welded.triangles, blk, out);
    }
}

/// [`Plan::fill_sides`] for `max_mult` K, from `edges` as slices (all of
/// them, or a finished prefix that holds block `blk`).
///
/// One loop over the block's edges, reading the four edge arrays by index,
/// with the two-opposite case (almost every edge of a closed mesh) written
/// by [`put_rows`]. Until the thirty-eighth round this loop took each
/// edge's opposites as a slice, the pair by a slice pattern, and
/// prefetched both ends of each row through bounds-checked lookups; the
/// old loop without any position load took 9.3 of its 9.4 ms on the
/// dragon (a scratch probe): its cost was its control, not the table.
/// One thread, `RECYCLE=1 cargo run --release --example stage_probe --
/// build FILE` (fills into reused buffers, as the writer's), the binaries
/// of the round's base and of this loop alternated: the dragon's sides
/// 8.99–9.71 → 6.51–6.57 ms (three alternations), the 5M scene's
/// 53.3–54.3 → 40.3 ms (two).
///
/// Since the fifty-eighth round the edge arrays are read unchecked (their
/// lengths asserted once per block) and the outputs written through
/// their starts and lengths, k = 2's cursor in a local: the loop's k = 2
/// path had reloaded 15 values from the stack for each edge (bounds,
/// lengths and pointers the registers could not hold), 34 loads an edge
/// in all, and llvm-mca's Ice Lake model put it at 18.1 cycles an edge,
/// bound by the two load ports; now 10 reloads, 27 loads and 15.1 cycles
/// (`bash benches/kernel_mca.sh`, its fill row; the base's from
/// `python3 benches/kernel_mca.py` on a build of 14f05e0 with v0 symbol
/// names).
/// The dragon's sides, `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run --release
/// --example stage_probe -- fill-write target/dragon/dragon.glb` (its
/// lines with the caps from the soup, less the caps), eight alternations,
/// fastest / median: alone 7.96 / 16.31 → 6.79 / 13.83 ms, each unit
/// written 8.46 / 17.60 → 7.07 / 14.85 ms; the 5M scene's
/// (`target/targets/scene_5000000.obj`, four alternations, in a slow
/// phase of the host) alone 127.3 / 129.4 → 113.1 / 114.6 ms, written
/// 116.9 / 148.5 → 124.1 / 130.6 ms.
fn fill_sides(
    max_mult: u32,
    welded: &Welded,
    edges: EdgeSlices,
    blk: usize,
    outs: &mut [&mut [f32]],
) {
    let k_max = max_mult as usize;
    let pos = &welded.positions[..];
    let EdgeSlices {
        a,
        b,
        opp_start,
        opp,
    } = edges;
    let len = edges.len();
    let (first, end) = (blk * BLOCK, ((blk + 1) * BLOCK).min(len));
    if first >= end {
        return;
    }
    // Checked once here, so that the loop reads the edge arrays unchecked.
    assert!(
        b.len() >= len && opp_start.len() > len,
        "edge arrays of unequal length"
    );
    // (Clamped so that the prefetches' reads stay inside the arrays.)
    let last_pair = opp.len().saturating_sub(2);
    // An edge ending at most here has its pair in `opp` and takes the
    // k = 2 path; none does when records hold one opposite. One value
    // for both tests: every value the loop keeps beyond the registers is
    // a load per edge, and the loop is bound by its loads (benches/
    // ROUNDS.md, Fifty-eighth round).
    let pair_limit = if k_max >= 2 { opp.len() } else { 0 };
    // Each output's start and length, and how far it is written (the
    // records of k = 2, almost all of a closed mesh's, in a local).
    let mut sink: [(*mut f32, usize); MAX_MAX_MULT as usize + 1] =
        [(std::ptr::null_mut(), 0); MAX_MAX_MULT as usize + 1];
    for (s, o) in sink.iter_mut().zip(outs.iter_mut()) {
        *s = (o.as_mut_ptr(), o.len());
    }
    let mut at = [0usize; MAX_MAX_MULT as usize + 1];
    let mut at2 = 0;
    for e in first..end {
        // SAFETY (every `get_unchecked` below): `e < len` and `ahead <
        // len`, which index `a`, `b` and `opp_start` (asserted above), and
        // `e + 1 <= len` indexes `opp_start`; `s` and `s + 1` index `opp`
        // when `t <= pair_limit <= opp.len()` and `t == s + 2`, and the
        // prefetch's pair is clamped to `last_pair`.
        let ahead = (e + AHEAD).min(len - 1);
        // The rows of an edge `AHEAD` on: its B and its first two
        // opposites. One prefetch per row, not both ends of it (a row
        // straddles two lines once in eight), unlike the caps': in this
        // loop 6.98 → 6.14 ms on the dragon, 41.8 → 38.6 ms on the 5M
        // scene (the scratch probe); 32 edges ahead measured the same, 16
        // and 128 slower, no prefetch 54.3 ms on the 5M scene.
        unsafe {
            prefetch_row(pos, *b.get_unchecked(ahead));
            if pair_limit >= 2 {
                let s = (*opp_start.get_unchecked(ahead) as usize).min(last_pair);
                prefetch_row(pos, *opp.get_unchecked(s));
                prefetch_row(pos, *opp.get_unchecked(s + 1));
            }
        }
        let (s, t) = unsafe {
            (
                *opp_start.get_unchecked(e) as usize,
                *opp_start.get_unchecked(e + 1) as usize,
            )
        };
        let (ea, eb) = unsafe { (*a.get_unchecked(e), *b.get_unchecked(e)) };
        if t.wrapping_sub(s) == 2 && t <= pair_limit {
            // An edge of two triangles: one record of k = 2.
            let ids = unsafe { [ea, eb, *opp.get_unchecked(s), *opp.get_unchecked(s + 1)] };
            // SAFETY: output 2 is `sink[2]`, written from `at2` on.
            let out = unsafe { records(sink[2], at2, 16) };
            at2 += 16;
            put_rows::<4, false>(pos, ids, [2.0, 2.0, 1.0, 1.0], out);
            continue;
        }
        let (pa, pb) = (pos[ea as usize], pos[eb as usize]);
        let opp = &opp[s..t];
        let n = opp.len() as f32;
        for chunk in opp.chunks(k_max) {
            let k = chunk.len();
            let (cursor, n_floats) = (if k == 2 { at2 } else { at[k] }, (2 + k) * 4);
            // SAFETY: output k is `sink[k]`, written from its cursor on
            // (`at2` for k = 2, else `at[k]`), which moves past them.
            let out = unsafe { records(sink[k], cursor, n_floats) };
            if k == 2 {
                at2 += n_floats;
            } else {
                at[k] += n_floats;
            }
            out[..4].copy_from_slice(&[pa[0], pa[1], pa[2], k as f32]);
            out[4..8].copy_from_slice(&[pb[0], pb[1], pb[2], n]);
            for (slot, &o) in out[8..].chunks_exact_mut(4).zip(chunk) {
                let o = pos[o as usize];
                slot.copy_from_slice(&[o[0], o[1], o[2], 1.0]);
            }
        }
    }
}

/// Floats `at..at + n` of an output of [`fill_sides`] (its start and
/// length); panics past its end.
///
/// # Safety
/// `out` must be a live `&mut [f32]`'s start and length, not otherwise
/// used while the result is, and no two calls may hand out the same
/// floats (the caller moves `at` past them).
#[inline(always)]
unsafe fn records<'a>(out: (*mut f32, usize), at: usize, n: usize) -> &'a mut [f32] {
    let (ptr, len) = out;
    assert!(at + n <= len, "side records past their output");
    // SAFETY: floats `at..at + n` are inside the output (just checked)
    // and, by the caller's, handed out once.
    unsafe { std::slice::from_raw_parts_mut(ptr.add(at), n) }
}

/// Asks for the line of position `i` of `pos` (no bounds: a prefetch
/// never faults).
#[inline(always)]
fn prefetch_row(pos: &[[f32; 3]], i: u32) {
    crate::hint::prefetch_ptr(pos.as_ptr().wrapping_add(i as usize));
}

/// Writes rows `ids` of `pos` into `out` (4 floats each) with the given
/// `w`s: an edge of two opposite vertices' side record (`[A, B, O0, O1]`,
/// `w` = 2, 2, 1, 1) or a triangle's caps record (`w` = 1). With `CANON`,
/// each float becomes `weld::canonical`'s (`+ 0.0`: -0.0 becomes +0.0,
/// every other value stays itself), for rows read from the soup.
///
/// On x86-64, each row by one 16-byte load (its three floats and the next
/// row's first), its `w` put in by a mask and an or, and one 16-byte store:
/// a row's two loads and four stores become one and one. In the sides'
/// old loop alone this took the dragon's sides 9.4–10.1 → 8.2–8.5 ms and
/// the 5M scene's 57.0–59.3 → 51.1 ms (a scratch probe alternating the
/// two in one process); the caps from the welded mesh 2.62–2.69 →
/// 2.12–2.27 ms (`stage_probe -- build` as in [`fill_sides`]). A row read
/// whole must not be the table's last, whose 16 bytes would run past its
/// end: a record naming it is copied float by float.
#[inline(always)]
fn put_rows<const N: usize, const CANON: bool>(
    pos: &[[f32; 3]],
    ids: [u32; N],
    w: [f32; N],
    out: &mut [f32],
) {
    assert_eq!(out.len(), 4 * N);
    #[cfg(target_arch = "x86_64")]
    if ids.iter().fold(0, |m, &i| m.max(i)) as usize + 1 < pos.len() {
        use std::arch::x86_64::*;
        // SAFETY: SSE2 is part of x86-64. Each row's 16 bytes lie inside
        // the table (its index is below the last), and `out` holds the
        // 4 · N floats stored.
        unsafe {
            let keep = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));
            let rows = pos.as_ptr().cast::<f32>();
            let dst = out.as_mut_ptr();
            for j in 0..N {
                let mut v = _mm_loadu_ps(rows.add(3 * ids[j] as usize));
                if CANON {
                    v = _mm_add_ps(v, _mm_setzero_ps());
                }
                let v = _mm_or_ps(_mm_and_ps(v, keep), _mm_setr_ps(0.0, 0.0, 0.0, w[j]));
                _mm_storeu_ps(dst.add(4 * j), v);
            }
        }
        return;
    }
    for ((slot, &i), &w) in out.chunks_exact_mut(4).zip(&ids).zip(&w) {
        let p = pos[i as usize];
        let p = if CANON { p.map(|f| f + 0.0) } else { p };
        slot.copy_from_slice(&[p[0], p[1], p[2], w]);
    }
}

/// Floats that caps block `blk` of a mesh of `triangles` triangles writes.
fn cap_block_floats(triangles: usize, blk: usize) -> usize {
    let end = ((blk + 1) * BLOCK).min(triangles);
    (end - blk * BLOCK) * 12
}

/// Writes caps block `blk`'s records of the welded mesh `pos`,
/// `triangles` into `out` ([`cap_block_floats`] floats).
fn fill_caps(pos: &[[f32; 3]], triangles: &[u32], blk: usize, out: &mut [f32]) {
    let end = ((blk + 1) * BLOCK).min(triangles.len() / 3);
    let tris = &triangles[3 * blk * BLOCK..3 * end];
    let ahead = tris.get(3 * AHEAD..).unwrap_or(&[]);
    for (i, (rec, c)) in out
        .chunks_exact_mut(12)
        .zip(tris.chunks_exact(3))
        .enumerate()
    {
        // The triangles' line 2 KiB on (`hint::STREAM_AHEAD`): the reads
        // just below are only `AHEAD` triangles (768 bytes) on. Each unit
        // written, one thread, four alternations of `stage_probe --
        // fill-write`, medians: the dragon's caps 4.92 → 3.10 ms, the 5M
        // scene's 38.0 → 33.7 ms. The same hint on the sides' edge arrays
        // (every 16 edges) made them slower: 7.0 → 7.6 ms on the dragon.
        prefetch_stream(tris.as_ptr().wrapping_add(3 * i));
        if let Some(f) = ahead.get(3 * i..3 * i + 3) {
            for &v in f {
                prefetch_whole(&pos[v as usize]);
            }
        }
        put_rows::<3, false>(pos, [c[0], c[1], c[2]], [1.0; 3], rec);
    }
}

/// The caps records of a welded mesh alone, as a [`PayloadSource`] of one
/// section in the same units as the first units of [`Records`] (one per
/// caps block): what `format::AheadFile::write` writes while the edges are
/// still being made, since the caps need only the welded mesh.
pub struct CapsRecords<'a> {
    positions: &'a [[f32; 3]],
    triangles: &'a [u32],
}

impl<'a> CapsRecords<'a> {
    /// Floats of the largest unit (a block of triangles, 12 floats each).
    pub const UNIT_FLOATS: usize = BLOCK * 12;

    /// The caps of `welded`.
    pub fn new(welded: &'a Welded) -> Self {
        Self::from_parts(&welded.positions, &welded.triangles)
    }

    /// The caps of the welded mesh with these `positions` and
    /// `triangles`: for a build that shares the triangles with the
    /// topology (`topology::build_edges_opposites_only_shared_fed`).
    pub fn from_parts(positions: &'a [[f32; 3]], triangles: &'a [u32]) -> Self {
        CapsRecords {
            positions,
            triangles,
        }
    }
}

impl PayloadSource for CapsRecords<'_> {
    fn units(&self) -> usize {
        (self.triangles.len() / 3).div_ceil(BLOCK)
    }

    fn floats(&self, unit: usize, section: usize) -> usize {
        match section {
            0 => cap_block_floats(self.triangles.len() / 3, unit),
            _ => 0,
        }
    }

    fn fill(&self, unit: usize, outs: &mut [&mut [f32]]) {
        fill_caps(self.positions, self.triangles, unit, outs[0]);
    }
}

/// The caps records of a welded mesh made from the soup it was welded
/// from, in the units of [`CapsRecords`], with the same bytes.
///
/// A kept triangle's record is its corners' canonical positions, which is
/// what its welded positions are (`weld` decodes them from the canonical
/// bits), and the weld keeps the soup's triangles in order less the ones
/// it lists as dropped. Why read the soup: the welded positions are in
/// lexicographic order, so the welded corners of consecutive triangles
/// are scattered over the whole table, while a soup's corners are near
/// each other as the input has them. On the 5M scene (30 MB of welded
/// positions), one thread, each unit written: 42.2 ms from the welded
/// mesh (33 ms with `hint::prefetch_whole`, which came after), 14.0 ms
/// from the soup, 9.0 ms for the same stores with no position read
/// (`stage_probe -- fill-write`); on the dragon 3.9 against 3.7 ms.
pub struct SoupCaps<'a> {
    positions: &'a [[f32; 3]],
    indices: &'a [u32],
    /// The welded mesh's dropped input triangles, increasing.
    dropped: &'a [u32],
    /// Kept triangles.
    triangles: usize,
}

impl<'a> SoupCaps<'a> {
    /// The caps of `welded`, read from `positions` and `indices`, the
    /// soup `welded` was welded from (positions as welded: after
    /// quantising, if the build quantises).
    pub fn new(positions: &'a [[f32; 3]], indices: &'a [u32], welded: &'a Welded) -> Self {
        assert_eq!(
            indices.len() / 3,
            welded.triangle_count() + welded.dropped.len(),
            "SoupCaps: not the soup this mesh was welded from"
        );
        SoupCaps {
            positions,
            indices,
            dropped: &welded.dropped,
            triangles: welded.triangle_count(),
        }
    }

    /// How many dropped triangles come before kept triangle `k` in the
    /// soup: the `d` such that `k + d` is its input index. `dropped[i] - i`
    /// (the kept triangles before dropped one `i`) never decreases, so
    /// it is the number of `i` with `dropped[i] - i <= k`.
    fn dropped_before(&self, k: usize) -> usize {
        let (mut lo, mut hi) = (0, self.dropped.len());
        while lo < hi {
            let mid = (lo + hi) / 2;
            if self.dropped[mid] as usize - mid <= k {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        lo
    }
}

impl PayloadSource for SoupCaps<'_> {
    fn units(&self) -> usize {
        self.triangles.div_ceil(BLOCK)
    }

    fn floats(&self, unit: usize, section: usize) -> usize {
        match section {
            0 => cap_block_floats(self.triangles, unit),
            _ => 0,
        }
    }

    fn fill(&self, unit: usize, outs: &mut [&mut [f32]]) {
        let out = &mut *outs[0];
        let first = unit * BLOCK;
        let mut d = self.dropped_before(first);
        let mut t = first + d;
        let pos = self.positions;
        for rec in out.chunks_exact_mut(12) {
            // Past the dropped triangles here (none, in most meshes).
            while self.dropped.get(d) == Some(&(t as u32)) {
                d += 1;
                t += 1;
            }
            let c = &self.indices[3 * t..3 * t + 3];
            // 2 KiB on in the indices (`hint::STREAM_AHEAD`): each unit
            // written, one thread, four alternations of `stage_probe --
            // fill-write`, medians: the dragon's caps 3.82 → 3.42 ms, the
            // 5M scene's 15.2 → 11.5 ms.
            prefetch_stream(c.as_ptr());
            // (Canonical, as `weld` decodes a kept corner's position.)
            put_rows::<3, true>(pos, [c[0], c[1], c[2]], [1.0; 3], rec);
            t += 1;
        }
    }
}

/// Whether every edge of side block `blk` of `edges` (which must hold the
/// block) has two opposite vertices: then, with K ≥ 2, the block's records
/// are all in bucket 2, one per edge, in edge order.
fn pure_block(edges: EdgeSlices, blk: usize) -> bool {
    let end = ((blk + 1) * BLOCK).min(edges.len());
    edges.opp_start[blk * BLOCK..=end]
        .windows(2)
        .all(|w| w[1].wrapping_sub(w[0]) == 2)
}

/// Side blocks `blocks` of `edges`, all pure ([`pure_block`]), as a
/// [`PayloadSource`] of one section: their bucket-2 records.
struct PureSides<'a> {
    max_mult: u32,
    welded: &'a Welded,
    edges: EdgeSlices<'a>,
    blocks: std::ops::Range<usize>,
}

impl PayloadSource for PureSides<'_> {
    fn units(&self) -> usize {
        self.blocks.len()
    }

    fn floats(&self, unit: usize, section: usize) -> usize {
        let blk = self.blocks.start + unit;
        let edges = ((blk + 1) * BLOCK).min(self.edges.len()) - blk * BLOCK;
        if section == 0 { edges * 16 } else { 0 }
    }

    fn fill(&self, unit: usize, outs: &mut [&mut [f32]]) {
        let mut by_k: Vec<&mut [f32]> = (0..=self.max_mult).map(|_| Default::default()).collect();
        by_k[2] = std::mem::take(&mut outs[0]);
        fill_sides(
            self.max_mult,
            self.welded,
            self.edges,
            self.blocks.start + unit,
            &mut by_k,
        );
    }
}

/// Copies side blocks into `file` while `feed`'s emit makes the edges
/// (the consumer of `topology::build_edges_opposites_only_fed`), guessing
/// that the file's first bucket is bucket 2: right for every mesh without
/// a record of k = 1 (no edge with one opposite vertex, nor with `n` > K
/// and `n mod K` = 1), which is every closed manifold mesh. Block after
/// block as the edges are finished, up to the first block with an edge
/// whose opposite count is not 2 (its records leave bucket 2, so later
/// blocks' offsets are not known); once the emit has ended, what is left
/// on both threads. The final writer keeps the blocks that went where
/// the file puts them and writes the others again: if the guess was
/// wrong, the whole copy is wasted. The side units follow the caps' of
/// the mesh's `triangles` kept triangles; of `welded` only the positions
/// are read (the triangles may be with the topology).
///
/// Why: with two threads the side records' copy into the file (83 MB on
/// the dragon) was one thread's work after the edges were made; buffered
/// writes into one file take its lock in turn (benches/ROUNDS.md,
/// "Nineteenth round").
pub fn write_sides_ahead(
    feed: &EmitFeed,
    welded: &Welded,
    triangles: usize,
    max_mult: u32,
    file: &crate::format::AheadFile,
    side: &(dyn Fn() -> bool + Sync),
) -> crate::error::Result<()> {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering::Relaxed};
    if max_mult < 2 {
        return Ok(());
    }
    // Side units follow the caps' in the final payload; bucket 2 is its
    // section 1 when it is the first bucket. Block b goes at b whole
    // blocks past the first bucket's start (every block but the last of
    // all is whole): 16 floats of 4 or 2 bytes per edge.
    let first_unit = triangles.div_ceil(BLOCK);
    let block_bytes = (BLOCK * 16) as u64 * (file.vec4_bytes() / 4);
    // With every edge pure, half as many edges as records.
    let sides_end =
        file.sides_offset() + (feed.records() / 2 * 16) as u64 * (file.vec4_bytes() / 4);
    file.reserve(file.sides_offset(), sides_end)?;
    // Blocks are taken in order by the threads copying (this one, and the
    // emitting one once it is done); the first impure block stops them.
    let next = AtomicUsize::new(0);
    let stop = AtomicBool::new(false);
    let copy = || -> crate::error::Result<()> {
        let mut bufs = crate::format::UnitBuffers::new(BLOCK * 16);
        loop {
            let blk = next.fetch_add(1, Relaxed);
            if stop.load(Relaxed) {
                return Ok(());
            }
            // All of block `blk`'s edges are done, or every edge is.
            let wait = crate::trace::now();
            let (done, ended) = feed.wait((blk + 1) * BLOCK, side);
            if let Some(wait) = wait {
                crate::trace::since_n("wait for edges", blk as u64, wait);
            }
            debug_assert!(ended || done >= (blk + 1) * BLOCK);
            if blk * BLOCK >= done {
                return Ok(());
            }
            let edges = feed.edges(done);
            if !pure_block(edges, blk) {
                stop.store(true, Relaxed);
                return Ok(());
            }
            let source = PureSides {
                max_mult,
                welded,
                edges,
                blocks: blk..blk + 1,
            };
            let at = file.sides_offset() + blk as u64 * block_bytes;
            file.write(&source, first_unit + blk, 1, at, &mut bufs, side)?;
        }
    };
    // The second copier waits in this thread's queue for the emitting
    // thread, which takes it when its emit is done.
    let (x, y) = rayon::join(copy, copy);
    x.and(y)
}

/// A plan's records as a [`PayloadSource`] ([`Plan::records`]): the caps
/// blocks, then the side blocks, filled as `format::write_file_streamed`
/// asks; sections are the caps, then the non-empty buckets in increasing k.
pub struct Records<'a> {
    plan: &'a Plan,
    welded: &'a Welded,
    edges: &'a Edges,
    /// Bucket k of each side section (section `s` is bucket `ks[s - 1]`).
    ks: Vec<u32>,
}

impl PayloadSource for Records<'_> {
    fn units(&self) -> usize {
        self.plan.cap_blocks() + self.plan.side_blocks()
    }

    fn floats(&self, unit: usize, section: usize) -> usize {
        let caps = self.plan.cap_blocks();
        match (unit < caps, section) {
            (true, 0) => self.plan.cap_block_floats(unit),
            (false, s) if s > 0 => self.plan.side_block_floats(unit - caps, self.ks[s - 1]),
            _ => 0,
        }
    }

    fn fill(&self, unit: usize, outs: &mut [&mut [f32]]) {
        let caps = self.plan.cap_blocks();
        if unit < caps {
            self.plan.fill_caps(self.welded, unit, outs[0]);
            return;
        }
        let mut by_k: Vec<&mut [f32]> = (0..=self.plan.max_mult)
            .map(|_| Default::default())
            .collect();
        for (out, &k) in outs[1..].iter_mut().zip(&self.ks) {
            by_k[k as usize] = std::mem::take(out);
        }
        self.plan
            .fill_sides(self.welded, self.edges, unit - caps, &mut by_k);
    }

    /// The caps need the welded triangles, which a one-thread build gives
    /// to the topology once its caps are written ahead (`build`).
    fn can_fill(&self, unit: usize) -> bool {
        unit >= self.plan.cap_blocks() || self.welded.triangles.len() == 3 * self.plan.triangles
    }
}

/// Builds the sides and caps buffers. `max_mult` must be in `1..=MAX_MAX_MULT`.
///
/// Records go to their bucket in edge order. The fill is parallel but the
/// output is not thread-dependent: edges are cut into fixed blocks, each
/// block's record count per bucket is known beforehand ([`Plan`]), so every
/// block writes its own precomputed range of every bucket.
pub fn layout(welded: &Welded, edges: &Edges, max_mult: u32) -> Layout {
    layout_planned(
        welded,
        edges,
        &Plan::new(edges, welded.triangle_count(), max_mult),
    )
}

/// [`layout`] from a plan made for these edges and triangles. Its passes
/// run as one job on rayon's pool (see `crate::pool`).
pub fn layout_planned(welded: &Welded, edges: &Edges, plan: &Plan) -> Layout {
    crate::pool::one_job(|| fill_planned(welded, edges, plan))
}

/// The passes of [`layout_planned`].
fn fill_planned(welded: &Welded, edges: &Edges, plan: &Plan) -> Layout {
    use rayon::prelude::*;
    let k_max = plan.max_mult as usize;
    let counts = &plan.counts;
    let mut data: Vec<Vec<f32>> = (0..=k_max)
        .map(|k| vec![0.0; counts[k] as usize * (2 + k) * 4])
        .collect();

    // Cut every bucket into the blocks' ranges, then fill in parallel.
    let mut per_block: Vec<Vec<&mut [f32]>> = (0..plan.side_blocks()).map(|_| Vec::new()).collect();
    for (k, bucket) in data.iter_mut().enumerate() {
        let mut rest: &mut [f32] = bucket;
        for (blk, outs) in per_block.iter_mut().enumerate() {
            let (mine, tail) = rest.split_at_mut(plan.side_block_floats(blk, k as u32));
            outs.push(mine);
            rest = tail;
        }
    }
    per_block
        .into_par_iter()
        .enumerate()
        .for_each(|(blk, mut outs)| plan.fill_sides(welded, edges, blk, &mut outs));

    let mut caps = vec![0.0f32; plan.triangles * 12];
    caps.par_chunks_mut(12 * BLOCK)
        .enumerate()
        .for_each(|(blk, out)| plan.fill_caps(welded, blk, out));

    let buckets = data
        .into_iter()
        .enumerate()
        .filter(|(k, _)| counts[*k] > 0)
        .map(|(k, d)| SideBucket {
            k: k as u32,
            instances: counts[k],
            data: d,
        })
        .collect();
    Layout { caps, buckets }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::topology::build_edges;
    use crate::weld::weld;

    fn fan(n: usize) -> Welded {
        // Edge (0,0,0)-(1,0,0) with n fins.
        let mut pos = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
        let mut idx = Vec::new();
        for i in 0..n {
            let ang = i as f32 * 0.3;
            pos.push([0.5, ang.cos(), ang.sin() + 2.0]);
            idx.extend_from_slice(&[0, 1, (i + 2) as u32]);
        }
        weld(&pos, &idx)
    }

    /// The estimate is exact for separate triangles (every edge open) and
    /// for a closed torus, over by the Euler characteristic's edges
    /// otherwise (2 for a closed sphere, a tetrahedron), and counts each
    /// edge once however many opposite vertices it has. Caught: the edges
    /// not capped at one per record (separate triangles over), and the
    /// caps left out.
    #[test]
    fn the_expected_payload_is_exact_for_open_and_closed_meshes() {
        let separate = |n: usize| {
            let mut pos = Vec::new();
            let mut idx = Vec::new();
            for i in 0..n {
                let x = i as f32 * 3.0;
                pos.extend_from_slice(&[[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x, 1.0, 0.0]]);
                idx.extend_from_slice(&[3 * i as u32, 3 * i as u32 + 1, 3 * i as u32 + 2]);
            }
            weld(&pos, &idx)
        };
        // A torus of 6 × 5 quads, each cut into two triangles.
        let torus = {
            let (n, m) = (6u32, 5u32);
            let mut pos = Vec::new();
            for i in 0..n {
                for j in 0..m {
                    let a = i as f32 * std::f32::consts::TAU / n as f32;
                    let b = j as f32 * std::f32::consts::TAU / m as f32;
                    let r = 3.0 + b.cos();
                    pos.push([r * a.cos(), r * a.sin(), b.sin()]);
                }
            }
            let at = |i: u32, j: u32| (i % n) * m + j % m;
            let mut idx = Vec::new();
            for i in 0..n {
                for j in 0..m {
                    let (p, q, r, t) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                    idx.extend_from_slice(&[p, q, r, p, r, t]);
                }
            }
            weld(&pos, &idx)
        };
        let tetrahedron = weld(
            &[
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
            ],
            &[0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3],
        );
        for (what, w, over) in [
            ("separate", separate(40), 0),
            ("torus", torus, 0),
            ("tetrahedron", tetrahedron, 2 * 2 * 16),
            // Four fins on one edge: V − E + T = 1, one edge over.
            ("fan", fan(4), 2 * 16),
        ] {
            let e = build_edges(&w.triangles, w.positions.len());
            let l = layout(&w, &e, 5);
            let payload = l.caps_bytes() + l.sides_bytes();
            let (t, v) = (w.triangle_count() as u64, w.positions.len() as u64);
            let expected = expected_payload_bytes(t, v, 16);
            assert_eq!(
                expected,
                payload + over,
                "{what}: {t} triangles, {v} vertices"
            );
            assert_eq!(
                expected_payload_bytes(t, v, 8),
                expected / 2,
                "{what}, unorm16"
            );
        }
    }

    #[test]
    fn split_is_quotient_and_remainder() {
        for m in 1..=MAX_MAX_MULT {
            for n in 0..3 * MAX_MAX_MULT + 2 {
                assert_eq!(split(n, m), (n / m, n % m), "n {n}, K {m}");
            }
        }
    }

    #[test]
    fn plan_counts_every_block_as_a_walk_over_its_edges_does() {
        // Fans of 1 to 17, mostly 2, over three blocks and a bit; one block
        // holds fans of 1 and 2 only (the histogram's fast path).
        let mut x = 0x9e37_79b9u32;
        let mut starts = vec![0u32];
        for e in 0..2 * BLOCK + BLOCK / 3 {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            let fan = match (e / BLOCK, x % 16) {
                (1, 0..=3) => 1,
                (1, _) => 2,
                (_, 0) => 1 + x % 17,
                (_, 1..=3) => 1,
                _ => 2,
            };
            starts.push(starts.last().unwrap() + fan);
        }
        let edges = Edges {
            opp_start: starts,
            a: vec![0; 2 * BLOCK + BLOCK / 3],
            ..Edges::default()
        };
        for k in [1, 2, 3, 5, 13] {
            let plan = Plan::new(&edges, 0, k);
            let mut total = vec![0u64; k as usize + 1];
            for (blk, counts) in plan.block_counts.iter().enumerate() {
                let mut walk = vec![0u64; k as usize + 1];
                for e in blk * BLOCK..((blk + 1) * BLOCK).min(edges.len()) {
                    let n = edges.fan(e) as u32;
                    walk[k as usize] += u64::from(n / k);
                    if !n.is_multiple_of(k) {
                        walk[(n % k) as usize] += 1;
                    }
                }
                assert_eq!(*counts, walk, "K {k}, block {blk}");
                total.iter_mut().zip(&walk).for_each(|(t, w)| *t += w);
            }
            assert_eq!(plan.block_counts.len(), 3);
            assert_eq!(plan.counts, total, "K {k}");
        }
    }

    #[test]
    fn rows_read_whole_equal_rows_copied_float_by_float() {
        // Row 3, the table's last, is copied float by float (its 16 bytes
        // would run past the table); the others are read 16 bytes at a
        // time on x86-64. `-0.0` in every lane, so that canonical rows
        // (+0.0) differ from plain ones.
        let pos = [
            [-0.0, 1.0, 2.0],
            [3.0, -0.0, -5.0],
            [6.0, f32::MIN_POSITIVE, -0.0],
            [-0.0, -1.5, -0.0],
        ];
        let want = |ids: &[u32], w: &[f32], canon: bool| -> Vec<u32> {
            ids.iter()
                .zip(w)
                .flat_map(|(&i, &w)| {
                    let p = pos[i as usize];
                    let f = |x: f32| if canon && x == 0.0 { 0.0 } else { x };
                    [f(p[0]), f(p[1]), f(p[2]), w]
                })
                .map(f32::to_bits)
                .collect()
        };
        let bits = |out: &[f32]| out.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        for ids in [[0, 1, 2, 3], [3, 2, 1, 0], [1, 1, 2, 2], [3, 3, 3, 3]] {
            let mut out = [f32::NAN; 16];
            put_rows::<4, false>(&pos, ids, [2.0, 2.0, 1.0, 1.0], &mut out);
            assert_eq!(
                bits(&out),
                want(&ids, &[2.0, 2.0, 1.0, 1.0], false),
                "{ids:?}"
            );
            let mut out = [f32::NAN; 12];
            let ids = [ids[0], ids[1], ids[2]];
            put_rows::<3, true>(&pos, ids, [1.0; 3], &mut out);
            assert_eq!(
                bits(&out),
                want(&ids, &[1.0; 3], true),
                "{ids:?}, canonical"
            );
            put_rows::<3, false>(&pos, ids, [1.0; 3], &mut out);
            assert_eq!(
                bits(&out),
                want(&ids, &[1.0; 3], false),
                "{ids:?}, as stored"
            );
        }
    }

    /// The table's last row ends a page whose next page cannot be read: a
    /// 16-byte load of that row (4 bytes past the table) would fault.
    /// Caught: the whole-row loads allowed for the last row (the test
    /// process killed by SIGSEGV).
    #[cfg(target_os = "linux")]
    #[test]
    fn the_last_row_is_never_read_past_its_end() {
        // SAFETY: two fresh anonymous pages, the second made unreadable;
        // the table lies inside the first, and both are unmapped at the end.
        unsafe {
            let page = libc::sysconf(libc::_SC_PAGESIZE) as usize;
            let base = libc::mmap(
                std::ptr::null_mut(),
                2 * page,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            );
            assert_ne!(base, libc::MAP_FAILED);
            assert_eq!(
                libc::mprotect(base.cast::<u8>().add(page).cast(), page, libc::PROT_NONE),
                0
            );
            let n = 5;
            let rows = base.cast::<u8>().add(page - 12 * n).cast::<[f32; 3]>();
            for i in 0..n {
                rows.add(i).write([i as f32, -0.0, 0.5]);
            }
            let pos = std::slice::from_raw_parts(rows, n);
            // (Bits, so that the zeros' signs count.)
            let bits = |f: &[f32]| f.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
            let mut out = [0f32; 16];
            put_rows::<4, false>(pos, [3, 4, 4, 0], [2.0, 2.0, 1.0, 1.0], &mut out);
            assert_eq!(bits(&out[4..8]), bits(&[4.0, -0.0, 0.5, 2.0]));
            let mut out = [0f32; 12];
            put_rows::<3, true>(pos, [4, 1, 2], [1.0; 3], &mut out);
            assert_eq!(bits(&out[..4]), bits(&[4.0, 0.0, 0.5, 1.0]));
            assert_eq!(libc::munmap(base, 2 * page), 0);
        }
    }

    #[test]
    fn split_into_buckets() {
        let w = fan(12);
        let e = build_edges(&w.triangles, w.positions.len());
        let l = layout(&w, &e, 5);
        // Fan edge: 12 = 5 + 5 + 2; 24 fin edges have 1 opposite each.
        let ks: Vec<(u32, u64)> = l.buckets.iter().map(|b| (b.k, b.instances)).collect();
        assert_eq!(ks, vec![(1, 24), (2, 1), (5, 2)]);
        for b in &l.buckets {
            assert_eq!(b.data.len() as u64, b.instances * (2 + b.k as u64) * 4);
        }
        let b5 = &l.buckets[2].data;
        assert_eq!(b5[3], 5.0); // A.w = used
        assert_eq!(b5[7], 12.0); // B.w = total
        assert_eq!(l.caps.len(), 12 * 12);
        assert_eq!(l.sides_bytes(), 16 * (3 * 24 + 4 + 7 * 2));
    }
}
