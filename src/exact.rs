//! Exact sign of a 4×4 determinant whose entries are f32 values (held in
//! f64): the one predicate the shadow-truth check needs, for homogeneous
//! points `(x, y, z, w)` with `w ∈ {0, 1}` — finite points and points at
//! infinity alike.
//!
//! A floating-point evaluation with a proven error bound decides almost every
//! call; the rest are decided exactly with big integers (every f32 is an
//! integer times a power of two, so the determinant is an exact sum of 24
//! integer products). `robust::orient3d` covers only finite points, which is
//! why this exists.
//!
//! [`det4_sign_points`] and [`meet_points`] extend both to rows that are
//! differences of two such points ([`Point::Away`]): the exact extrusion
//! direction `P − L` of a corner away from a point light, which f32 cannot
//! hold (the float contract rounds it).

use num_bigint::BigInt;

/// Homogeneous point or vector; every entry must be an f32 value.
pub type H = [f64; 4];

/// The 24 permutations of 0..4 with their signs.
const PERMS: [([usize; 4], i8); 24] = {
    let mut out = [([0usize; 4], 0i8); 24];
    let mut n = 0;
    let mut a = 0;
    while a < 4 {
        let mut b = 0;
        while b < 4 {
            let mut c = 0;
            while c < 4 {
                let mut d = 0;
                while d < 4 {
                    if a != b && a != c && a != d && b != c && b != d && c != d {
                        let p = [a, b, c, d];
                        // Parity by counting inversions.
                        let mut inv = 0;
                        let mut i = 0;
                        while i < 4 {
                            let mut j = i + 1;
                            while j < 4 {
                                if p[i] > p[j] {
                                    inv += 1;
                                }
                                j += 1;
                            }
                            i += 1;
                        }
                        out[n] = (p, if inv % 2 == 0 { 1 } else { -1 });
                        n += 1;
                    }
                    d += 1;
                }
                c += 1;
            }
            b += 1;
        }
        a += 1;
    }
    out
};

/// Sign (−1, 0, +1) of `orient3d(t[0], t[1], t[2], d)` (the sign
/// [`det4_sign`] gives for four points with `w = 1`) when the f64
/// evaluation decides it, `None` otherwise.
///
/// This is the first stage of Shewchuk's adaptive predicate, as
/// `robust::orient3d` computes it: the determinant of the differences to
/// `d` in f64 ([`det3_sign_filtered`] with no slack, within
/// [`DET3_BOUND`] of the permanent). Inline and with no exact stage, so
/// the caller can fall back to [`det4_sign`] only for the rare undecided
/// case. The entries must be f32 values (as [`DET3_BOUND`] requires).
#[inline(always)]
pub(crate) fn orient3d_filtered(t: [[f64; 3]; 3], d: [f64; 3]) -> Option<i32> {
    let [a, b, c] = t.map(|p| [p[0] - d[0], p[1] - d[1], p[2] - d[2]]);
    match det3_sign_filtered(a, b, c, 0.0) {
        0 => None,
        s => Some(s),
    }
}

/// Sign (−1, 0, +1) of `det[t0; t1; t2; (d, 0)]` (the sign [`det4_sign`]
/// gives for three points with `w = 1` and a direction) when the f64
/// evaluation decides it, `None` otherwise: [`det4_sign`]'s reduction
/// (`−det3[t0 − t2; t1 − t2; d]`) with Shewchuk's first-stage bound
/// ([`det3_sign_filtered`], no slack: each entry is exact or one rounded
/// subtraction of f32 values). The entries must be f32 values.
#[inline(always)]
pub(crate) fn directional_filtered(t: [[f64; 3]; 3], d: [f64; 3]) -> Option<i32> {
    let [a, b] = [t[0], t[1]].map(|p| [p[0] - t[2][0], p[1] - t[2][1], p[2] - t[2][2]]);
    match det3_sign_filtered(a, b, d, 0.0) {
        0 => None,
        s => Some(-s),
    }
}

/// Sign (−1, 0, +1) of `det[r0; r1; r2; r3]` (rows), exactly.
///
/// With every `w` in {0, 1} (all the shadow check asks), row operations
/// reduce the 4×4 determinant to a 3×3 one, decided by `robust::orient3d`
/// (Shewchuk's adaptive exact predicate), several times cheaper than the
/// 24-term sum below. Let `L` be the last row with `w = 1`. Subtracting it
/// from the other rows with `w = 1` zeroes their `w` and keeps the
/// determinant; expanding along the `w` column then leaves
/// `(−1)^(L+3) · det3` of the other three rows' `x, y, z`. Those
/// differences must be exact: four such rows go to `orient3d(p0, p1, p2,
/// p3)` whole (it forms `pi − p3` exactly itself); for two or three, each
/// difference is checked to be exact in f64 (it is unless the two values'
/// exponents are far apart), and if one is not, the sum below decides. No
/// row with `w = 1`: the `w` column is zero, and so is the determinant.
/// Anything else goes through the filtered Leibniz sum and its exact
/// fallback.
pub fn det4_sign(r: [H; 4]) -> i32 {
    det4_sign_by_det3(&r).unwrap_or_else(|| sum_sign(&[(1, r)]))
}

