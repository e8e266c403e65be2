//! CPU evaluator: the vertex shaders' decisions, computed on the CPU over the
//! file's own buffers (format-spec/multiplicity.md), for one light at a time.
//!
//! It reads the sides and caps records exactly as the GPU does (flat f32
//! arrays, one record after another) and calls the single implementation of
//! the float contract in [`crate::multiplicity`]. Work is split over records
//! with rayon; results do not depend on the thread count.

use crate::multiplicity::{Light, tri_sign};

/// How multiplicities and cap orientations are computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Strategy {
    /// The format's contract: reference edge in f32 (format-spec/multiplicity.md).
    #[default]
    Reference,
    /// Kim et al. 2008: one light plane per edge, opposite vertices tested
    /// against it; caps oriented by their own plane. Three different float
    /// expressions per triangle, so it can crack (kept as a peer and to show
    /// that verify catches it).
    Kim,
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
pub fn side_multiplicities_with(
    strategy: Strategy,
    k: usize,
    data: &[f32],
    light: Light,
    out: &mut [i8],
) {
    let sign = match strategy {
        Strategy::Reference => tri_sign,
        Strategy::Kim => kim_sign,
    };
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

/// Orientation (−1, 0, +1) of every caps record (12 floats each).
pub fn cap_signs(data: &[f32], light: Light, out: &mut [i8]) {
    cap_signs_with(Strategy::Reference, data, light, out)
}

/// [`cap_signs`] with an explicit strategy.
pub fn cap_signs_with(strategy: Strategy, data: &[f32], light: Light, out: &mut [i8]) {
    let sign = match strategy {
        Strategy::Reference => tri_sign,
        Strategy::Kim => kim_cap_sign,
    };
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
}
