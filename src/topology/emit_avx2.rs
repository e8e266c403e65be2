//! Pass 3's emit for CPUs with AVX2 but not AVX-512 (AMD's Zen 2 and 3,
//! Intel's client cores): [`super::emit_range_avx512`]'s method in 256-bit
//! registers, with a table where that kernel compresses.
//!
//! Why: without AVX-512 the emit ran the scalar [`super::emit_vertex`],
//! which moves every record through memory, sorts them by a network of 19
//! dependent scalar compare-exchanges and writes them one at a time. On the
//! AMD EPYC of the sixty-first round (Zen 3, no AVX-512) that took 22.4 ms
//! of the dragon's 28.6 ms topology, one thread, where the AVX-512 kernel
//! took 8.4 ms on the Intel Xeon of the rounds before. With this kernel,
//! one thread, `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run --release --example
//! stage_probe -- passes FILE`, binaries alternated, fastest / median: the
//! emit pass 22.36 / 22.50 → 11.64 / 11.71 ms on the dragon (eight), 111.97
//! / 117.86 → 60.56 / 63.12 ms on the 5M scene (four); `SCALAR_TOPOLOGY=1`
//! times the scalar passes on the same binary. Tried on that machine and
//! dropped (benches/ROUNDS.md, "Sixty-first round"): every vertex of at
//! most 8 listings through two registers (no branch on 4 listings:
//! slower), two vertices of at most 4 listings at once (the same time),
//! the table as whole registers (the same), `sort_range_bmi2` (the same).

use super::{EmitBuf, GroupOut, KernelOut, Listings, SLOTS, emit_vertex};
use std::arch::x86_64::*;

/// For each 8-bit mask, the indices of its set bits in increasing order,
/// one byte each from the lowest (the bytes past them 0): the `vpermd`
/// indices that compress a register's lanes by that mask, which AVX2 has
/// no instruction for. 2 KiB, which stay in L1.
const COMPRESS8: [u64; 256] = {
    let mut table = [0u64; 256];
    let mut mask = 0;
    while mask < 256 {
        let (mut bit, mut at, mut indices) = (0, 0, 0u64);
        while bit < 8 {
            if mask >> bit & 1 == 1 {
                indices |= (bit as u64) << (8 * at);
                at += 1;
            }
            bit += 1;
        }
        table[mask] = indices;
        mask += 1;
    }
    table
};

/// The `vpermd` indices of [`COMPRESS8`]'s entry for `mask`.
#[inline]
#[target_feature(enable = "avx2")]
fn compress_indices(mask: u32) -> __m256i {
    _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(COMPRESS8[mask as usize & 255] as i64))
}

/// One layer of compare-exchanges: lane i against `partner`'s lane i (the
/// keys permuted), the lanes whose bit is set in `UPPER` keeping the larger.
#[inline]
#[target_feature(enable = "avx2")]
fn layer<const UPPER: i32>(s: __m256i, partner: __m256i) -> __m256i {
    _mm256_blend_epi32::<UPPER>(_mm256_min_epu32(s, partner), _mm256_max_epu32(s, partner))
}

/// Compare-exchanges at distance 1 (within pairs of lanes).
#[inline]
#[target_feature(enable = "avx2")]
fn d1(s: __m256i) -> __m256i {
    layer::<0xAA>(s, _mm256_shuffle_epi32::<0xB1>(s))
}

/// Compare-exchanges at distance 2 (within 128-bit halves).
#[inline]
#[target_feature(enable = "avx2")]
fn d2(s: __m256i) -> __m256i {
    layer::<0xCC>(s, _mm256_shuffle_epi32::<0x4E>(s))
}

/// Compare-exchanges at distance 4 (lane i against lane i + 4).
#[inline]
#[target_feature(enable = "avx2")]
fn d4(s: __m256i) -> __m256i {
    layer::<0xF0>(s, _mm256_permute4x64_epi64::<0x4E>(s))
}

/// The lanes in reverse order.
#[inline]
#[target_feature(enable = "avx2")]
fn reverse(s: __m256i) -> __m256i {
    _mm256_permutevar8x32_epi32(s, _mm256_set_epi32(0, 1, 2, 3, 4, 5, 6, 7))
}

/// Sorts 8 unsigned keys: the network of `emit_range_avx512`'s `sort8`
/// (each half by the network of 4, then the halves merged), whose layers
/// but one stay inside the 128-bit halves, where a `vpshufd` finds the
/// partners.
#[inline]
#[target_feature(enable = "avx2")]
fn sort8(s: __m256i) -> __m256i {
    let s = d2(d1(s));
    let s = layer::<0x44>(s, _mm256_shuffle_epi32::<0xD8>(s));
    let s = layer::<0xF0>(s, reverse(s));
    d1(d2(s))
}

/// Sorts a bitonic sequence of 8 keys (half-cleaners at distances 4, 2, 1).
#[inline]
#[target_feature(enable = "avx2")]
fn merge8(s: __m256i) -> __m256i {
    d1(d2(d4(s)))
}