/// The 3×3 reduction of [`det4_sign`], or `None` when a `w` is not 0 or 1
/// or a needed difference is not exact in f64.
fn det4_sign_by_det3(r: &[H; 4]) -> Option<i32> {
    use robust::{Coord3D, orient3d};
    let c = |h: [f64; 3]| Coord3D {
        x: h[0],
        y: h[1],
        z: h[2],
    };
    let sign = |v: f64| (v > 0.0) as i32 - (v < 0.0) as i32;
    let w = r.map(|h| h[3]);
    if !w.iter().all(|&w| w == 0.0 || w == 1.0) {
        return None;
    }
    let xyz = |h: H| [h[0], h[1], h[2]];
    let Some(last) = (0..4).rev().find(|&i| w[i] == 1.0) else {
        return Some(0);
    };
    if w.iter().all(|&w| w == 1.0) {
        return Some(sign(orient3d(
            c(xyz(r[0])),
            c(xyz(r[1])),
            c(xyz(r[2])),
            c(xyz(r[3])),
        )));
    }
    let mut o = [[0f64; 3]; 3];
    for (slot, i) in (0..4).filter(|&i| i != last).enumerate() {
        for a in 0..3 {
            o[slot][a] = if w[i] == 1.0 {
                exact_difference(r[i][a], r[last][a])?
            } else {
                r[i][a]
            };
        }
    }
    let zero = [0.0; 3];
    // Cofactor sign (−1)^(last + 3).
    let cofactor = if (last + 3) % 2 == 0 { 1 } else { -1 };
    Some(cofactor * sign(orient3d(c(o[0]), c(o[1]), c(o[2]), c(zero))))
}

/// `a − b` when f64 holds it exactly (the rounding error of the
/// subtraction, by Knuth's two-sum, is zero), else `None`.
fn exact_difference(a: f64, b: f64) -> Option<f64> {
    let x = a - b;
    let bv = a - x;
    let av = x + bv;
    let err = (a - av) + (bv - b);
    (err == 0.0).then_some(x)
}

/// Sign of `Σ c · det(r)` over `(c, r)` in `dets` (c = ±1, f32 entries),
/// exactly. Filter: the Leibniz sums in f64. Each product of four f32
/// values has relative error at most 3u (u = 2^-53; no overflow or
/// underflow is possible for f32 inputs), and summing the N = 24 · n terms
/// adds at most (N − 1)u of the sum of magnitudes; (N + 8)u covers both
/// with margin (32u for one determinant). Big integers when it cannot
/// decide.
fn sum_sign(dets: &[(i8, [H; 4])]) -> i32 {
    let mut sum = 0.0f64;
    let mut mag = 0.0f64;
    for (c, r) in dets {
        for (p, s) in PERMS.iter() {
            let t = r[0][p[0]] * r[1][p[1]] * r[2][p[2]] * r[3][p[3]];
            sum += if *s * *c > 0 { t } else { -t };
            mag += t.abs();
        }
    }
    let bound = mag * ((24 * dets.len() + 8) as f64 * f64::EPSILON / 2.0);
    if sum > bound {
        return 1;
    }
    if sum < -bound {
        return -1;
    }
    if mag == 0.0 {
        return 0;
    }
    exact_sum_sign(dets)
}

/// A homogeneous point for [`det4_sign_points`] and [`meet_points`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Point {
    /// A point or direction whose entries are f32 values, as for [`det4_sign`].
    H(H),
    /// `Away(p, l)` is the direction `(p − l, 0)` at infinity, exactly, for
    /// finite points `p` and `l` (w = 1, f32 entries): where a point light
    /// at `l` extrudes `p` to. The contract's `toInf` is its f32 rounding.
    Away(H, H),
}

impl Point {
    /// True for a point at infinity (a direction).
    pub fn at_infinity(&self) -> bool {
        match self {
            Point::H(h) => h[3] == 0.0,
            Point::Away(..) => true,
        }
    }
}

