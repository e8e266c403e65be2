//! CPU evaluator: the vertex shaders' decisions, computed on the CPU over the
//! file's own buffers (format-spec/multiplicity.md), for one light at a time.
//!
//! It reads the sides and caps records exactly as the GPU does (flat f32
//! arrays, one record after another). [`Strategy::Reference`], the format's
//! contract, runs the branch-free kernels of [`crate::evaluate_simd`]: the
//! same float expression as [`crate::multiplicity`], operation for
//! operation, vectorised over records because the scalar version's corner
//! sort mispredicts about once per triangle (that, not the arithmetic, was
//! its cost). The scalar loops stay as `*_scalar` functions: the peers in
//! `benches/evaluate.rs` and the oracle the tests compare the kernels with,
//! bit for bit. Work is split over fixed chunks of records with rayon, and
//! every record's result depends on that record alone, so results do not
//! depend on the thread count.

use crate::multiplicity::{Light, lex_less_nb, ref_sign, sort3, tri_sign};

/// How multiplicities and cap orientations are computed. Only
/// [`Strategy::Reference`] is the format's contract (what the shaders do);
/// the others are peers for `svpack verify --evaluator` and
/// `svpack bench --accuracy`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Strategy {
    /// (a) Kim et al. 2008: one light plane per edge, opposite vertices tested
    /// against it; caps oriented by their own plane. Three different float
    /// expressions per triangle, so it can crack.
    Kim,
    /// (b) Pečiva et al. 2013 (thesis ch. 4): every occurrence of a triangle
    /// evaluates Kim's light-plane test for all three of its edges, in one
    /// fixed corner order (lexicographic), and discards the triangle (sign 0)
    /// when the three disagree. Consistent, three plane tests per triangle.
    Peciva,
    /// (c) The format's contract: reference edge in f32 (format-spec/multiplicity.md).
    #[default]
    Reference,
    /// (d) The reference edge evaluated in f64 on the same sorted corners.
    ReferenceF64,
    /// (e) Exact orientation: the sign of the 4×4 determinant of the
    /// homogeneous corners and light ([`crate::exact::det4_sign`]).
    Exact,
}

impl Strategy {
    /// Every strategy, in the order (a)–(e).
    pub const ALL: [Strategy; 5] = [
        Strategy::Kim,
        Strategy::Peciva,
        Strategy::Reference,
        Strategy::ReferenceF64,
        Strategy::Exact,
    ];

    /// Short name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Kim => "kim",
            Strategy::Peciva => "peciva",
            Strategy::Reference => "reference",
            Strategy::ReferenceF64 => "reference-f64",
            Strategy::Exact => "exact",
        }
    }

    /// Side contribution of opposite vertex `o` to edge `a → b` (`a < b`).
    #[inline(always)]
    pub fn side_sign(self, a: [f32; 3], b: [f32; 3], o: [f32; 3], l: Light) -> i32 {
        match self {
            Strategy::Kim => kim_sign(a, b, o, l),
            Strategy::Peciva => peciva_sign(a, b, o, l),
            Strategy::Reference => tri_sign(a, b, o, l),
            Strategy::ReferenceF64 => tri_sign_f64(a, b, o, l),
            Strategy::Exact => exact_sign(a, b, o, l),
        }
    }

    /// Orientation of the cap `(p0, p1, p2)`.
    #[inline(always)]
    pub fn cap_sign(self, p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], l: Light) -> i32 {
        match self {
            Strategy::Kim => kim_cap_sign(p0, p1, p2, l),
            Strategy::Peciva => peciva_sign(p0, p1, p2, l),
            Strategy::Reference => tri_sign(p0, p1, p2, l),
            Strategy::ReferenceF64 => tri_sign_f64(p0, p1, p2, l),
            Strategy::Exact => exact_sign(p0, p1, p2, l),
        }
    }
}

