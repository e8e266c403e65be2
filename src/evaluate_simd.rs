//! Vectorised kernels for [`Strategy::Reference`](crate::evaluate::Strategy),
//! bit for bit the contract of format-spec/multiplicity.md.
//!
//! Why a second control flow for the contract: the scalar one
//! ([`crate::multiplicity::tri_sign`]) sorts the corners with branches and
//! leaves early when the light is on a corner. On a mesh the corner order is
//! data-dependent, so those branches mispredict about once per triangle and
//! cost more than the arithmetic; they also stop LLVM from vectorising. Here
//! every step is written without control flow: the three-comparator network
//! is three compare-and-select steps over the same comparisons
//! ([`lex_less_nb`] is `lex_less` without short-circuit, equal on every
//! input, NaN and ±0.0 included), the parity is the XOR of the three swap
//! decisions, and the light-on-corner test is a mask applied at the end. The
//! float expression is not restated: it is
//! [`crate::multiplicity::ref_expr`], the one Rust transcription of the
//! contract, inlined into each lane. IEEE `+ − ×` are exact functions of
//! their operands whether computed one at a time or eight per instruction,
//! and Rust never contracts `a * b + c` into a fused multiply-add or
//! reassociates a sum on its own, so each lane rounds exactly as the shaders
//! and [`crate::multiplicity::ref_sign`] do.
//!
//! Each loop is compiled twice: plainly (SSE2 on x86-64, whatever the target
//! has elsewhere) and with AVX2 (8 lanes), chosen at run time. The `fma`
//! feature is deliberately not enabled: LLVM does not form FMAs without
//! fast-math flags anyway, but keeping it off means no code path could round
//! differently. The tests call both versions and compare them with the scalar
//! contract on random and adversarial inputs.

use crate::multiplicity::{Light, lex_less_nb};

/// `if m { x } else { y }` per coordinate: a select (blend), never a branch.
#[inline(always)]
fn pick(m: bool, x: [f32; 3], y: [f32; 3]) -> [f32; 3] {
    [
        if m { x[0] } else { y[0] },
        if m { x[1] } else { y[1] },
        if m { x[2] } else { y[2] },
    ]
}

/// [`crate::multiplicity::tri_sign`]`(p0, p1, p2, l)`, branch-free: the same
/// three-comparator network (same comparisons, same tie handling, same
/// parity) and the same float expression as `ref_sign`, operation for
/// operation (format-spec/multiplicity.md §2, §3).
#[inline(always)]
pub fn tri_sign_nb(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], l: Light) -> i32 {
    // sort3: each comparator swaps (a select of both corners) when the later
    // corner is strictly smaller; every swap flips the parity.
    let s0 = lex_less_nb(p1, p0);
    let (a, b) = (pick(s0, p1, p0), pick(s0, p0, p1));
    let s1 = lex_less_nb(p2, b);
    let (b, c) = (pick(s1, p2, b), pick(s1, b, p2));
    let s2 = lex_less_nb(b, a);
    let (r0, r1) = (pick(s2, b, a), pick(s2, a, b));
    let r2 = c;
    sorted_sign_nb(r0, r1, r2, s0 ^ s1 ^ s2, l)
}

/// The part of [`tri_sign_nb`] after the corner sort: corners already in the
/// network's order (`r0, r1, r2`) and the parity of the sorting permutation
/// (`odd`). The light-on-corner test, the contract's expression, its sign,
/// the parity flip, all without branches (format-spec/multiplicity.md §2).
/// [`crate::evaluate_indexed`] calls it with corners sorted once per file.
#[inline(always)]
pub(crate) fn sorted_sign_nb(r0: [f32; 3], r1: [f32; 3], r2: [f32; 3], odd: bool, l: Light) -> i32 {
    // The point light exactly on a corner: 0 (spec §2), whichever corner.
    let lp = [l[0], l[1], l[2]];
    let eq = |p: [f32; 3]| (p[0] == lp[0]) & (p[1] == lp[1]) & (p[2] == lp[2]);
    let on_corner = (l[3] == 1.0) & (eq(r0) | eq(r1) | eq(r2));
    let sign = sorted_sign_off_corners(r0, r1, r2, odd, l);
    if on_corner { 0 } else { sign }
}

/// [`sorted_sign_nb`] without the light-on-corner test: equal to it
/// whenever the light is not a point light on one of the three corners
/// (a caller that knows no corner equals the light saves the nine
/// comparisons).
#[inline(always)]
pub(crate) fn sorted_sign_off_corners(
    r0: [f32; 3],
    r1: [f32; 3],
    r2: [f32; 3],
    odd: bool,
    l: Light,
) -> i32 {
    // The contract's expression, written once (multiplicity::ref_expr).
    let s = crate::multiplicity::ref_expr(r0, r1, r2, l);
    // The odd permutation's flip on the float, before the comparisons:
    // negation (the sign bit flipped) is exact, so the sign of `-s` is
    // minus the sign of `s` (0 for both zeros and for NaN), and the
    // vectorised kernels flip a bit instead of negating bytes and blending.
    let s = f32::from_bits(s.to_bits() ^ (u32::from(odd) << 31));
    (s > 0.0) as i32 - (s < 0.0) as i32
}

#[inline(always)]
fn xyz(r: &[f32], at: usize) -> [f32; 3] {
    [r[at], r[at + 1], r[at + 2]]
}

/// Records per block: one AVX2 vector of f32 lanes.
pub const LANES: usize = 8;