/// Sign (−1, 0, +1) of `det[r0; r1; r2; r3]` (rows), exactly, where a row
/// `Away(p, l)` is `p − l`: by linearity in each row, the signed sum of up to
/// 16 determinants with f32 entries.
pub fn det4_sign_points(r: [Point; 4]) -> i32 {
    if let [Point::H(a), Point::H(b), Point::H(c), Point::H(d)] = r {
        return det4_sign([a, b, c, d]);
    }
    let mut dets: Vec<(i8, [H; 4])> = vec![(1, [[0.0; 4]; 4])];
    for (i, row) in r.iter().enumerate() {
        match *row {
            Point::H(h) => dets.iter_mut().for_each(|d| d.1[i] = h),
            Point::Away(p, l) => {
                let mut minus = dets.clone();
                dets.iter_mut().for_each(|d| d.1[i] = p);
                minus.iter_mut().for_each(|d| {
                    d.0 = -d.0;
                    d.1[i] = l;
                });
                dets.extend(minus);
            }
        }
    }
    sum_sign(&dets)
}

/// Decomposes an f32 value into `m · 2^e` with integer `m`.
fn split(v: f64) -> (i64, i32) {
    let f = v as f32;
    debug_assert_eq!(f as f64, v, "entry is not an f32 value");
    if f == 0.0 {
        return (0, 0);
    }
    let bits = f.to_bits();
    let sign = if bits >> 31 != 0 { -1 } else { 1 };
    let exp = ((bits >> 23) & 0xff) as i32;
    let frac = (bits & 0x7f_ffff) as i64;
    let (m, e) = if exp == 0 {
        (frac, -149)
    } else {
        (frac | 0x80_0000, exp - 150)
    };
    (sign * m, e)
}

/// Sign of `Σ c · det(r)` over `(c, r)` in `dets` (c = ±1), exactly.
fn exact_sum_sign(dets: &[(i8, [H; 4])]) -> i32 {
    let mut terms: Vec<(i128, i32)> = Vec::with_capacity(24 * dets.len());
    for (c, r) in dets {
        let parts: Vec<Vec<(i64, i32)>> = r
            .iter()
            .map(|row| row.iter().map(|&v| split(v)).collect())
            .collect();
        for (p, s) in PERMS.iter() {
            let mut m: i128 = (*s * *c) as i128;
            let mut e = 0;
            for (row, &col) in p.iter().enumerate() {
                let (mi, ei) = parts[row][col];
                m *= mi as i128;
                e += ei;
            }
            if m != 0 {
                terms.push((m, e));
            }
        }
    }
    let Some(emin) = terms.iter().map(|t| t.1).min() else {
        return 0;
    };
    let mut acc = BigInt::from(0);
    for (m, e) in terms {
        acc += BigInt::from(m) << ((e - emin) as usize);
    }
    match acc.sign() {
        num_bigint::Sign::Plus => 1,
        num_bigint::Sign::Minus => -1,
        num_bigint::Sign::NoSign => 0,
    }
}

/// Where the open segment from `a` to `b` (all positive combinations of the
/// two homogeneous points) meets a triangle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Meet {
    /// No contact.
    None,
    /// A transversal crossing of the interior; the value is the sign of
    /// `det[t0; t1; t2; a]` (which side `a` starts on).
    Cross(i32),
    /// `a` lies on the triangle (interior or boundary).
    AOnTriangle,
    /// The segment touches an edge or vertex of the triangle: ambiguous.
    Degenerate,
}

/// Classifies the segment `a → b` against triangle `t` (homogeneous corners;
/// a triangle whose corners are all at infinity is met where `b` is at
/// infinity too, i.e. the crossing happens at the end of a ray).
///
/// Most calls come from rays that pass well beside the triangle, and
/// [`passes_beside`] answers those with three floating-point determinants
/// before any exact arithmetic.
pub fn meet(a: H, b: H, t: [H; 3]) -> Meet {
    if passes_beside(&a, &b, &t, 0.0) {
        return Meet::None;
    }
    meet_exact(a, b, t)
}

/// [`meet`] without the filter: every determinant decided exactly.
fn meet_exact(a: H, b: H, t: [H; 3]) -> Meet {
    let v = [t[0], t[1], t[2], a, b];
    meet_by(t.map(|c| c[3] == 0.0), |i| det4_sign(i.map(|k| v[k])))
}

/// Shewchuk's static error bound for `orient3d` (his `o3derrboundA`):
/// with every entry of the three rows exact or one rounded subtraction of
/// exact values, the computed determinant is within this factor of the
/// permanent (the same sum with every product taken in absolute value) of
/// the exact one, barring underflow, which f32 entries cannot reach
/// (nonzero differences are at least 2^-149, so products of three are far
/// above f64's smallest normal).
const DET3_BOUND: f64 = (7.0 + 56.0 * (f64::EPSILON / 2.0)) * (f64::EPSILON / 2.0);