/// [`tri_sign`]`(a, b, o, l)` for a side record, where the file guarantees
/// `a < b`: O's place among the sorted corners takes two comparisons instead
/// of the three-comparator network, and the corners are chosen without
/// branches (O's position is data-dependent and mispredicts). The float
/// expression evaluated is [`ref_sign`] on the same sorted corners, so the
/// result is bit-for-bit the contract's; when `a < b` does not hold (a
/// corrupt record) it falls back to [`tri_sign`] itself, which is what the
/// shader computes.
#[inline(always)]
pub fn reference_side_sign(a: [f32; 3], b: [f32; 3], o: [f32; 3], l: Light) -> i32 {
    if !lex_less_nb(a, b) {
        return tri_sign(a, b, o, l);
    }
    let before = lex_less_nb(o, a); // (O, A, B): even
    let after = lex_less_nb(b, o); // (A, B, O): even; otherwise (A, O, B): odd
    let r0 = if before { o } else { a };
    let r2 = if after { o } else { b };
    let r1 = if before {
        a
    } else if after {
        b
    } else {
        o
    };
    let parity = if before | after { 1 } else { -1 };
    parity * ref_sign(r0, r1, r2, l)
}

/// Pečiva 2013: Kim's test on all three edges of the triangle in one fixed
/// (lexicographic) corner order; 0 when they disagree. Every occurrence of a
/// triangle computes the same three expressions, so it is consistent.
#[inline(always)]
pub fn peciva_sign(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], l: Light) -> i32 {
    let ([a, b, c], parity) = sort3(p0, p1, p2);
    let s0 = kim_sign(a, b, c, l);
    let s1 = kim_sign(b, c, a, l);
    let s2 = kim_sign(c, a, b, l);
    if s0 == s1 && s1 == s2 { parity * s0 } else { 0 }
}

/// The reference expression of [`crate::multiplicity::ref_sign`] in f64 on
/// the same sorted corners (consistent for the same reason, but rounds far
/// less; still not exact).
#[inline(always)]
pub fn tri_sign_f64(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], l: Light) -> i32 {
    let ([r0, r1, r2], parity) = sort3(p0, p1, p2);
    if l[3] == 1.0 && [r0, r1, r2].contains(&[l[0], l[1], l[2]]) {
        return 0;
    }
    let f = |v: [f32; 3]| v.map(|x| x as f64);
    let (r0, r1, r2) = (f(r0), f(r1), f(r2));
    let l = l.map(|x| x as f64);
    let x = [r2[0] - r0[0], r2[1] - r0[1], r2[2] - r0[2]];
    let y = [
        l[0] - r0[0] * l[3],
        l[1] - r0[1] * l[3],
        l[2] - r0[2] * l[3],
    ];
    let d = [r1[0] - r0[0], r1[1] - r0[1], r1[2] - r0[2]];
    let n = [
        x[1] * y[2] - x[2] * y[1],
        x[2] * y[0] - x[0] * y[2],
        x[0] * y[1] - x[1] * y[0],
    ];
    let s = (n[0] * d[0] + n[1] * d[1]) + n[2] * d[2];
    parity * ((s > 0.0) as i32 - (s < 0.0) as i32)
}

/// Exact orientation of `(p0, p1, p2)` towards the light: +1 when the light
/// sees it counter-clockwise (the sign convention of [`tri_sign`]).
#[inline(always)]
pub fn exact_sign(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], l: Light) -> i32 {
    let h = |p: [f32; 3]| [p[0] as f64, p[1] as f64, p[2] as f64, 1.0];
    // det[P0; P1; P2; L] = −N·(L − P0·w).
    -crate::exact::det4_sign([h(p0), h(p1), h(p2), l.map(|v| v as f64)])
}