/// One corner of [`LANES`] triangles, structure of arrays: `[x, y, z][lane]`.
pub(crate) type Corner = [[f32; LANES]; 3];

/// Reads the corner at float offset `off` of [`LANES`] consecutive records
/// of `stride` floats (each corner a vec4 `x, y, z, w`) into lanes.
///
/// With `AVX2` it loads each vec4 whole and transposes 4×4 blocks with
/// unpack shuffles (7 shuffles per 8 corners); the element-by-element copy
/// of the plain version compiles to one insert per float, which on AVX2 was
/// the bottleneck of the whole kernel. Either way the lanes hold the same
/// bits: loads and shuffles do not touch values.
#[inline(always)]
fn load_corner<const AVX2: bool>(r: &[f32], stride: usize, off: usize, dst: &mut Corner) {
    #[cfg(target_arch = "x86_64")]
    if AVX2 {
        // SAFETY: `AVX2` is true only in code compiled with the `avx2`
        // feature, which runs only after `is_x86_feature_detected!("avx2")`.
        unsafe { load_corner_avx2(r, stride, off, dst) };
        return;
    }
    let r = &r[..LANES * stride];
    for i in 0..LANES {
        for (a, lane) in dst.iter_mut().enumerate() {
            lane[i] = r[stride * i + off + a];
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn load_corner_avx2(r: &[f32], stride: usize, off: usize, dst: &mut Corner) {
    let r = &r[..LANES * stride];
    let rows: [&[f32; 4]; LANES] =
        std::array::from_fn(|i| r[stride * i + off..][..4].try_into().unwrap());
    load_rows_avx2(rows, dst)
}

/// The two-source permutes that split 16 triangles, given as 48 `u32`
/// (three per triangle) in three 512-bit vectors, into one vector per
/// corner: lane i of corner c is word 3i + c. The first permute takes the
/// words below 32 from the first two vectors; the second keeps those lanes
/// and takes the rest from the third. Used by the caps' AVX-512 kernel
/// (`evaluate_indexed`) and the topology's first pass (`count_avx512`).
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct TriangleCorners16 {
    perm: [(std::arch::x86_64::__m512i, std::arch::x86_64::__m512i); 3],
}

#[cfg(target_arch = "x86_64")]
impl TriangleCorners16 {
    /// The permutes' index vectors.
    #[target_feature(enable = "avx512f")]
    pub(crate) fn new() -> Self {
        use std::arch::x86_64::*;
        let vector = |f: &dyn Fn(u32) -> u32| -> __m512i {
            let idx: [u32; 16] = std::array::from_fn(|i| f(i as u32));
            // SAFETY: 16 u32 are 64 bytes.
            unsafe { _mm512_loadu_si512(idx.as_ptr().cast()) }
        };
        let perm = [0, 1, 2].map(|c| {
            (
                vector(&|i| (3 * i + c) & 31),
                vector(&|i| if 3 * i + c < 32 { i } else { 3 * i + c - 16 }),
            )
        });
        TriangleCorners16 { perm }
    }

    /// Corner `c` (0, 1 or 2) of the 16 triangles in `v`.
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub(crate) fn corner(
        &self,
        v: &[std::arch::x86_64::__m512i; 3],
        c: usize,
    ) -> std::arch::x86_64::__m512i {
        use std::arch::x86_64::*;
        let (a, b) = self.perm[c];
        _mm512_permutex2var_epi32(_mm512_permutex2var_epi32(v[0], a, v[1]), b, v[2])
    }
}

/// `dst[a][i] = rows[i][a]` for `a` in x, y, z: [`LANES`] vec4s (anywhere
/// in memory) transposed into lanes, with AVX2: each vec4 loaded whole and
/// 4×4 blocks transposed with unpack shuffles (7 shuffles per 8 corners).
/// Loads and shuffles do not touch values, so the lanes hold the same bits
/// as an element-by-element copy.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) fn load_rows_avx2(rows: [&[f32; 4]; LANES], dst: &mut Corner) {
    use std::arch::x86_64::*;
    let mut v = [_mm256_setzero_ps(); 4];
    for (i, v) in v.iter_mut().enumerate() {
        // SAFETY: each row is 4 floats; unaligned loads.
        *v = unsafe {
            _mm256_insertf128_ps::<1>(
                _mm256_castps128_ps256(_mm_loadu_ps(rows[i].as_ptr())),
                _mm_loadu_ps(rows[i + 4].as_ptr()),
            )
        };
    }
    // v[i] = (x, y, z, w) of row i | of row i + 4. Per 128-bit half:
    let t0 = _mm256_unpacklo_ps(v[0], v[1]); // x0 x1 y0 y1
    let t1 = _mm256_unpackhi_ps(v[0], v[1]); // z0 z1 w0 w1
    let t2 = _mm256_unpacklo_ps(v[2], v[3]); // x2 x3 y2 y3
    let t3 = _mm256_unpackhi_ps(v[2], v[3]); // z2 z3 w2 w3
    let lo64 = |a: __m256, b: __m256| {
        _mm256_castpd_ps(_mm256_unpacklo_pd(_mm256_castps_pd(a), _mm256_castps_pd(b)))
    };
    let hi64 = |a: __m256, b: __m256| {
        _mm256_castpd_ps(_mm256_unpackhi_pd(_mm256_castps_pd(a), _mm256_castps_pd(b)))
    };
    // SAFETY: each destination is 8 floats; unaligned stores.
    unsafe {
        _mm256_storeu_ps(dst[0].as_mut_ptr(), lo64(t0, t2)); // x0 x1 x2 x3 | x4 x5 x6 x7
        _mm256_storeu_ps(dst[1].as_mut_ptr(), hi64(t0, t2)); // y
        _mm256_storeu_ps(dst[2].as_mut_ptr(), lo64(t1, t3)); // z
    }
}

/// [`tri_sign_nb`] of [`LANES`] triangles `(p0, p1, p2)` given as lanes. A
/// fixed-count loop over a straight-line body: LLVM vectorises it, one
/// vector instruction per operation of the contract.
#[inline(always)]
fn signs8(p0: &Corner, p1: &Corner, p2: &Corner, l: Light) -> [i32; LANES] {
    let mut out = [0i32; LANES];
    for (i, o) in out.iter_mut().enumerate() {
        let c = |p: &Corner| [p[0][i], p[1][i], p[2][i]];
        *o = tri_sign_nb(c(p0), c(p1), c(p2), l);
    }
    out
}

/// The caps loop: blocks of [`LANES`] records (12 floats each), then the
/// tail record by record through the same [`tri_sign_nb`].
#[inline(always)]
fn caps_impl<const AVX2: bool>(data: &[f32], l: Light, out: &mut [i8]) {
    let mut blocks = out.chunks_exact_mut(LANES);
    let mut recs = data.chunks_exact(LANES * 12);
    for (o, r) in (&mut blocks).zip(&mut recs) {
        let mut p = [[[0f32; LANES]; 3]; 3];
        for (c, p) in p.iter_mut().enumerate() {
            load_corner::<AVX2>(r, 12, 4 * c, p);
        }
        let s = signs8(&p[0], &p[1], &p[2], l);
        for (o, s) in o.iter_mut().zip(s) {
            *o = s as i8;
        }
    }
    let tail = blocks.into_remainder();
    for (o, r) in tail.iter_mut().zip(recs.remainder().chunks_exact(12)) {
        *o = tri_sign_nb(xyz(r, 0), xyz(r, 4), xyz(r, 8), l) as i8;
    }
}

fn caps_plain(data: &[f32], l: Light, out: &mut [i8]) {
    caps_impl::<false>(data, l, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn caps_avx2(data: &[f32], l: Light, out: &mut [i8]) {
    caps_impl::<true>(data, l, out)
}

/// True when the AVX2 versions may run.
#[inline]
pub(crate) fn have_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Set by [`disable_avx512`].
static AVX512_OFF: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Makes the evaluator skip its AVX-512 kernels (AVX2 then runs where the
/// CPU has it), and the topology its AVX-512 passes (its AVX2 count and
/// emit then run where the CPU has AVX2), until called again
/// with `false`. For benchmarks, which time both in one run; results are
/// bit for bit the same either way.
#[doc(hidden)]
pub fn disable_avx512(off: bool) {
    AVX512_OFF.store(off, std::sync::atomic::Ordering::Relaxed);
}

/// What [`prefer_gather_caps`] set: 0 the measurement decides, 1 yes, 2 no.
static GATHER_CAPS: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(0);

/// With `Some(yes)`, makes [`gather_caps`] answer `yes` (where the CPU has
/// AVX-512) for any table, whatever the measurement; with None, leaves it
/// to the measurement again. For benchmarks, which time the caps kernel
/// with gathers against the one without in one run; results are bit for
/// bit the same either way.
#[doc(hidden)]
pub fn prefer_gather_caps(choice: Option<bool>) {
    let v = match choice {
        None => 0,
        Some(true) => 1,
        Some(false) => 2,
    };
    GATHER_CAPS.store(v, std::sync::atomic::Ordering::Relaxed);
}

/// Whether the caps from corner ids (`evaluate_indexed`) should take the
/// AVX-512 kernel, which fetches the corners with gathers, rather than the
/// copies that load each corner's row and transpose: where the CPU has
/// AVX-512 ([`have_avx512`]), for a table that is `large` enough to pay
/// for asking, when the gathers measured faster on this CPU
/// (`evaluate_indexed::gathers_pay`, once per process), unless
/// [`prefer_gather_caps`] says otherwise (for any table). Why measured: the three CPUs
/// this project's machine has run on disagree, and two of them are
/// Intel's. On a Sapphire Rapids Xeon (sixth round) the kernel took the
/// shared evaluation of the dragon from 2.8–3.6 to 1.8 ns per side
/// record; on an EPYC of family 25, model 17 (Zen 4, twenty-fifth round)
/// the dragon's caps took 3.02 ms with it and 1.84 ms without, the shared
/// evaluation 5.25 and 3.66 ms (fastest of 40 alternated rounds, `cargo
/// run --release --example stage_probe -- evaluate
/// target/dragon/dragon.glb`); so until the fifty-first round the rule was
/// the vendor's, Intel yes. On an Intel Xeon at 2.8 GHz with AVX-512
/// (fifty-first round) the dragon's caps took 4.78–4.91 ms with the
/// gathers and 1.32–1.47 without. The sides' gathers (`try_sides_from_caps`)
/// still gained on the EPYC: 2.48 → 1.75 ms (`RAYON_NUM_THREADS=1
/// SVPACK_BENCH_ONLY=dragon_full cargo bench --bench evaluate --
/// 'dragon_full/sides_given_caps'`).
pub(crate) fn gather_caps(large: bool) -> bool {
    let setting = GATHER_CAPS.load(std::sync::atomic::Ordering::Relaxed);
    // AVX-512 first: the measurement runs the AVX-512 kernel.
    have_avx512() && gather_caps_for(setting, large, measured_gathers_pay)
}

/// `evaluate_indexed::gathers_pay` where there is one.
fn measured_gathers_pay() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        crate::evaluate_indexed::gathers_pay()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`gather_caps`] after the check for AVX-512: the setting (as in
/// `GATHER_CAPS`), else for a `large` table the measurement (`measured`
/// asked only then), else no.
fn gather_caps_for(setting: u8, large: bool, measured: impl FnOnce() -> bool) -> bool {
    match setting {
        0 => large && measured(),
        v => v == 1,
    }
}

/// Whether the AVX-512 kernels run: the CPU has AVX-512F (run-time check;
/// they also use AVX2, which every AVX-512F CPU has) and
/// [`disable_avx512`] has not turned them off.
pub(crate) fn have_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        !AVX512_OFF.load(std::sync::atomic::Ordering::Relaxed)
            && std::arch::is_x86_feature_detected!("avx512f")
            && have_avx2()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// True when code compiled with AVX-512F, VL, BW and DQ may run (the caps
/// kernel's `evaluate_indexed::Kernel::Avx512Vl`, the weld's
/// `Wide::Avx512`): as [`have_avx512`], with the three other subsets too.
#[inline]
pub(crate) fn have_avx512vl() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        have_avx512()
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512dq")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Reference orientation of every caps record (12 floats each):
/// `out[t] = tri_sign(P0, P1, P2, l)` of record `t`, bit for bit.
/// `data.len()` must be `12 · out.len()`.
pub fn cap_signs(data: &[f32], l: Light, out: &mut [i8]) {
    assert_eq!(data.len(), out.len() * 12, "caps size mismatch");
    #[cfg(target_arch = "x86_64")]
    if have_avx2() {
        // SAFETY: the CPU has AVX2 (checked just above).
        return unsafe { caps_avx2(data, l, out) };
    }
    caps_plain(data, l, out)
}

/// Sides record by record, as the shader does: every record `(A, B, O_0 …
/// O_{k−1})` sums `tri_sign(A, B, O_j)` over its slots. Blocks of [`LANES`]
/// records share the lanes of A and B across the `k` slots.
#[inline(always)]
fn sides_impl<const AVX2: bool>(k: usize, data: &[f32], l: Light, out: &mut [i8]) {
    let stride = (2 + k) * 4;
    let mut blocks = out.chunks_exact_mut(LANES);
    let mut recs = data.chunks_exact(LANES * stride);
    for (o, r) in (&mut blocks).zip(&mut recs) {
        let mut a = [[0f32; LANES]; 3];
        let mut b = [[0f32; LANES]; 3];
        let mut q = [[0f32; LANES]; 3];
        load_corner::<AVX2>(r, stride, 0, &mut a);
        load_corner::<AVX2>(r, stride, 4, &mut b);
        let mut sum = [0i32; LANES];
        for j in 0..k {
            load_corner::<AVX2>(r, stride, 8 + 4 * j, &mut q);
            let s = signs8(&a, &b, &q, l);
            for (m, s) in sum.iter_mut().zip(s) {
                *m += s;
            }
        }
        for (o, m) in o.iter_mut().zip(sum) {
            *o = m as i8;
        }
    }
    let tail = blocks.into_remainder();
    for (m, r) in tail.iter_mut().zip(recs.remainder().chunks_exact(stride)) {
        let (a, b) = (xyz(r, 0), xyz(r, 4));
        let mut sum = 0i32;
        for j in 0..k {
            sum += tri_sign_nb(a, b, xyz(r, 8 + 4 * j), l);
        }
        *m = sum as i8;
    }
}

fn sides_plain(k: usize, data: &[f32], l: Light, out: &mut [i8]) {
    sides_impl::<false>(k, data, l, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn sides_avx2(k: usize, data: &[f32], l: Light, out: &mut [i8]) {
    sides_impl::<true>(k, data, l, out)
}

/// Reference multiplicity of every record of a sides bucket with `k`
/// opposite slots, record by record (what the sides shader computes), bit
/// for bit [`crate::multiplicity::edge_multiplicity`]. `data.len()` must be
/// `(2 + k) · 4 · out.len()`.
pub fn side_multiplicities(k: usize, data: &[f32], l: Light, out: &mut [i8]) {
    assert_eq!(data.len(), out.len() * (2 + k) * 4, "bucket size mismatch");
    #[cfg(target_arch = "x86_64")]
    if have_avx2() {
        // SAFETY: the CPU has AVX2 (checked just above).
        return unsafe { sides_avx2(k, data, l, out) };
    }
    sides_plain(k, data, l, out)
}

/// Sum of `parity[j] · caps[tri[j]]` per record of `K` slots. The caller
/// has checked every index against `caps.len()`, so the loop has no branch.
///
/// # Safety
/// Every `tri` entry must be below `caps.len()`.
#[inline(always)]
unsafe fn gather_body<const K: usize>(tri: &[u32], parity: &[i8], caps: &[i8], out: &mut [i8]) {
    for ((m, t), p) in out
        .iter_mut()
        .zip(tri.chunks_exact(K))
        .zip(parity.chunks_exact(K))
    {
        let mut sum = 0i32;
        for j in 0..K {
            // SAFETY: the caller guarantees t[j] < caps.len().
            let c = unsafe { *caps.get_unchecked(t[j] as usize) };
            sum += p[j] as i32 * c as i32;
        }
        *m = sum as i8;
    }
}

/// [`gather_body`] for `K` = 1 or 2 with AVX-512, 16 records per step: the
/// signs of 16 slots fetched with one gather (four bytes at each index; the
/// low one is the sign), multiplied by the slots' parities, and for `K` = 2
/// the two slots of each record added after an even/odd de-interleave, then
/// truncated to bytes. Integer sums of at most two −1/0/+1 terms: exact in
/// any order, and they fit an i8. The tail goes through [`gather_body`].
///
/// Returns `false`, with `out` partly written, at the first index that is
/// not below `caps.len() − 3` (the four-byte reads must stay inside caps);
/// nothing past `caps` is read.
///
/// # Safety
/// The CPU must have AVX-512F, and `caps.len()` must be at most `i32::MAX`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2")]
unsafe fn sides_avx512<const K: usize>(
    tri: &[u32],
    parity: &[i8],
    caps: &[i8],
    out: &mut [i8],
) -> bool {
    use std::arch::x86_64::*;
    const W: usize = 16;
    // Indices the four-byte reads may start at: below caps.len() − 3.
    let Some(limit) = caps.len().checked_sub(3) else {
        return false;
    };
    let limit_v = _mm512_set1_epi32(limit as i32);
    let base = caps.as_ptr();
    // Slot signs times parities of 16 consecutive slots, as i32 lanes, or
    // None when an index is out of the gather's range.
    let products = |t: &[u32], p: &[i8]| -> Option<__m512i> {
        // SAFETY: t holds 16 u32 and p 16 i8; the gather runs only when
        // every index + 3 < caps.len() (the compare just before), so each
        // four-byte read is inside caps.
        unsafe {
            let idx = _mm512_loadu_si512(t.as_ptr().cast());
            if _mm512_cmplt_epu32_mask(idx, limit_v) != 0xFFFF {
                return None;
            }
            // The low byte is the slot's sign; the three above it belong
            // to the next triangles and are left in: the sums are taken
            // modulo 2^32 and truncated to their low byte at the end, and
            // the low byte of a product or sum depends only on its terms'
            // low bytes.
            let word = _mm512_i32gather_epi32::<1>(idx, base.cast());
            let par = _mm512_cvtepi8_epi32(_mm_loadu_si128(p.as_ptr().cast()));
            Some(_mm512_mullo_epi32(word, par))
        }
    };
    let even: [u32; W] = std::array::from_fn(|i| 2 * i as u32);
    let odd: [u32; W] = std::array::from_fn(|i| 2 * i as u32 + 1);
    // SAFETY: 16 u32 are 64 bytes.
    let (even, odd) = unsafe {
        (
            _mm512_loadu_si512(even.as_ptr().cast()),
            _mm512_loadu_si512(odd.as_ptr().cast()),
        )
    };
    let mut blocks = out.chunks_exact_mut(W);
    let mut tris = tri.chunks_exact(W * K);
    let mut pars = parity.chunks_exact(W * K);
    for ((o, t), p) in (&mut blocks).zip(&mut tris).zip(&mut pars) {
        let sum = if K == 1 {
            let Some(a) = products(t, p) else {
                return false;
            };
            a
        } else {
            let (Some(a), Some(b)) = (products(&t[..W], &p[..W]), products(&t[W..], &p[W..]))
            else {
                return false;
            };
            _mm512_add_epi32(
                _mm512_permutex2var_epi32(a, even, b),
                _mm512_permutex2var_epi32(a, odd, b),
            )
        };
        // SAFETY: o holds 16 bytes.
        unsafe { _mm_storeu_si128(o.as_mut_ptr().cast(), _mm512_cvtepi32_epi8(sum)) };
    }
    let tail = tris.remainder();
    if tail.iter().any(|&t| t as usize >= caps.len()) {
        return false;
    }
    let n = blocks.into_remainder().len();
    let at = out.len() - n;
    // SAFETY: every tail index was checked against caps.len() just above.
    unsafe { gather_body::<K>(tail, pars.remainder(), caps, &mut out[at..]) };
    true
}

/// Side multiplicities as signed sums of already evaluated triangle signs:
/// record `r` gets `Σ_j parity[r·k + j] · caps[tri[r·k + j]]`. Every `tri`
/// entry must index `caps` (the caller routes records with unknown slots
/// elsewhere); panics otherwise.
pub fn sides_from_caps(k: usize, tri: &[u32], parity: &[i8], caps: &[i8], out: &mut [i8]) {
    assert!(
        try_sides_from_caps(k, tri, parity, caps, out),
        "slot names a triangle past the caps"
    );
}

/// [`sides_from_caps`], or `false` when some slot names no triangle (`tri`
/// entry `>= caps.len()`, e.g. the `u32::MAX` of a slot with no matching
/// cap in a damaged file); `out` is then unspecified, and the caller
/// computes it another way.
///
/// With AVX-512 (`k` = 1 or 2) the kernel checks each block's indices with
/// one vector compare before its gather; elsewhere, and when an index is in
/// the last three caps (which the kernel's four-byte reads would pass), one
/// vectorised pass over the indices checks them all and the summing loop
/// runs without a bounds check per slot. A separate pass read the indices
/// twice: it took as long as the AVX-512 kernel itself.
pub fn try_sides_from_caps(
    k: usize,
    tri: &[u32],
    parity: &[i8],
    caps: &[i8],
    out: &mut [i8],
) -> bool {
    assert_eq!(tri.len(), out.len() * k, "slot table size mismatch");
    assert_eq!(parity.len(), tri.len(), "slot table size mismatch");
    #[cfg(target_arch = "x86_64")]
    if (k == 1 || k == 2) && have_avx512() && caps.len() <= i32::MAX as usize {
        // SAFETY: the CPU has AVX-512F and caps.len() fits an i32.
        let done = unsafe {
            if k == 1 {
                sides_avx512::<1>(tri, parity, caps, out)
            } else {
                sides_avx512::<2>(tri, parity, caps, out)
            }
        };
        if done {
            return true;
        }
    }
    let max = tri.iter().fold(0u32, |a, &t| a.max(t));
    if !tri.is_empty() && max as usize >= caps.len() {
        return false;
    }
    // SAFETY: every index was checked against caps.len() just above.
    unsafe {
        match k {
            1 => gather_body::<1>(tri, parity, caps, out),
            2 => gather_body::<2>(tri, parity, caps, out),
            3 => gather_body::<3>(tri, parity, caps, out),
            4 => gather_body::<4>(tri, parity, caps, out),
            5 => gather_body::<5>(tri, parity, caps, out),
            _ => {
                for ((m, t), p) in out
                    .iter_mut()
                    .zip(tri.chunks_exact(k))
                    .zip(parity.chunks_exact(k))
                {
                    let mut sum = 0i32;
                    for (&t, &p) in t.iter().zip(p) {
                        sum += p as i32 * *caps.get_unchecked(t as usize) as i32;
                    }
                    *m = sum as i8;
                }
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    //! The kernels against the scalar contract ([`tri_sign`], which is the
    //! transcription of format-spec/multiplicity.md), bit for bit: every
    //! compiled version (plain, AVX2 when the CPU has it, and the run-time
    //! dispatch), block lengths with and without a tail, and inputs chosen to
    //! hit every tie of the lexicographic order, every exact zero of the
    //! expression and values the rounding order changes.
    use super::*;
    use crate::multiplicity::tri_sign;

    type CapsFn = fn(&[f32], Light, &mut [i8]);
    type SidesFn = fn(usize, &[f32], Light, &mut [i8]);

    /// Every compiled version of the caps loop this machine can run.
    fn caps_versions() -> Vec<(&'static str, CapsFn)> {
        let mut v: Vec<(&'static str, CapsFn)> =
            vec![("plain", caps_plain), ("dispatch", cap_signs)];
        #[cfg(target_arch = "x86_64")]
        if have_avx2() {
            // SAFETY: only when the CPU has AVX2.
            v.push(("avx2", |d, l, o| unsafe { caps_avx2(d, l, o) }));
        }
        v
    }

    /// Every compiled version of the per-record sides loop.
    fn sides_versions() -> Vec<(&'static str, SidesFn)> {
        let mut v: Vec<(&'static str, SidesFn)> =
            vec![("plain", sides_plain), ("dispatch", side_multiplicities)];
        #[cfg(target_arch = "x86_64")]
        if have_avx2() {
            // SAFETY: only when the CPU has AVX2.
            v.push(("avx2", |k, d, l, o| unsafe { sides_avx2(k, d, l, o) }));
        }
        v
    }

    /// Xorshift64, fixed seeds: failures reproduce.
    struct Gen(u64);

    impl Gen {
        fn u(&mut self) -> u64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            self.0
        }
        fn below(&mut self, n: u64) -> usize {
            (self.u() % n) as usize
        }
        /// Uniform in [-1, 1).
        fn unit(&mut self) -> f32 {
            (self.u() >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
        }
        /// A coordinate: ties and exact zeros are common, and so are values
        /// whose products round.
        fn coord(&mut self) -> f32 {
            const LATTICE: [f32; 9] = [-1.0, -0.5, -0.0, 0.0, 0.0, 0.5, 1.0, 1.5, 3.0];
            match self.below(8) {
                0..=2 => LATTICE[self.below(LATTICE.len() as u64)],
                3 => self.unit() * 1e-6,
                4 => self.unit() * 1e6,
                5 => 1.0 + self.below(8) as f32 * f32::EPSILON,
                _ => self.unit(),
            }
        }
        fn point(&mut self) -> [f32; 3] {
            [self.coord(), self.coord(), self.coord()]
        }
        /// A triangle: generic, with duplicate corners, with corners equal
        /// but for the sign of a zero, nearly flat, or on a lattice.
        fn tri(&mut self) -> [[f32; 3]; 3] {
            let mut t = [self.point(), self.point(), self.point()];
            match self.below(6) {
                0 => t[self.below(3)] = t[self.below(3)],
                1 => {
                    let (i, j) = (self.below(3), self.below(3));
                    t[i] = t[j].map(|v| if v == 0.0 { -v } else { v });
                }
                2 => {
                    for p in &mut t {
                        p[2] = 0.1 * p[0] + 0.37 * p[1];
                    }
                }
                3 => {
                    // Two corners share x, or x and y: the deeper ties.
                    let (i, j) = (self.below(3), self.below(3));
                    t[i][0] = t[j][0];
                    if self.below(2) == 0 {
                        t[i][1] = t[j][1];
                    }
                }
                _ => {}
            }
            t
        }
        /// A light placed against triangle `t`: on a corner (also with a
        /// zero of the other sign), on an edge line, in its plane, parallel
        /// to it, or anywhere; point and directional.
        fn light(&mut self, t: [[f32; 3]; 3]) -> Light {
            let (a, b, c) = (t[0], t[1], t[2]);
            let p = |v: [f32; 3], w: f32| [v[0], v[1], v[2], w];
            match self.below(9) {
                0 => p(t[self.below(3)], 1.0),
                1 => p(t[self.below(3)].map(|v| if v == 0.0 { -v } else { v }), 1.0),
                2 => p([0, 1, 2].map(|k| 2.0 * b[k] - a[k]), 1.0),
                3 => p([0, 1, 2].map(|k| b[k] + c[k] - a[k]), 1.0),
                4 => p([0, 1, 2].map(|k| b[k] - a[k]), 0.0),
                5 => p(self.point(), 0.0),
                6 => p([0.0, -0.0, 0.0], 0.0),
                _ => p(self.point(), 1.0),
            }
        }
    }

    /// Caps records (12 floats each, `.w` = 1) of triangles in every corner
    /// order, so both parities of each sorting permutation occur.
    fn caps_records(tris: &[[[f32; 3]; 3]]) -> Vec<f32> {
        let mut d = Vec::new();
        for t in tris {
            for p in crate::multiplicity::PERMS {
                for i in p {
                    d.extend_from_slice(&t[i]);
                    d.push(1.0);
                }
            }
        }
        d
    }

    fn check_caps(data: &[f32], l: Light, what: &str) {
        let n = data.len() / 12;
        let want: Vec<i8> = data
            .chunks_exact(12)
            .map(|r| tri_sign(xyz(r, 0), xyz(r, 4), xyz(r, 8), l) as i8)
            .collect();
        for (name, f) in caps_versions() {
            // Every length up to the whole: blocks plus each tail size.
            for len in [
                n,
                n.saturating_sub(1),
                n.saturating_sub(7),
                n / 2 + 3,
                9,
                7,
                1,
                0,
            ] {
                let len = len.min(n);
                let mut got = vec![9i8; len];
                f(&data[..12 * len], l, &mut got);
                for (t, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(
                        g,
                        w,
                        "{name} {what}: record {t} of {len}, light {l:?}, corners {:?}",
                        &data[12 * t..12 * t + 12]
                    );
                }
            }
        }
    }

    /// The caps' choice of kernel follows the benchmarks' setting for any
    /// table, and with none the measurement, asked only for a large table
    /// (the setting itself is not changed here: other tests set it while
    /// they run). Caught: the setting ignored (the measurement alone
    /// decides); the measurement asked for a small table.
    #[test]
    fn gather_caps_follow_the_setting_then_the_measurement() {
        for faster in [false, true] {
            assert_eq!(gather_caps_for(0, true, || faster), faster);
            assert!(!gather_caps_for(0, false, || panic!("measured")));
            for large in [false, true] {
                assert!(gather_caps_for(1, large, || panic!("measured")));
                assert!(!gather_caps_for(2, large, || panic!("measured")));
            }
        }
    }

    #[test]
    fn caps_kernel_is_the_contract_bit_for_bit() {
        let mut g = Gen(0x9E37_79B9_7F4A_7C15);
        let mut nonzero = [0usize; 3];
        for round in 0..3000 {
            // Up to 7 triangles × 6 orders = 42 records: blocks and tails.
            let n = 1 + g.below(7);
            let tris: Vec<_> = (0..n).map(|_| g.tri()).collect();
            let at = g.below(n as u64);
            let l = g.light(tris[at]);
            let data = caps_records(&tris);
            for r in data.chunks_exact(12) {
                nonzero[(tri_sign(xyz(r, 0), xyz(r, 4), xyz(r, 8), l) + 1) as usize] += 1;
            }
            check_caps(&data, l, &format!("round {round}"));
        }
        // The inputs exercise all three answers, not just the easy ones.
        assert!(nonzero.iter().all(|&c| c > 1000), "{nonzero:?}");
    }

    #[test]
    fn caps_kernel_matches_on_a_long_run_of_random_triangles() {
        // 8 · 125 + 5 records per light through the vectorised blocks.
        let mut g = Gen(42);
        for _ in 0..40 {
            let tris: Vec<_> = (0..(8 * 125 + 5) / 6 + 1).map(|_| g.tri()).collect();
            let l = g.light(tris[0]);
            let mut data = caps_records(&tris);
            data.truncate(12 * (8 * 125 + 5));
            check_caps(&data, l, "long run");
        }
    }

    #[test]
    fn caps_kernel_matches_outside_the_contract_too() {
        // Infinities, NaN and huge values are outside the contract, but the
        // branch-free comparisons are the scalar ones on every input, so even
        // here the answers agree.
        let odd = [
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::MAX,
            -f32::MAX,
            1e-40,
            -1e-40,
        ];
        let mut g = Gen(7);
        for _ in 0..2000 {
            let mut tris: Vec<_> = (0..3).map(|_| g.tri()).collect();
            for t in &mut tris {
                if g.below(2) == 0 {
                    t[g.below(3)][g.below(3)] = odd[g.below(odd.len() as u64)];
                }
            }
            let mut l = g.light(tris[0]);
            if g.below(4) == 0 {
                l[g.below(3)] = odd[g.below(odd.len() as u64)];
            }
            check_caps(&caps_records(&tris), l, "odd values");
        }
    }

    /// A sides bucket of `n` records with `k` slots: A and B usually in the
    /// file's order (`A < B`), sometimes not (a damaged record, which the
    /// shader still evaluates through the full sort).
    fn bucket(g: &mut Gen, k: usize, n: usize) -> (Vec<f32>, Light) {
        let mut d = Vec::new();
        let mut l = [0.0; 4];
        for r in 0..n {
            let t = g.tri();
            let (mut a, mut b) = (t[0], t[1]);
            if g.below(8) != 0 && crate::multiplicity::lex_less(b, a) {
                std::mem::swap(&mut a, &mut b);
            }
            if r == 0 {
                l = g.light(t);
            }
            d.extend_from_slice(&[a[0], a[1], a[2], k as f32, b[0], b[1], b[2], k as f32]);
            for j in 0..k {
                let o = if j == 0 { t[2] } else { g.tri()[g.below(3)] };
                d.extend_from_slice(&[o[0], o[1], o[2], 1.0]);
            }
        }
        (d, l)
    }

    #[test]
    fn sides_kernel_is_the_contract_bit_for_bit() {
        let mut g = Gen(1234567);
        for round in 0..1500 {
            let k = 1 + g.below(7); // 6 and 7 take the run-time-k path
            let n = [0, 1, 7, 8, 9, 16, 23, 8 * 6 + 5][g.below(8)];
            let (data, l) = bucket(&mut g, k, n);
            let want: Vec<i8> = data
                .chunks_exact((2 + k) * 4)
                .map(|r| {
                    let o: Vec<[f32; 3]> = (0..k).map(|j| xyz(r, 8 + 4 * j)).collect();
                    crate::multiplicity::edge_multiplicity(xyz(r, 0), xyz(r, 4), &o, l) as i8
                })
                .collect();
            for (name, f) in sides_versions() {
                let mut got = vec![99i8; n];
                f(k, &data, l, &mut got);
                assert_eq!(
                    got, want,
                    "{name} round {round}: k = {k}, n = {n}, light {l:?}"
                );
            }
        }
    }

    #[test]
    fn gather_equals_the_per_slot_sum() {
        let mut g = Gen(99);
        let caps: Vec<i8> = (0..1000).map(|_| g.below(3) as i8 - 1).collect();
        // Indices up to the last cap (the AVX-512 path declines those: its
        // four-byte reads would pass the end) and up to the fourth from
        // last (it takes them); the bytes after each index are other
        // triangles' signs, which the kernel's truncation must discard.
        for (k, bound) in (1..=8).flat_map(|k| [(k, 1000), (k, 997)]) {
            for n in [0, 1, 5, 15, 16, 17, 64, 333] {
                let tri: Vec<u32> = (0..n * k).map(|_| g.below(bound) as u32).collect();
                let par: Vec<i8> = (0..n * k).map(|_| g.below(3) as i8 - 1).collect();
                let want: Vec<i8> = tri
                    .chunks_exact(k)
                    .zip(par.chunks_exact(k))
                    .map(|(t, p)| {
                        t.iter()
                            .zip(p)
                            .map(|(&t, &p)| p as i32 * caps[t as usize] as i32)
                            .sum::<i32>() as i8
                    })
                    .collect();
                let mut got = vec![0i8; n];
                sides_from_caps(k, &tri, &par, &caps, &mut got);
                assert_eq!(got, want, "k = {k}, n = {n}, bound {bound}");
                // Each compiled body directly, not only the dispatch.
                if k <= 2 {
                    let mut got = vec![0i8; n];
                    // SAFETY: every index is below caps.len().
                    unsafe {
                        if k == 1 {
                            gather_body::<1>(&tri, &par, &caps, &mut got)
                        } else {
                            gather_body::<2>(&tri, &par, &caps, &mut got)
                        }
                    }
                    assert_eq!(got, want, "plain, k = {k}, n = {n}");
                }
                #[cfg(target_arch = "x86_64")]
                if have_avx512() && bound == 997 && k <= 2 {
                    let mut got = vec![0i8; n];
                    // SAFETY: the CPU has AVX-512F.
                    let done = unsafe {
                        if k == 1 {
                            sides_avx512::<1>(&tri, &par, &caps, &mut got)
                        } else {
                            sides_avx512::<2>(&tri, &par, &caps, &mut got)
                        }
                    };
                    assert!(done, "avx512 declined, k = {k}, n = {n}");
                    assert_eq!(got, want, "avx512, k = {k}, n = {n}");
                }
            }
        }
    }

    #[test]
    fn gather_declines_a_slot_with_no_triangle_anywhere() {
        // A damaged file's unknown slot (u32::MAX) or an index one past the
        // caps, in the first block, a middle block and the tail, for k = 1
        // and 2 (the AVX-512 kernel where the CPU has it) and k = 3.
        let caps = vec![1i8; 500];
        for k in 1..=3 {
            let n = 40;
            for at in [0, 16 * k + 3, n * k - 1] {
                for bad in [u32::MAX, 500] {
                    let mut tri: Vec<u32> = (0..(n * k) as u32).map(|i| i % 500).collect();
                    tri[at] = bad;
                    let par = vec![1i8; n * k];
                    let mut out = vec![0i8; n];
                    assert!(
                        !try_sides_from_caps(k, &tri, &par, &caps, &mut out),
                        "k = {k}, slot {at} = {bad}"
                    );
                }
            }
        }
    }

    #[test]
    #[should_panic(expected = "past the caps")]
    fn gather_refuses_an_index_past_the_caps() {
        let mut out = [0i8; 1];
        sides_from_caps(2, &[0, 3], &[1, 1], &[1, 1, 1], &mut out);
    }
}
