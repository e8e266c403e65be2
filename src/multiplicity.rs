//! The multiplicity contract: the one float expression that the GLSL sides
//! and caps shaders and the CPU evaluator must all compute identically.
//!
//! format-spec/multiplicity.md is the normative text; this file is its Rust
//! transcription and the only place the arithmetic is written. Rust never
//! contracts `a * b + c` into a fused multiply-add on its own, and nothing
//! here calls `mul_add`, so every operation rounds exactly as written.
//!
//! Why a reference edge: a triangle (P, Q, R) touches three edges, and the
//! shadow volume is closed only if all three agree on the triangle's
//! orientation towards the light. Evaluating a light plane per edge (Kim 2008)
//! gives three different float expressions that can disagree when the light is
//! nearly in the triangle's plane. Instead every occurrence sorts the three
//! corners lexicographically and evaluates one expression on the sorted corners
//! (Milet et al. 2014, Algorithms 3 and 4); only the permutation parity
//! differs, and that is exact.

/// Homogeneous light position: `w == 1.0` point light at `(x, y, z)`,
/// `w == 0.0` directional light shining from direction `(x, y, z)` (towards the
/// light). Other `w` values are outside the contract.
pub type Light = [f32; 4];

/// Strict lexicographic order on `(x, y, z)` f32 values.
///
/// Inputs are finite and contain no `-0.0` (the builder turns it into `+0.0`),
/// so float comparison is a total order here.
#[inline(always)]
pub fn lex_less(a: [f32; 3], b: [f32; 3]) -> bool {
    if a[0] != b[0] {
        return a[0] < b[0];
    }
    if a[1] != b[1] {
        return a[1] < b[1];
    }
    a[2] < b[2]
}

/// [`lex_less`] with `&`/`|` instead of early returns, so it compiles to
/// flag arithmetic or vector masks instead of branches. Same truth table for
/// every input: `a < b` and `a == b` are both false when either is NaN,
/// exactly like the `!=` then `<` of [`lex_less`], and `-0.0 == 0.0` in both.
#[inline(always)]
pub fn lex_less_nb(a: [f32; 3], b: [f32; 3]) -> bool {
    (a[0] < b[0]) | ((a[0] == b[0]) & ((a[1] < b[1]) | ((a[1] == b[1]) & (a[2] < b[2]))))
}

/// Sign (−1, 0, +1) of the reference expression on sorted corners
/// `r0 < r1 < r2`: `((r2 − r0) × (L.xyz − r0·L.w)) · (r1 − r0)`, each
/// operation rounded to f32 in exactly this order (see the spec, §2).
#[inline(always)]
pub fn ref_sign(r0: [f32; 3], r1: [f32; 3], r2: [f32; 3], l: Light) -> i32 {
    // A point light exactly on a corner lies in the triangle's plane: the
    // exact answer is 0, but (x × y)·d need not round to 0 (and a fused
    // multiply-add on a GPU could spoil the other corners too). Extruding
    // that corner would give the point (0, 0, 0, 0), which is no point.
    if l[3] == 1.0
        && (r0 == [l[0], l[1], l[2]] || r1 == [l[0], l[1], l[2]] || r2 == [l[0], l[1], l[2]])
    {
        return 0;
    }
    let s = ref_expr(r0, r1, r2, l);
    (s > 0.0) as i32 - (s < 0.0) as i32
}

/// The reference expression itself, `((r2 − r0) × (L.xyz − r0·L.w)) · (r1 −
/// r0)`, each operation rounded to f32 in exactly this order (spec §2),
/// without the light-on-corner test. The one transcription of the float
/// contract in Rust: [`ref_sign`] and the vectorised kernels of
/// [`crate::evaluate_simd`] both call it (inlined, so the kernels' lanes
/// compute these operations in this order).
#[inline(always)]
pub fn ref_expr(r0: [f32; 3], r1: [f32; 3], r2: [f32; 3], l: Light) -> f32 {
    // x = reference edge r0 → r2
    let x0 = r2[0] - r0[0];
    let x1 = r2[1] - r0[1];
    let x2 = r2[2] - r0[2];
    // y = direction from r0 to the light (for w = 0: the light direction itself)
    let y0 = l[0] - r0[0] * l[3];
    let y1 = l[1] - r0[1] * l[3];
    let y2 = l[2] - r0[2] * l[3];
    // d = r0 → r1, the middle corner
    let d0 = r1[0] - r0[0];
    let d1 = r1[1] - r0[1];
    let d2 = r1[2] - r0[2];
    // n = x × y
    let n0 = x1 * y2 - x2 * y1;
    let n1 = x2 * y0 - x0 * y2;
    let n2 = x0 * y1 - x1 * y0;
    (n0 * d0 + n1 * d1) + n2 * d2
}