/// Kim 2008's per-edge test: side of opposite vertex `o` relative to the
/// plane through edge `a → b` and the light.
#[inline(always)]
pub fn kim_sign(a: [f32; 3], b: [f32; 3], o: [f32; 3], l: Light) -> i32 {
    let e = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    let v = [l[0] - a[0] * l[3], l[1] - a[1] * l[3], l[2] - a[2] * l[3]];
    let n = [
        e[1] * v[2] - e[2] * v[1],
        e[2] * v[0] - e[0] * v[2],
        e[0] * v[1] - e[1] * v[0],
    ];
    let d = [o[0] - a[0], o[1] - a[1], o[2] - a[2]];
    let s = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
    // n = (B − A) × (L − A) points to the side where (A, B, O) is seen
    // counter-clockwise from L when s < 0, matching tri_sign's convention.
    (s < 0.0) as i32 - (s > 0.0) as i32
}

/// Kim 2008's cap test: the triangle's own plane against the light.
#[inline(always)]
pub fn kim_cap_sign(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], l: Light) -> i32 {
    let u = [p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]];
    let w = [p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]];
    let n = [
        u[1] * w[2] - u[2] * w[1],
        u[2] * w[0] - u[0] * w[2],
        u[0] * w[1] - u[1] * w[0],
    ];
    let v = [
        l[0] - p0[0] * l[3],
        l[1] - p0[1] * l[3],
        l[2] - p0[2] * l[3],
    ];
    let s = n[0] * v[0] + n[1] * v[1] + n[2] * v[2];
    (s > 0.0) as i32 - (s < 0.0) as i32
}
use rayon::prelude::*;

/// Records per rayon task: large enough that scheduling costs nothing.
const CHUNK: usize = 4096;

#[inline(always)]
fn xyz(r: &[f32], at: usize) -> [f32; 3] {
    [r[at], r[at + 1], r[at + 2]]
}

/// Multiplicity of every record of a sides bucket with `k` opposite slots
/// (`data` holds `(2 + k) · 4` floats per record). `out.len()` must equal the
/// record count.
pub fn side_multiplicities(k: usize, data: &[f32], light: Light, out: &mut [i8]) {
    side_multiplicities_with(Strategy::Reference, k, data, light, out)
}

/// [`side_multiplicities`] with an explicit strategy.
///
/// [`Strategy::Reference`] runs the branch-free vectorised kernel of
/// [`crate::evaluate_simd`] (bit for bit the contract, tested there); the
/// other strategies, and [`side_multiplicities_scalar`], run the scalar loop.
pub fn side_multiplicities_with(
    strategy: Strategy,
    k: usize,
    data: &[f32],
    light: Light,
    out: &mut [i8],
) {
    if strategy == Strategy::Reference {
        let stride = (2 + k) * 4;
        assert_eq!(data.len(), out.len() * stride, "bucket size mismatch");
        out.par_chunks_mut(CHUNK)
            .zip(data.par_chunks(CHUNK * stride))
            .for_each(|(o, d)| crate::evaluate_simd::side_multiplicities(k, d, light, o));
        return;
    }
    side_multiplicities_scalar(strategy, k, data, light, out)
}

/// [`side_multiplicities_with`] through the scalar per-record loop for every
/// strategy, [`Strategy::Reference`] included: the evaluator as it was before
/// the vectorised kernel, kept as the benchmark's peer and the tests' oracle.
pub fn side_multiplicities_scalar(
    strategy: Strategy,
    k: usize,
    data: &[f32],
    light: Light,
    out: &mut [i8],
) {
    // One monomorphised loop per strategy: the sign function inlines.
    match strategy {
        Strategy::Kim => sides_loop(kim_sign, k, data, light, out),
        Strategy::Peciva => sides_loop(peciva_sign, k, data, light, out),
        Strategy::Reference => sides_loop(reference_side_sign, k, data, light, out),
        Strategy::ReferenceF64 => sides_loop(tri_sign_f64, k, data, light, out),
        Strategy::Exact => sides_loop(exact_sign, k, data, light, out),
    }
}

