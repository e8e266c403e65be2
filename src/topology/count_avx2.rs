//! Pass 1's counts for CPUs with AVX2 but not AVX-512:
//! [`super::count_avx512`]'s method on 8 triangles a block.
//!
//! Why: without AVX-512 the count pass ran its scalar loop, which loads and
//! orders the corners one triangle at a time and adds to each counter as
//! soon as it has the range. On the AMD EPYC of the sixty-first round (Zen
//! 3), one thread, `RECYCLE=1 RAYON_NUM_THREADS=1 cargo run --release
//! --example stage_probe -- passes FILE`, binaries alternated, fastest /
//! median: the count pass 2.24 / 2.25 → 1.13 / 1.15 ms on the dragon (six),
//! 13.10 / 13.39 → 7.17 / 7.25 ms on the 5M scene (four); with two
//! threads (`RAYON_NUM_THREADS=2`, its "fed" line, the topology as a
//! two-thread build runs it) 15.71–20.36 → 14.60–14.77 ms on the dragon
//! (three).

use super::{COUNT_LANES, EDGE_KEY, RANGE_SHIFT, count_triangle};
use std::arch::x86_64::*;

/// The corners of 8 triangles from their 24 words in three registers
/// (`w[0]` words 0–7 and so on): one register per corner, lane i triangle
/// i's, by a `vpermd` of each register and two blends. Corner c of
/// triangle i is word 3i + c, in register (3i + c) / 8 at lane
/// (3i + c) % 8. Which corner lands in which register does not matter to
/// the count (the smallest and the middle corner come out the same), only
/// that each triangle's three do.
#[inline]
#[target_feature(enable = "avx2")]
fn corners(w: &[__m256i; 3]) -> [__m256i; 3] {
    let pick = |idx: __m256i| w.map(|r| _mm256_permutevar8x32_epi32(r, idx));
    // c = 0: words 0, 3, …, 21, registers 0 0 0 1 1 1 2 2.
    let p = pick(_mm256_setr_epi32(0, 3, 6, 1, 4, 7, 2, 5));
    let x = _mm256_blend_epi32::<0xC0>(_mm256_blend_epi32::<0x38>(p[0], p[1]), p[2]);
    // c = 1: words 1, 4, …, 22, registers 0 0 0 1 1 2 2 2.
    let p = pick(_mm256_setr_epi32(1, 4, 7, 2, 5, 0, 3, 6));
    let y = _mm256_blend_epi32::<0xE0>(_mm256_blend_epi32::<0x18>(p[0], p[1]), p[2]);
    // c = 2: words 2, 5, …, 23, registers 0 0 1 1 1 2 2 2.
    let p = pick(_mm256_setr_epi32(2, 5, 0, 3, 6, 1, 4, 7));
    let z = _mm256_blend_epi32::<0xE0>(_mm256_blend_epi32::<0x1C>(p[0], p[1]), p[2]);
    [x, y, z]
}

/// The keys `(a << 32 | b) · EDGE_KEY` (wrapping) of 4 edges, `a` and `b`
/// 4 ids each: AVX2 has no 64-bit multiply, so the low 64 bits of the
/// product are `b · k_lo` (32 × 32 → 64 bits) plus `(a · k_lo + b · k_hi)
/// << 32`, whose low 32 bits alone count.
#[inline]
#[target_feature(enable = "avx2")]
fn keys(a: __m128i, b: __m128i) -> __m256i {
    let k_lo = _mm256_set1_epi64x(EDGE_KEY as u32 as i64);
    let k_hi = _mm256_set1_epi64x((EDGE_KEY >> 32) as i64);
    let (a, b) = (_mm256_cvtepu32_epi64(a), _mm256_cvtepu32_epi64(b));
    let cross = _mm256_add_epi32(_mm256_mullo_epi32(a, k_lo), _mm256_mullo_epi32(b, k_hi));
    _mm256_add_epi64(_mm256_mul_epu32(b, k_lo), _mm256_slli_epi64::<32>(cross))
}

/// [`super::count_avx512`] for CPUs with AVX2: the whole blocks of 8
/// triangles in `tris` counted into the same [`COUNT_LANES`] lanes of
/// counters, each block's adds a block after its ranges, and with `PARITY`
/// the xor of their edges' keys into `odd`; returns the number of
/// triangles counted.
///
/// # Safety
/// The CPU must have AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn count_avx2<const PARITY: bool>(
    tris: &[u32],
    lanes: &mut [u64],
    ranges: usize,
    odd: &mut u64,
) -> usize {
    const { assert!(8 % COUNT_LANES == 0) };
    let blocks = tris.len() / 24;
    let mut parity = _mm256_setzero_si256();
    // Block b's ranges (8 lo, then 8 mid) in `held[b % 2]`.
    let mut held = [[0u32; 16]; 2];
    for b in 0..=blocks {
        if b < blocks {
            // SAFETY: block b's 24 words lie inside `tris`.
            let w = unsafe {
                let at = tris.as_ptr().add(24 * b);
                crate::hint::prefetch_stream(at);
                [0, 8, 16].map(|k| _mm256_loadu_si256(at.add(k).cast()))
            };
            let [x, y, z] = corners(&w);
            let lo = _mm256_min_epu32(x, _mm256_min_epu32(y, z));
            let hi = _mm256_max_epu32(x, _mm256_max_epu32(y, z));
            let mid = _mm256_xor_si256(
                _mm256_xor_si256(x, y),
                _mm256_xor_si256(z, _mm256_xor_si256(lo, hi)),
            );
            if PARITY {
                let halves =
                    |v: __m256i| (_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
                let ((l0, l1), (m0, m1), (u0, u1)) = (halves(lo), halves(mid), halves(hi));
                for (l, m, u) in [(l0, m0, u0), (l1, m1, u1)] {
                    let k = _mm256_xor_si256(keys(l, m), _mm256_xor_si256(keys(l, u), keys(m, u)));
                    parity = _mm256_xor_si256(parity, k);
                }
            }
            let slot = &mut held[b % 2];
            // SAFETY: 16 u32, 8 for each store.
            unsafe {
                _mm256_storeu_si256(
                    slot.as_mut_ptr().cast(),
                    _mm256_srli_epi32::<{ RANGE_SHIFT as i32 }>(lo),
                );
                _mm256_storeu_si256(
                    slot.as_mut_ptr().add(8).cast(),
                    _mm256_srli_epi32::<{ RANGE_SHIFT as i32 }>(mid),
                );
            }
        }
        if b > 0 {
            let slot = &held[(b - 1) % 2];
            for j in 0..8 {
                // A block starts at a multiple of 8, so `j % COUNT_LANES`
                // is the triangle's lane in the scalar loop's numbering too.
                let (l, m) = (slot[j] as usize, slot[8 + j] as usize);
                count_triangle(lanes, ranges, j % COUNT_LANES, l, m);
            }
        }
    }
    if PARITY {
        let mut words = [0u64; 4];
        // SAFETY: 4 u64.
        unsafe { _mm256_storeu_si256(words.as_mut_ptr().cast(), parity) };
        *odd ^= words.iter().fold(0, |x, &w| x ^ w);
    }
    8 * blocks
}