/// Lane i holds i.
#[inline]
#[target_feature(enable = "avx2")]
fn ranks() -> __m256i {
    _mm256_set_epi32(7, 6, 5, 4, 3, 2, 1, 0)
}

/// All ones in the lanes below `n` (at most 8).
#[inline]
#[target_feature(enable = "avx2")]
fn first_lanes(n: usize) -> __m256i {
    _mm256_cmpgt_epi32(_mm256_set1_epi32(n as i32), ranks())
}

/// Four listings' words (`x`, [p, q] per listing, `l` of them real) as
/// keys `word << 4 | rank` (`rank` plus the lane) where the word is a
/// record's larger endpoint, all ones elsewhere, and the number of those
/// records: word 2j is listing j's p (always a record's), word 2j + 1 its
/// q (a record's where p < q; ids below 2^28, so the signed compare
/// orders them). `swapped` is `x` with each pair swapped: the records'
/// opposite vertices, lane for lane.
#[inline]
#[target_feature(enable = "avx2")]
fn keys_of(x: __m256i, swapped: __m256i, l: usize, rank: __m256i) -> (__m256i, u32) {
    let even = _mm256_set_epi32(0, -1, 0, -1, 0, -1, 0, -1);
    // Lane 2j: p < q, moved up to lane 2j + 1 (the odd lanes' compares
    // are shifted out).
    let lower = _mm256_slli_epi64::<32>(_mm256_cmpgt_epi32(swapped, x));
    let records = _mm256_and_si256(_mm256_or_si256(even, lower), first_lanes(2 * l));
    let keys = _mm256_blendv_epi8(
        _mm256_set1_epi32(-1),
        _mm256_or_si256(_mm256_slli_epi32::<4>(x), rank),
        records,
    );
    (
        keys,
        (_mm256_movemask_ps(_mm256_castsi256_ps(records)) as u32).count_ones(),
    )
}

/// Writes `k` (at most 8) sorted records of vertex `v` and their edges:
/// `sorted` their keys, `after` keys whose first is the key after them
/// (all ones for none), `opposite` the vertex's opposite vertices in the
/// order of the keys. As `emit_range_avx512`'s `finish`, with the edges
/// compressed through [`COMPRESS8`].
///
/// # Safety
/// Records `out.records..out.records + k` are the group's.
#[inline]
#[target_feature(enable = "avx2,popcnt")]
unsafe fn finish(
    out: &mut KernelOut,
    sorted: __m256i,
    after: __m256i,
    opposite: __m256i,
    k: usize,
    v: usize,
) {
    let larger = _mm256_srli_epi32::<4>(sorted);
    // Each key's next: lanes 1..8, then `after`'s first.
    let next = _mm256_srli_epi32::<4>(_mm256_blend_epi32::<0x80>(
        _mm256_permutevar8x32_epi32(sorted, _mm256_set_epi32(7, 7, 6, 5, 4, 3, 2, 1)),
        _mm256_broadcastd_epi32(_mm256_castsi256_si128(after)),
    ));
    // No padding lane ends an edge: padding keys are all ones, as is the
    // key after the last (`after`'s first is padding too, or a record).
    let same = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpeq_epi32(larger, next))) as u32;
    let ends = !same & 0xFF;
    let edges = ends.count_ones() as usize;
    let at = compress_indices(ends);
    let end = _mm256_add_epi32(
        ranks(),
        _mm256_set1_epi32((out.base + out.records as u32 + 1) as i32),
    );
    let (a_at, b_at, end_at) = (
        _mm256_set1_epi32(v as i32),
        _mm256_permutevar8x32_epi32(larger, at),
        _mm256_permutevar8x32_epi32(end, at),
    );
    // SAFETY: records `records..records + k` are the group's (the
    // caller's contract), and edges never outnumber records; the whole
    // stores write 8 slots from `records` only inside the room (listings
    // already read), from `edges` only inside `a`, `b` and `end`, which are
    // equally long (as in `emit_range_avx512`).
    //
    // Whole stores wherever there is room, the masked ones near the ends:
    // a `vpmaskmovd` store is slow on AMD's cores. With it for every
    // vertex's records, the dragon's emit pass took 13.40–13.51 ms against
    // 11.72–11.85 (the command of the module's doc, four alternations, a
    // fourth run of the masked form at 20.07 ms left out as noise).
    unsafe {
        let opp = out.opp.add(out.records);
        if out.records + 8 <= out.room {
            _mm256_storeu_si256(opp.cast(), opposite);
        } else {
            _mm256_maskstore_epi32(opp.cast(), first_lanes(k), opposite);
        }
        let (a, b, e) = (
            out.a.add(out.edges),
            out.b.add(out.edges),
            out.end.add(out.edges),
        );
        if out.edges + 8 <= out.len {
            _mm256_storeu_si256(a.cast(), a_at);
            _mm256_storeu_si256(b.cast(), b_at);
            _mm256_storeu_si256(e.cast(), end_at);
        } else {
            let mask = first_lanes(edges);
            _mm256_maskstore_epi32(a.cast(), mask, a_at);
            _mm256_maskstore_epi32(b.cast(), mask, b_at);
            _mm256_maskstore_epi32(e.cast(), mask, end_at);
        }
        crate::hint::prefetch_stream(a);
        crate::hint::prefetch_stream(b);
        crate::hint::prefetch_stream(e);
    }
    out.records += k;
    out.edges += edges;
}