fn sides_loop<F>(sign: F, k: usize, data: &[f32], light: Light, out: &mut [i8])
where
    F: Fn([f32; 3], [f32; 3], [f32; 3], Light) -> i32 + Sync,
{
    let stride = (2 + k) * 4;
    assert_eq!(data.len(), out.len() * stride, "bucket size mismatch");
    out.par_chunks_mut(CHUNK)
        .zip(data.par_chunks(CHUNK * stride))
        .for_each(|(o, d)| {
            for (m, r) in o.iter_mut().zip(d.chunks_exact(stride)) {
                let a = xyz(r, 0);
                let b = xyz(r, 4);
                let mut sum = 0i32;
                for j in 0..k {
                    sum += sign(a, b, xyz(r, 8 + 4 * j), light);
                }
                *m = sum as i8;
            }
        });
}

/// Side multiplicities from already evaluated cap signs: slot j of a record
/// contributes `slot_parity[j] · caps[slot_tri[j]]`, or is evaluated directly
/// with `strategy` when `slot_tri[j]` is `u32::MAX`. Exact for every
/// consistent strategy (not Kim's), see `verify::DecodedBucket::slot_parity`.
///
/// A chunk of records whose slots all name a triangle (every chunk of an
/// intact file) runs the branch-free gather of
/// [`crate::evaluate_simd::try_sides_from_caps`]; only a chunk with an
/// unknown slot takes the per-slot fallback, so the check costs one pass
/// over the slot indices instead of a branch per slot.
#[allow(clippy::too_many_arguments)]
pub fn side_multiplicities_shared(
    strategy: Strategy,
    k: usize,
    data: &[f32],
    slot_tri: &[u32],
    slot_parity: &[i8],
    caps: &[i8],
    light: Light,
    out: &mut [i8],
) {
    shared_loop(
        true,
        strategy,
        k,
        data,
        slot_tri,
        slot_parity,
        caps,
        light,
        out,
    );
}

/// [`side_multiplicities_shared`] as it was before the vectorised gather:
/// one `caps.get` per slot. The benchmark's peer and the tests' oracle.
#[allow(clippy::too_many_arguments)]
pub fn side_multiplicities_shared_scalar(
    strategy: Strategy,
    k: usize,
    data: &[f32],
    slot_tri: &[u32],
    slot_parity: &[i8],
    caps: &[i8],
    light: Light,
    out: &mut [i8],
) {
    shared_loop(
        false,
        strategy,
        k,
        data,
        slot_tri,
        slot_parity,
        caps,
        light,
        out,
    );
}

/// The two shared evaluators: per chunk, the vectorised gather when `gather`
/// is set and the chunk's slots all name a triangle, else one checked
/// `caps.get` per slot with `strategy` for unknown slots.
#[allow(clippy::too_many_arguments)]
fn shared_loop(
    gather: bool,
    strategy: Strategy,
    k: usize,
    data: &[f32],
    slot_tri: &[u32],
    slot_parity: &[i8],
    caps: &[i8],
    light: Light,
    out: &mut [i8],
) {
    let stride = (2 + k) * 4;
    assert_eq!(data.len(), out.len() * stride, "bucket size mismatch");
    assert_eq!(slot_tri.len(), out.len() * k, "slot table size mismatch");
    assert_eq!(slot_parity.len(), out.len() * k, "slot table size mismatch");
    out.par_chunks_mut(CHUNK)
        .zip(data.par_chunks(CHUNK * stride))
        .zip(
            slot_tri
                .par_chunks(CHUNK * k)
                .zip(slot_parity.par_chunks(CHUNK * k)),
        )
        .for_each(|((o, d), (tri, par))| {
            if gather && crate::evaluate_simd::try_sides_from_caps(k, tri, par, caps, o) {
                return;
            }
            for (((m, r), t), p) in o
                .iter_mut()
                .zip(d.chunks_exact(stride))
                .zip(tri.chunks_exact(k))
                .zip(par.chunks_exact(k))
            {
                let mut sum = 0i32;
                for j in 0..k {
                    sum += match caps.get(t[j] as usize) {
                        Some(&c) => p[j] as i32 * c as i32,
                        None => strategy.side_sign(xyz(r, 0), xyz(r, 4), xyz(r, 8 + 4 * j), light),
                    };
                }
                *m = sum as i8;
            }
        });
}