/// Sign of `det[r; u; v]` when the floating-point evaluation decides it
/// with `slack` times the permanent to spare beyond Shewchuk's bound (see
/// [`DET3_BOUND`]), 0 when it does not.
#[inline(always)]
fn det3_sign_filtered(r: [f64; 3], u: [f64; 3], v: [f64; 3], slack: f64) -> i32 {
    let (uxvy, vxuy) = (u[0] * v[1], v[0] * u[1]);
    let (vxry, rxvy) = (v[0] * r[1], r[0] * v[1]);
    let (rxuy, uxry) = (r[0] * u[1], u[0] * r[1]);
    let det = r[2] * (uxvy - vxuy) + u[2] * (vxry - rxvy) + v[2] * (rxuy - uxry);
    let permanent = (uxvy.abs() + vxuy.abs()) * r[2].abs()
        + (vxry.abs() + rxvy.abs()) * u[2].abs()
        + (rxuy.abs() + uxry.abs()) * v[2].abs();
    let bound = (DET3_BOUND + slack) * permanent;
    (det > bound) as i32 - (det < -bound) as i32
}

/// True when the segment or ray from the finite point `a` to `b` certainly
/// passes beside triangle `t`, in which case [`meet`] answers
/// [`Meet::None`]; false when that is not certain (then the exact path
/// decides) or when a `w` is not what this needs (`a` finite, every other
/// `w` 0 or 1).
///
/// With `slack > 0` the answer also holds for every nearby triangle whose
/// corners at infinity differ from `t`'s by a relative `slack / 4` or less
/// in each component: each product in the determinants has at most two
/// such factors, so moves by less than `slack` of its magnitude, and the
/// determinant by less than `slack` times the permanent, which the margin
/// covers. The shadow check uses this for the exact extrusions that the
/// f32 corners round ([`crate::exact::Point::Away`]): one rounding,
/// relative 2^-24.
///
/// Why this is the same answer: [`meet`]'s three edge determinants
/// `det[a; b; t_i; t_j]` (i, j = 0 1, 1 2, 2 0) are, after subtracting row
/// `a` from every row with `w = 1` and expanding along the `w` column, all
/// `−det3(b', t_i', t_j')`, where `x'` is `x − a` for a finite `x` and `x`
/// itself for a direction. If one of them is certainly positive and another
/// certainly negative, [`meet`] answers `None` whatever its plane tests
/// say: every branch before the edge test also answers `None`. The
/// differences are rounded here, which the bound allows for; nothing is
/// decided exactly, so the filter only ever short-cuts to an answer the
/// exact path gives.
#[inline]
pub fn passes_beside(a: &H, b: &H, t: &[H; 3], slack: f64) -> bool {
    if a[3] != 1.0 {
        return false;
    }
    let rel = |p: &H| -> Option<[f64; 3]> {
        if p[3] == 1.0 {
            Some([p[0] - a[0], p[1] - a[1], p[2] - a[2]])
        } else if p[3] == 0.0 {
            Some([p[0], p[1], p[2]])
        } else {
            None
        }
    };
    let (Some(r), Some(u0), Some(u1), Some(u2)) = (rel(b), rel(&t[0]), rel(&t[1]), rel(&t[2]))
    else {
        return false;
    };
    let s = [
        det3_sign_filtered(r, u0, u1, slack),
        det3_sign_filtered(r, u1, u2, slack),
        det3_sign_filtered(r, u2, u0, slack),
    ];
    s.contains(&1) && s.contains(&-1)
}

/// [`meet`] for corners and end points that may be exact extrusion
/// directions ([`Point::Away`]).
pub fn meet_points(a: Point, b: Point, t: [Point; 3]) -> Meet {
    let v = [t[0], t[1], t[2], a, b];
    meet_by(t.map(|c| c.at_infinity()), |i| {
        det4_sign_points(i.map(|k| v[k]))
    })
}