/// Orientation (−1, 0, +1) of the ordered triangle `(p0, p1, p2)` as seen from
/// the light: +1 when the light is on the side of the right-hand normal
/// `(p1 − p0) × (p2 − p0)`. Computed through the reference edge, so all six
/// orderings of the same three corners give consistent answers (a swap flips
/// the sign exactly).
///
/// This is both an edge's per-opposite-vertex contribution (edge `A → B`,
/// opposite vertex `O`: `tri_sign(A, B, O, L)`) and a cap's orientation.
#[inline(always)]
pub fn tri_sign(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3], l: Light) -> i32 {
    let ([a, b, c], parity) = sort3(p0, p1, p2);
    parity * ref_sign(a, b, c, l)
}

/// The corners in lexicographic order and the parity (+1 even, −1 odd) of the
/// permutation that sorted them: the three-comparator network of the spec.
#[inline(always)]
pub fn sort3(p0: [f32; 3], p1: [f32; 3], p2: [f32; 3]) -> ([[f32; 3]; 3], i32) {
    let (mut a, mut b, mut c) = (p0, p1, p2);
    let mut parity = 1;
    // Each swap is an odd permutation.
    if lex_less(b, a) {
        std::mem::swap(&mut a, &mut b);
        parity = -parity;
    }
    if lex_less(c, b) {
        std::mem::swap(&mut b, &mut c);
        parity = -parity;
    }
    if lex_less(b, a) {
        std::mem::swap(&mut a, &mut b);
        parity = -parity;
    }
    ([a, b, c], parity)
}

/// Multiplicity of edge `a → b` (with `a < b`) over its opposite vertices: the
/// number of signed side quads the sides shader extrudes.
pub fn edge_multiplicity(a: [f32; 3], b: [f32; 3], opposite: &[[f32; 3]], l: Light) -> i32 {
    opposite.iter().map(|&o| tri_sign(a, b, o, l)).sum()
}

/// Extrusion of a point to infinity away from the light: `(p·L.w − L.xyz, 0)`.
/// For `w ∈ {0, 1}` this rounds identically with or without FMA.
#[inline(always)]
pub fn to_infinity(p: [f32; 3], l: Light) -> [f32; 4] {
    [
        p[0] * l[3] - l[0],
        p[1] * l[3] - l[1],
        p[2] * l[3] - l[2],
        0.0,
    ]
}

/// Corner of the side quad that vertex `v` (0..5) of a side draw uses, for an
/// edge with multiplicity `m != 0`: 0 = A, 1 = B, 2 = A at infinity, 3 = B at
/// infinity (paper eqs. 3–5; spec §4). `m > 0` gives triangles (2, 1, 0) and
/// (1, 2, 3); `m < 0` the same triangles reversed.
#[inline(always)]
pub fn side_corner(v: u32, m: i32) -> u32 {
    if m > 0 {
        // |v − 2|: v = 0, 1, 2 → 2, 1, 0 and v = 3, 4, 5 → 1, 2, 3.
        v.abs_diff(2)
    } else if v > 2 {
        6 - v
    } else {
        v
    }
}

/// Corner of the cap pair that vertex `v` (0..5) of a caps draw uses, for a
/// triangle with orientation `c != 0`: the index (0, 1, 2) into the stored
/// corners after the swap that `c < 0` causes, and whether it is the back cap
/// vertex at infinity. Front cap (P0, P1, P2), back cap (P2, P1, P0) at infinity.
#[inline(always)]
pub fn cap_corner(v: u32, c: i32) -> (u32, bool) {
    let (corner, at_infinity) = if v < 3 { (v, false) } else { (5 - v, true) };
    // c < 0 swaps P0 and P1 before the lookup.
    let corner = if c < 0 && corner < 2 {
        1 - corner
    } else {
        corner
    };
    (corner, at_infinity)
}