/// Orientation (−1, 0, +1) of every caps record (12 floats each).
pub fn cap_signs(data: &[f32], light: Light, out: &mut [i8]) {
    cap_signs_with(Strategy::Reference, data, light, out)
}

/// [`cap_signs`] with an explicit strategy.
///
/// [`Strategy::Reference`] runs the branch-free vectorised kernel of
/// [`crate::evaluate_simd`] (bit for bit the contract, tested there); the
/// other strategies, and [`cap_signs_scalar`], run the scalar loop.
pub fn cap_signs_with(strategy: Strategy, data: &[f32], light: Light, out: &mut [i8]) {
    if strategy == Strategy::Reference {
        assert_eq!(data.len(), out.len() * 12, "caps size mismatch");
        out.par_chunks_mut(CHUNK)
            .zip(data.par_chunks(CHUNK * 12))
            .for_each(|(o, d)| crate::evaluate_simd::cap_signs(d, light, o));
        return;
    }
    cap_signs_scalar(strategy, data, light, out)
}

/// [`cap_signs_with`] through the scalar loop for every strategy,
/// [`Strategy::Reference`] included (branchy `tri_sign`): the benchmark's
/// peer and the tests' oracle.
pub fn cap_signs_scalar(strategy: Strategy, data: &[f32], light: Light, out: &mut [i8]) {
    match strategy {
        Strategy::Kim => caps_loop(kim_cap_sign, data, light, out),
        Strategy::Peciva => caps_loop(peciva_sign, data, light, out),
        Strategy::Reference => caps_loop(tri_sign, data, light, out),
        Strategy::ReferenceF64 => caps_loop(tri_sign_f64, data, light, out),
        Strategy::Exact => caps_loop(exact_sign, data, light, out),
    }
}