/// [`super::emit_vertex`] for a group's `vertices` in AVX2 registers:
/// vertices with at most 8 listings (all but 84 of the dragon's 435,545)
/// here, the others by [`super::emit_vertex`]. Same output, word for word.
/// Only for `listings.narrow` (ids below `KEY_IDS` − 1).
///
/// Method, per vertex: its first 4 slots in one load (and the next 4 in
/// another with 5 to 8 listings); keys `larger << 4 | rank` where a word
/// is a record's larger endpoint, all ones elsewhere ([`keys_of`]), so no
/// compress stands between the load and the network (which AVX2 would do
/// by a table); [`sort8`]; with two registers both sorted and merged into
/// the 8 smallest and 8 largest keys (distinct, so the stable order). The
/// ranks then permute the opposite vertices, and the edges are compressed
/// out of the records by [`COMPRESS8`] ([`finish`]).
///
/// # Safety
/// The CPU must have AVX2 and POPCNT.
#[target_feature(enable = "avx2,popcnt")]
pub(super) unsafe fn emit_range_avx2(
    mut group: GroupOut,
    listings: &Listings,
    vertices: std::ops::Range<usize>,
    buf: &mut EmitBuf,
) -> (usize, usize) {
    debug_assert!(
        listings.narrow,
        "topology: 32-bit keys need ids below KEY_IDS - 1"
    );
    const { assert!(SLOTS == 8) };
    let none = _mm256_set1_epi32(-1);
    let mut spilled = 0;
    let mut kout = KernelOut::of(&mut group);
    for v in vertices {
        let out = &mut kout;
        let (from, l) = listings.of(v);
        if l <= 8 {
            let slots = &listings.pairs[from..from + SLOTS];
            // SAFETY: the load reads the first 32 bytes of `slots`' 64.
            let x = unsafe { _mm256_loadu_si256(slots.as_ptr().cast()) };
            let swapped = _mm256_shuffle_epi32::<0xB1>(x);
            let (keys, k) = keys_of(x, swapped, l.min(4), ranks());
            if l <= 4 {
                let k = k as usize;
                assert!(out.records + k <= out.len, "topology: records miscounted");
                let sorted = sort8(keys);
                // The ranks (below 8) pick the opposite vertices.
                let opposite = _mm256_permutevar8x32_epi32(swapped, sorted);
                // SAFETY: asserted just above.
                unsafe { finish(out, sorted, none, opposite, k, v) };
                continue;
            }
            // SAFETY: the load reads the last 32 bytes of `slots`.
            let x1 = unsafe { _mm256_loadu_si256(slots[4..].as_ptr().cast()) };
            let swapped1 = _mm256_shuffle_epi32::<0xB1>(x1);
            let rank1 = _mm256_or_si256(ranks(), _mm256_set1_epi32(8));
            let (keys1, k1) = keys_of(x1, swapped1, l - 4, rank1);
            let k = (k + k1) as usize;
            assert!(out.records + k <= out.len, "topology: records miscounted");
            // Two sorted halves, then a bitonic merge: the first against
            // the second reversed gives the 8 smallest and the 8 largest
            // keys, each a bitonic sequence.
            let (a, b) = (sort8(keys), reverse(sort8(keys1)));
            let (lo, hi) = (
                merge8(_mm256_min_epu32(a, b)),
                merge8(_mm256_max_epu32(a, b)),
            );
            // Ranks 0 to 15: the low 3 bits pick the lane, bit 3 (moved to
            // the sign) the register.
            let pick = |s: __m256i| {
                _mm256_castps_si256(_mm256_blendv_ps(
                    _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(swapped, s)),
                    _mm256_castsi256_ps(_mm256_permutevar8x32_epi32(swapped1, s)),
                    _mm256_castsi256_ps(_mm256_slli_epi32::<28>(s)),
                ))
            };
            // SAFETY: asserted above.
            unsafe {
                finish(out, lo, hi, pick(lo), k.min(8), v);
                if k > 8 {
                    finish(out, hi, none, pick(hi), k - 8, v);
                }
            }
            continue;
        }
        listings.gather(v, l, &mut spilled, buf);
        (group.records, group.edges) = (kout.records, kout.edges);
        emit_vertex::<false>(
            &mut group,
            v as u32,
            0,
            &buf.pairs,
            &buf.tri,
            &mut buf.records,
        );
        // (Pointers taken again: `emit_vertex` wrote through the slices.)
        kout = KernelOut::of(&mut group);
    }
    (kout.records, kout.edges)
}