/// The logic of [`meet`] on points 0, 1, 2 (the triangle, `inf` telling
/// which corners are at infinity), 3 (`a`) and 4 (`b`), given the sign of
/// the determinant of any four of them by index.
#[inline(always)]
fn meet_by(inf: [bool; 3], det: impl Fn([usize; 4]) -> i32) -> Meet {
    let all_inf = inf.iter().all(|&i| i);
    let fa = det([0, 1, 2, 3]);
    if !all_inf {
        let fb = det([0, 1, 2, 4]);
        if fa != 0 && fa == fb {
            return Meet::None;
        }
        if fb == 0 && fa != 0 {
            // The segment reaches the plane only at its excluded end b.
            return Meet::None;
        }
        if fa == 0 && fb == 0 {
            return Meet::None; // segment in the plane: no transversal contact
        }
    } else if fa == 0 {
        return Meet::None;
    }
    let s = [det([3, 4, 0, 1]), det([3, 4, 1, 2]), det([3, 4, 2, 0])];
    let pos = s.iter().filter(|&&x| x > 0).count();
    let neg = s.iter().filter(|&&x| x < 0).count();
    if pos > 0 && neg > 0 {
        return Meet::None;
    }
    if pos == 0 && neg == 0 {
        return Meet::Degenerate;
    }
    let inside = pos == 3 || neg == 3;
    if all_inf {
        // The three signs are those of the cone coefficients of b's
        // direction times −fa (expand the determinants along w): equal to
        // +fa means the opposite direction lies in the cone, not b's.
        let sign = if pos > 0 { 1 } else { -1 };
        if sign == fa {
            return Meet::None;
        }
    }
    if fa == 0 {
        return Meet::AOnTriangle; // a in the plane, on the line's hit point
    }
    if inside {
        Meet::Cross(fa)
    } else {
        Meet::Degenerate
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(x: f32, y: f32, z: f32) -> H {
        [x as f64, y as f64, z as f64, 1.0]
    }
    fn d(x: f32, y: f32, z: f32) -> H {
        [x as f64, y as f64, z as f64, 0.0]
    }

    /// Marsaglia's xorshift64 from `seed` (non-zero): reproducible inputs.
    fn xorshift(mut x: u64) -> impl FnMut() -> u64 {
        move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        }
    }

    /// Runs `filtered` on 20,000 cases from `case` (given the case number,
    /// a source of uniform values and a scale, a triangle and the fourth
    /// row's `x, y, z`, whose `w` is `w`): every sign it decides must be
    /// [`det4_sign`]'s, and it must both decide and decline often (the
    /// near-degenerate cases exercise the bound).
    fn filter_agrees_with_exact(
        seed: u64,
        w: f64,
        filtered: fn([[f64; 3]; 3], [f64; 3]) -> Option<i32>,
        mut case: impl FnMut(usize, &mut dyn FnMut() -> f64, f64) -> ([[f32; 3]; 3], [f32; 3]),
    ) {
        let mut next = xorshift(seed);
        let mut unit = move || (next() >> 11) as f64 / (1u64 << 53) as f64;
        let (mut decided, mut undecided) = (0, 0);
        for i in 0..20_000 {
            let scale = [1e-3, 1.0, 1e3][i % 3];
            let (t, l) = case(i, &mut unit, scale);
            let f = t.map(|c| c.map(f64::from));
            let lf = l.map(f64::from);
            let w1 = |c: [f64; 3]| [c[0], c[1], c[2], 1.0];
            let exact = det4_sign([w1(f[0]), w1(f[1]), w1(f[2]), [lf[0], lf[1], lf[2], w]]);
            match filtered(f, lf) {
                Some(s) => {
                    assert_eq!(s, exact, "case {i}: {t:?}, {l:?}");
                    decided += 1;
                }
                None => undecided += 1,
            }
        }
        assert!(
            decided > 9_000 && undecided > 3_000,
            "{decided} / {undecided}"
        );
    }

    /// Integers below 2^21 as f32: the products of their differences
    /// outgrow f64's 53 bits, so the f64 determinant of coplanar points is
    /// often not exactly 0.
    fn int(v: f64) -> f32 {
        (v * (1u32 << 21) as f64).floor() as f32
    }

    /// A point on the plane x + y + z = 2^23, exactly in f32.
    fn on_plane(x: f32, y: f32) -> [f32; 3] {
        [x, y, (1u32 << 23) as f32 - x - y]
    }

    #[test]
    fn orient3d_filtered_decides_only_what_the_exact_sign_says() {
        // A triangle and a point: exactly coplanar (on a tilted plane of
        // small integers, on a corner, or all at one z), one f32 ulp off
        // such a plane, near the plane within f32 rounding, or anywhere; at
        // several scales.
        filter_agrees_with_exact(
            0x5eed_0f0e_1e47,
            1.0,
            orient3d_filtered,
            |i, unit, scale| {
                let q = |v: f64| (v * scale) as f32;
                let mut t: [[f32; 3]; 3] =
                    std::array::from_fn(|_| [q(unit()), q(unit()), q(unit())]);
                let mut l = [q(unit()), q(unit()), q(unit())];
                match i % 6 {
                    0 | 1 => {
                        t = std::array::from_fn(|_| on_plane(int(unit()), int(unit())));
                        l = on_plane(int(unit()), int(unit()));
                        if i % 6 == 1 {
                            l[2] = f32::from_bits(l[2].to_bits() + 1);
                        }
                    }
                    2 => l = t[i % 3],
                    3 => {
                        let z = t[0][2];
                        for c in &mut t {
                            c[2] = z;
                        }
                        l[2] = z;
                    }
                    4 => {
                        let (u, v) = (unit(), unit());
                        l = std::array::from_fn(|a| {
                            (t[0][a] as f64
                                + u * (t[1][a] - t[0][a]) as f64
                                + v * (t[2][a] - t[0][a]) as f64) as f32
                        });
                    }
                    _ => {}
                }
                (t, l)
            },
        );
    }

    #[test]
    fn directional_filtered_decides_only_what_the_exact_sign_says() {
        // A triangle and a direction: exactly parallel to its plane (a
        // tilted plane of small integers, or all at one z), one f32 ulp off
        // parallel, an edge's direction rounded to f32, or anything; at
        // several scales.
        filter_agrees_with_exact(
            0x0d1e_c710_0a11,
            0.0,
            directional_filtered,
            |i, unit, scale| {
                let q = |v: f64| (v * scale) as f32;
                let mut t: [[f32; 3]; 3] =
                    std::array::from_fn(|_| [q(unit()), q(unit()), q(unit())]);
                let mut l = [q(unit() - 0.5), q(unit() - 0.5), q(unit() - 0.5)];
                match i % 6 {
                    0 | 1 => {
                        // Directions with x + y + z = 0.
                        t = std::array::from_fn(|_| on_plane(int(unit()), int(unit())));
                        let (x, y) = (int(unit()) - int(unit()), int(unit()) - int(unit()));
                        l = [x, y, -x - y];
                        if i % 6 == 1 {
                            l[2] = f32::from_bits(l[2].to_bits() + 1);
                        }
                    }
                    2 => l = [0, 1, 2].map(|a| t[1][a] - t[0][a]),
                    3 => {
                        let z = t[0][2];
                        for c in &mut t {
                            c[2] = z;
                        }
                        l[2] = 0.0;
                    }
                    _ => {}
                }
                (t, l)
            },
        );
    }

    #[test]
    fn determinant_signs() {
        // orient of a unit tetrahedron, both orders.
        let r = [
            p(0.0, 0.0, 0.0),
            p(1.0, 0.0, 0.0),
            p(0.0, 1.0, 0.0),
            p(0.0, 0.0, 1.0),
        ];
        let s = det4_sign(r);
        assert_ne!(s, 0);
        assert_eq!(det4_sign([r[1], r[0], r[2], r[3]]), -s);
        // Coplanar points: exactly zero, even with awkward values.
        let a = p(0.1, 0.2, 0.3);
        let b = p(1e7, 0.2, 0.3);
        let c = p(0.1, 3e-8, 0.3);
        let e = p(-5.5, 1e-30, 0.3);
        assert_eq!(det4_sign([a, b, c, e]), 0);
        // Nearly coplanar: one ulp off the plane z = 0.3.
        let f = p(-5.5, 1e-30, f32::from_bits(0.3f32.to_bits() + 1));
        assert_ne!(det4_sign([a, b, c, f]), 0);
    }

    /// The 3×3 reduction of `det4_sign` against the general filtered sum
    /// with its exact fallback: every pattern of `w` in {0, 1}, random
    /// rows of mixed magnitudes (so some differences are inexact and fall
    /// back), and rows made dependent (exactly, on small integers, or
    /// nearly, after rounding), with a zero determinant among them.
    #[test]
    fn reduction_agrees_with_the_general_sum() {
        let mut next = xorshift(0x2545_F491_4F6C_DD1D);
        let coord = |n: u64| -> f32 {
            match n % 5 {
                0 | 1 => ((n >> 8) % 7) as f32 - 3.0,
                2 => ((n >> 16) % 2001) as f32 / 1000.0 - 1.0,
                3 => f32::from_bits(((n >> 16) as u32 & 0x3FFF_FFFF) | 0x0080_0000) * 1e-10,
                _ => ((n >> 20) as i32 % 1000) as f32 * 1e5,
            }
        };
        let (mut zeros, mut reduced, mut fallback) = (0, 0, 0);
        for case in 0..60_000u32 {
            let mut r: [H; 4] = std::array::from_fn(|_| {
                let w = (next() % 2) as f64;
                [
                    coord(next()) as f64,
                    coord(next()) as f64,
                    coord(next()) as f64,
                    w,
                ]
            });
            if case % 3 == 0 {
                // r3 = r0 − r1 + r2, rounded to f32: dependent, exactly when
                // nothing rounds (small integers), else nearly.
                let w = r[0][3] - r[1][3] + r[2][3];
                if w == 0.0 || w == 1.0 {
                    let f = |a: usize| (r[0][a] as f32 - r[1][a] as f32 + r[2][a] as f32) as f64;
                    r[3] = [f(0), f(1), f(2), w];
                }
            }
            let want = sum_sign(&[(1, r)]);
            match det4_sign_by_det3(&r) {
                Some(got) => {
                    assert_eq!(got, want, "case {case}: {r:?}");
                    reduced += 1;
                }
                None => fallback += 1,
            }
            assert_eq!(det4_sign(r), want);
            zeros += (want == 0) as u32;
        }
        assert!(zeros > 3000, "dependent rows must occur: {zeros}");
        assert!(
            reduced > 30_000 && fallback > 100,
            "{reduced} reduced, {fallback} fell back"
        );
    }

    #[test]
    fn differences_are_exact() {
        // Where p − l is an f32 value, Away(p, l) is that direction.
        let (a, b, c) = (p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0));
        let (q, l) = (p(0.25, 0.5, 3.0), p(-0.5, 0.25, 1.0));
        let dir = d(0.75, 0.25, 2.0);
        for rows in [[a, b, c, dir], [a, dir, b, c], [dir, a, b, c]] {
            let pts = rows.map(|r| {
                if r == dir {
                    Point::Away(q, l)
                } else {
                    Point::H(r)
                }
            });
            assert_eq!(det4_sign_points(pts), det4_sign(rows));
            assert_ne!(det4_sign(rows), 0);
        }
        // Where it is not: B − L rounds off the plane through A, B and L,
        // but (A, B, B − L, L) are exactly coplanar.
        let a = p(-1.0, -8.727_353_7e-7, 0.5);
        let b = p(2.173_373_6e-7, 1.907_575_3e-7, -0.5);
        let l = p(-0.5, 0.0, 0.0);
        let rounded = d(b[0] as f32 - l[0] as f32, b[1] as f32, b[2] as f32);
        assert_ne!(det4_sign([a, b, rounded, l]), 0);
        let rows = [Point::H(a), Point::H(b), Point::Away(b, l), Point::H(l)];
        assert_eq!(det4_sign_points(rows), 0);
        // Two rows of differences (a side triangle with both corners at
        // infinity): 4 determinants; swapping rows flips the sign.
        let s = p(49.957_226, -550.836, 134.612_49);
        let r = [
            Point::H(b),
            Point::Away(a, l),
            Point::Away(b, l),
            Point::H(s),
        ];
        let sign = det4_sign_points(r);
        assert_ne!(sign, 0);
        assert_eq!(det4_sign_points([r[0], r[2], r[1], r[3]]), -sign);
        // det[B, A − L, B − L, S] = det[B, A, B, S] − det[B, A, L, S]
        //   − det[B, L, B, S] + det[B, L, L, S] = −det[B, A, L, S].
        assert_eq!(sign, -det4_sign([b, a, l, s]));
    }

    /// The filter in front of [`meet`] against the exact path alone, on
    /// 200,000 segments and rays: random ones (most pass beside, which the
    /// filter must answer), ones starting on the triangle, and ones aimed
    /// at a corner, an edge's midpoint or the plane, exactly and one ulp
    /// off, at coordinates of mixed magnitudes where f64 rounding is large
    /// against the determinants.
    #[test]
    fn filter_agrees_with_the_exact_path() {
        let mut next = xorshift(0x9E37_79B9_7F4A_7C15);
        let coord = |n: u64| -> f32 {
            match n % 4 {
                0 => ((n >> 8) % 9) as f32 - 4.0,
                1 => ((n >> 16) % 2001) as f32 / 1000.0 - 1.0,
                2 => 1000.0 + ((n >> 16) % 4001) as f32 / 4096.0,
                _ => f32::from_bits(((n >> 16) as u32 & 0x0FFF_FFFF) | 0x3000_0000) - 0.75,
            }
        };
        let ulp = |v: f64, up: bool| -> f64 {
            let f = v as f32;
            let b = f.to_bits();
            let g = if (f >= 0.0) == up {
                b + 1
            } else {
                b.wrapping_sub(1)
            };
            if f == 0.0 {
                f32::from_bits(1) as f64
            } else {
                f32::from_bits(g) as f64
            }
        };
        let (mut filtered, mut declined) = (0, 0);
        let mut kinds = [0usize; 4];
        for i in 0..200_000 {
            let r = next();
            let mut pt = || [coord(next()), coord(next()), coord(next())];
            let w = |bit: u64| if r >> bit & 1 == 0 { 1.0 } else { 0.0 };
            let t: [H; 3] = [0, 1, 2].map(|k| {
                let c = pt();
                let w = if k == 0 { 1.0 } else { w(k as u64) };
                [c[0] as f64, c[1] as f64, c[2] as f64, w]
            });
            // Sometimes a starts on the triangle: at its first corner, or
            // at the rounded midpoint of its first edge.
            let a = match (r >> 20) % 4 {
                1 => t[0],
                2 if t[1][3] == 1.0 => {
                    let m = [0, 1, 2].map(|k| ((t[0][k] + t[1][k]) / 2.0) as f32 as f64);
                    [m[0], m[1], m[2], 1.0]
                }
                _ => {
                    let c = pt();
                    [c[0] as f64, c[1] as f64, c[2] as f64, 1.0]
                }
            };
            let mut b = {
                let c = pt();
                [c[0] as f64, c[1] as f64, c[2] as f64, w(3)]
            };
            // Aim at a corner, an edge's midpoint (rounded to f32) or the
            // plane's centroid, then maybe nudge one coordinate by an ulp.
            let aim = (r >> 8) % 4;
            if aim > 0 && t.iter().all(|c| c[3] == 1.0) {
                let target: [f64; 3] = match aim {
                    1 => [t[0][0], t[0][1], t[0][2]],
                    2 => [0, 1, 2].map(|k| ((t[1][k] + t[2][k]) / 2.0) as f32 as f64),
                    _ => [0, 1, 2].map(|k| ((t[0][k] + t[1][k] + t[2][k]) / 3.0) as f32 as f64),
                };
                b = if b[3] == 1.0 {
                    [target[0], target[1], target[2], 1.0]
                } else {
                    // The direction from a to the target, rounded.
                    let dir = [0, 1, 2].map(|k| (target[k] - a[k]) as f32 as f64);
                    [dir[0], dir[1], dir[2], 0.0]
                };
                if r >> 12 & 1 == 1 {
                    let k = (r >> 13) as usize % 3;
                    b[k] = ulp(b[k], r >> 15 & 1 == 1);
                }
            }
            if b[..3] == a[..3] && b[3] == 1.0 {
                continue;
            }
            let exact = meet_exact(a, b, t);
            if passes_beside(&a, &b, &t, 0.0) {
                filtered += 1;
                assert_eq!(
                    exact,
                    Meet::None,
                    "case {i}: filter said beside, {a:?} {b:?} {t:?}"
                );
            } else {
                declined += 1;
            }
            kinds[match exact {
                Meet::None => 0,
                Meet::Cross(_) => 1,
                Meet::AOnTriangle => 2,
                Meet::Degenerate => 3,
            }] += 1;
            assert_eq!(meet(a, b, t), exact, "case {i}");
        }
        // Not vacuous: the filter answers most calls, declines many, and
        // every kind of answer occurs.
        assert!(
            filtered > 80_000 && declined > 20_000,
            "{filtered} {declined}"
        );
        assert!(kinds.iter().all(|&k| k > 50), "{kinds:?}");
    }

    #[test]
    fn segment_meets_triangle() {
        let t = [p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), p(0.0, 1.0, 0.0)];
        assert!(matches!(
            meet(p(0.2, 0.2, -1.0), p(0.2, 0.2, 1.0), t),
            Meet::Cross(_)
        ));
        assert_eq!(meet(p(0.2, 0.2, 1.0), p(0.2, 0.2, 2.0), t), Meet::None);
        assert_eq!(meet(p(2.0, 2.0, -1.0), p(2.0, 2.0, 1.0), t), Meet::None);
        assert_eq!(
            meet(p(0.5, 0.0, -1.0), p(0.5, 0.0, 1.0), t),
            Meet::Degenerate
        );
        assert_eq!(
            meet(p(0.2, 0.2, 0.0), p(0.2, 0.2, 1.0), t),
            Meet::AOnTriangle
        );
        // Ray to infinity (b at infinity) and a triangle with a corner at infinity.
        assert!(matches!(
            meet(p(0.2, 0.2, -1.0), d(0.0, 0.0, 1.0), t),
            Meet::Cross(_)
        ));
        let wedge = [p(0.0, 0.0, 0.0), p(1.0, 0.0, 0.0), d(0.0, 1.0, 0.0)];
        assert!(matches!(
            meet(p(0.5, 5.0, -1.0), p(0.5, 5.0, 1.0), wedge),
            Meet::Cross(_)
        ));
        assert_eq!(
            meet(p(-0.5, 5.0, -1.0), p(-0.5, 5.0, 1.0), wedge),
            Meet::None
        );
        // Opposite crossing directions give opposite signs.
        let up = meet(p(0.2, 0.2, -1.0), p(0.2, 0.2, 1.0), t);
        let down = meet(p(0.2, 0.2, 1.0), p(0.2, 0.2, -1.0), t);
        assert!(matches!((up, down), (Meet::Cross(x), Meet::Cross(y)) if x == -y));
        // A triangle at infinity (directions) is met by the ray whose
        // direction lies in its cone, not by the opposite ray.
        let sky = [d(1.0, 0.0, 1.0), d(0.0, 1.0, 1.0), d(-1.0, -1.0, 1.0)];
        let o = p(5.0, -3.0, 2.0);
        assert!(matches!(meet(o, d(0.0, 0.0, 1.0), sky), Meet::Cross(_)));
        assert_eq!(meet(o, d(0.0, 0.0, -1.0), sky), Meet::None);
        assert_eq!(meet(o, d(1.0, 0.0, 0.0), sky), Meet::None);
    }
}