/// The six orders of three corners (even permutations first), for the unit
/// tests here, in `evaluate` and in `evaluate_simd`.
#[cfg(test)]
pub(crate) const PERMS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [1, 2, 0],
    [2, 0, 1],
    [1, 0, 2],
    [0, 2, 1],
    [2, 1, 0],
];

/// Xorshift64 for the unit tests of the crate (fixed seeds, so failures
/// reproduce): the successive states.
#[cfg(test)]
pub(crate) fn test_bits(mut seed: u64) -> impl FnMut() -> u64 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        seed
    }
}

/// [`test_bits`] as f32 in [-1, 1), for the unit tests here and in
/// `evaluate`.
#[cfg(test)]
pub(crate) fn test_rng(seed: u64) -> impl FnMut() -> f32 {
    let mut bits = test_bits(seed);
    move || (bits() >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orientation_matches_geometry() {
        let t = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        // Right-hand normal is +z.
        assert_eq!(tri_sign(t[0], t[1], t[2], [0.2, 0.2, 5.0, 1.0]), 1);
        assert_eq!(tri_sign(t[0], t[1], t[2], [0.2, 0.2, -5.0, 1.0]), -1);
        assert_eq!(tri_sign(t[0], t[1], t[2], [0.0, 0.0, 1.0, 0.0]), 1);
        assert_eq!(tri_sign(t[0], t[1], t[2], [0.0, 0.0, -1.0, 0.0]), -1);
        // Light in the plane of the triangle.
        assert_eq!(tri_sign(t[0], t[1], t[2], [3.0, 7.0, 0.0, 1.0]), 0);
        assert_eq!(tri_sign(t[0], t[1], t[2], [1.0, 1.0, 0.0, 0.0]), 0);
    }

    #[test]
    fn permutations_agree_exactly_even_near_the_plane() {
        // A light almost in the triangle's plane: the per-edge light plane of
        // Kim 2008 can disagree between edges here; the reference edge cannot.
        let mut rnd = test_rng(12345);
        for _ in 0..20000 {
            let t = [
                [rnd(), rnd(), rnd() * 1e-6],
                [rnd(), rnd(), rnd() * 1e-6],
                [rnd(), rnd(), rnd() * 1e-6],
            ];
            let l = [rnd() * 10.0, rnd() * 10.0, rnd() * 1e-6, 1.0];
            let base = tri_sign(t[0], t[1], t[2], l);
            for p in PERMS {
                let odd = p == [1, 0, 2] || p == [0, 2, 1] || p == [2, 1, 0];
                let s = tri_sign(t[p[0]], t[p[1]], t[p[2]], l);
                assert_eq!(s, if odd { -base } else { base });
            }
        }
    }

    #[test]
    fn edge_multiplicity_counts_fan() {
        // Edge on the x axis, four fins: two above the light plane, one below, one in it.
        let a = [0.0, 0.0, 0.0];
        let b = [1.0, 0.0, 0.0];
        let l = [0.5, 0.0, 10.0, 1.0]; // light plane is y = 0
        let opp = [
            [0.5, 1.0, 0.0],
            [0.5, 2.0, 1.0],
            [0.5, -1.0, 0.0],
            [0.5, 0.0, -1.0],
        ];
        let signs: Vec<i32> = opp.iter().map(|&o| tri_sign(a, b, o, l)).collect();
        assert_eq!(signs, vec![1, 1, -1, 0]);
        assert_eq!(edge_multiplicity(a, b, &opp, l), 1);
    }

    #[test]
    fn lex_order() {
        assert!(lex_less([0.0, 5.0, 5.0], [1.0, 0.0, 0.0]));
        assert!(lex_less([1.0, 0.0, 5.0], [1.0, 1.0, 0.0]));
        assert!(lex_less([1.0, 1.0, 0.0], [1.0, 1.0, 1e-30]));
        assert!(!lex_less([1.0, 1.0, 1.0], [1.0, 1.0, 1.0]));
    }
}