fn caps_loop<F>(sign: F, data: &[f32], light: Light, out: &mut [i8])
where
    F: Fn([f32; 3], [f32; 3], [f32; 3], Light) -> i32 + Sync,
{
    assert_eq!(data.len(), out.len() * 12, "caps size mismatch");
    out.par_chunks_mut(CHUNK)
        .zip(data.par_chunks(CHUNK * 12))
        .for_each(|(o, d)| {
            for (c, r) in o.iter_mut().zip(d.chunks_exact(12)) {
                *c = sign(xyz(r, 0), xyz(r, 4), xyz(r, 8), light) as i8;
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_direct_evaluation() {
        // Edge (0,0,0)-(1,0,0) with opposite vertices above and below; light above.
        let rec = [
            0.0, 0.0, 0.0, 2.0, 1.0, 0.0, 0.0, 2.0, 0.5, 1.0, 0.0, 1.0, 0.5, 0.0, 1.0, 1.0,
        ];
        let light = [0.5, 0.0, 3.0, 1.0];
        let mut m = [0i8; 1];
        side_multiplicities(2, &rec, light, &mut m);
        let want = tri_sign([0.0; 3], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], light)
            + tri_sign([0.0; 3], [1.0, 0.0, 0.0], [0.5, 0.0, 1.0], light);
        assert_eq!(m[0] as i32, want);
        let caps = [0.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0, 0.5, 1.0, 0.0, 1.0];
        let mut c = [0i8; 1];
        cap_signs(&caps, light, &mut c);
        assert_eq!(c[0], 1);
    }

    #[test]
    fn kim_agrees_away_from_the_plane() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        for l in [
            [0.2, 0.3, 4.0, 1.0],
            [0.2, 0.3, -4.0, 1.0],
            [1.0, 2.0, 3.0, 0.0],
        ] {
            let r = tri_sign(t[0], t[1], t[2], l);
            assert_eq!(kim_cap_sign(t[0], t[1], t[2], l), r);
            assert_eq!(kim_sign(t[0], t[1], t[2], l), r);
            assert_eq!(kim_sign(t[1], t[2], t[0], l), r);
            assert_eq!(kim_sign(t[1], t[0], t[2], l), -r);
        }
    }

    #[test]
    fn consistent_strategies_agree_under_every_corner_order() {
        // Near-parallel lights: Kim's three expressions can disagree here, but
        // Pečiva, f64 and exact evaluate one canonical expression per triangle.
        let mut rnd = crate::multiplicity::test_rng(777);
        let perms = crate::multiplicity::PERMS;
        for _ in 0..5000 {
            let t = [
                [rnd(), rnd(), rnd() * 1e-6],
                [rnd(), rnd(), rnd() * 1e-6],
                [rnd(), rnd(), rnd() * 1e-6],
            ];
            let l = [rnd() * 10.0, rnd() * 10.0, rnd() * 1e-6, 1.0];
            for s in [Strategy::Peciva, Strategy::ReferenceF64, Strategy::Exact] {
                let base = s.cap_sign(t[0], t[1], t[2], l);
                for (n, p) in perms.iter().enumerate() {
                    let want = if n < 3 { base } else { -base };
                    assert_eq!(s.side_sign(t[p[0]], t[p[1]], t[p[2]], l), want, "{s:?}");
                }
            }
        }
    }

    #[test]
    fn exact_is_exact_where_f32_is_not() {
        // A light 1e-7 off the plane z = 0 of a large triangle: f32 rounds
        // the reference expression, the exact predicate does not.
        let t = [[0.0, 0.0, 0.0], [1000.0, 0.0, 0.0], [0.0, 1000.0, 0.0]];
        assert_eq!(exact_sign(t[0], t[1], t[2], [3.0, 5.0, 1e-7, 1.0]), 1);
        assert_eq!(exact_sign(t[0], t[1], t[2], [3.0, 5.0, -1e-7, 1.0]), -1);
        assert_eq!(exact_sign(t[0], t[1], t[2], [3.0, 5.0, 0.0, 1.0]), 0);
        // Every strategy agrees with exact far from the plane.
        for l in [[0.2, 0.3, 4.0, 1.0], [1.0, -2.0, -3.0, 0.0]] {
            let e = exact_sign(t[0], t[1], t[2], l);
            for s in Strategy::ALL {
                assert_eq!(s.cap_sign(t[0], t[1], t[2], l), e, "{s:?}");
                assert_eq!(s.side_sign(t[0], t[1], t[2], l), e, "{s:?}");
            }
        }
    }

    #[test]
    fn peciva_discards_a_triangle_whose_edge_tests_disagree() {
        // Search a near-parallel configuration where Kim's three edge tests
        // disagree; Pečiva must give 0 there, and Kim's own edges must differ.
        let mut rnd = crate::multiplicity::test_rng(4242);
        let mut found = 0;
        for _ in 0..200_000 {
            // Corners and light (nearly) on the tilted plane z = 0.1x + 0.37y.
            let mut on = |s: f32| {
                let (x, y) = (rnd() * s, rnd() * s);
                [x, y, 0.1 * x + 0.37 * y]
            };
            let t = [on(1.0), on(1.0), on(1.0)];
            let p = on(50.0);
            let l = [p[0], p[1], p[2], 1.0];
            let ([a, b, c], _) = sort3(t[0], t[1], t[2]);
            let k = [
                kim_sign(a, b, c, l),
                kim_sign(b, c, a, l),
                kim_sign(c, a, b, l),
            ];
            if k[0] != k[1] || k[1] != k[2] {
                found += 1;
                assert_eq!(peciva_sign(t[0], t[1], t[2], l), 0);
            }
        }
        assert!(found > 0, "no disagreeing configuration found");
    }

    #[test]
    fn vectorised_paths_equal_the_scalar_loops_whatever_the_thread_count() {
        // More records than one rayon chunk (so chunk boundaries and a tail
        // block occur), lattice coordinates for ties, a light on a corner,
        // in a plane and directional; one slot with no triangle (a damaged
        // file) in the middle chunk, which must take the per-slot fallback.
        let mut rnd = crate::multiplicity::test_rng(2024);
        let mut coord = move || {
            let v = rnd();
            if v < -0.3 { (v * 4.0).round() * 0.5 } else { v }
        };
        let n_tri = 2 * CHUNK + 13;
        let caps_data: Vec<f32> = (0..n_tri * 3)
            .flat_map(|_| [coord(), coord(), coord(), 1.0])
            .collect();
        let k = 3;
        let n_rec = 3 * CHUNK + 5;
        let mut data = Vec::new();
        let mut slot_tri = Vec::new();
        let mut slot_parity = Vec::new();
        let mut next = 7u64;
        for _ in 0..n_rec {
            for p in 0..2 + k {
                data.extend_from_slice(&[coord(), coord(), coord(), if p < 2 { 3.0 } else { 1.0 }]);
            }
            for _ in 0..k {
                next = next
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                slot_tri.push((next >> 33) as u32 % n_tri as u32);
                slot_parity.push(((next >> 20) % 3) as i8 - 1);
            }
        }
        slot_tri[CHUNK * k + 17] = u32::MAX;
        let c0 = xyz(&caps_data, 0);
        let lights = [
            [0.3, -0.7, 0.25, 1.0],
            [c0[0], c0[1], c0[2], 1.0],
            [0.5, 0.0, -0.5, 0.0],
            [1.0, 1.0, 1.0, 0.0],
        ];
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                for l in lights {
                    let (mut a, mut b) = (vec![0i8; n_tri], vec![0i8; n_tri]);
                    cap_signs_with(Strategy::Reference, &caps_data, l, &mut a);
                    cap_signs_scalar(Strategy::Reference, &caps_data, l, &mut b);
                    assert_eq!(a, b, "caps, {threads} threads, {l:?}");
                    let (mut a, mut b) = (vec![0i8; n_rec], vec![0i8; n_rec]);
                    side_multiplicities_with(Strategy::Reference, k, &data, l, &mut a);
                    side_multiplicities_scalar(Strategy::Reference, k, &data, l, &mut b);
                    assert_eq!(a, b, "sides, {threads} threads, {l:?}");
                    let caps = {
                        let mut c = vec![0i8; n_tri];
                        cap_signs_with(Strategy::Reference, &caps_data, l, &mut c);
                        c
                    };
                    let (mut a, mut b) = (vec![0i8; n_rec], vec![0i8; n_rec]);
                    for (f, o) in [
                        (
                            side_multiplicities_shared as fn(_, _, _, _, _, _, _, _),
                            &mut a,
                        ),
                        (side_multiplicities_shared_scalar, &mut b),
                    ] {
                        f(
                            Strategy::Reference,
                            k,
                            &data,
                            &slot_tri,
                            &slot_parity,
                            &caps,
                            l,
                            o,
                        );
                    }
                    assert_eq!(a, b, "shared sides, {threads} threads, {l:?}");
                }
            });
        }
    }

    #[test]
    fn fast_side_sign_is_the_contract_bit_for_bit() {
        // Coordinates from a tiny lattice make ties in x and y (the hard part
        // of the lexicographic order) and lights in planes common.
        let mut next = crate::multiplicity::test_bits(99);
        for _ in 0..200_000 {
            let mut lattice = || [0, 1, 2].map(|_| ((next() % 3) as f32) * 0.5 - 0.5);
            let (a, b, o) = (lattice(), lattice(), lattice());
            let lp = lattice();
            let w = (next() % 2) as f32;
            let l = [lp[0] * 3.0 + 0.25, lp[1], lp[2] * 7.0, w];
            // Both orders of a, b: the fallback path must agree too.
            assert_eq!(reference_side_sign(a, b, o, l), tri_sign(a, b, o, l));
            assert_eq!(reference_side_sign(b, a, o, l), tri_sign(b, a, o, l));
        }
    }
}
