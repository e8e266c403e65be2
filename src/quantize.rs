//! Record space: where the shaders and the evaluator do their arithmetic.
//!
//! A file stores every position in *record space*, and each mesh carries the
//! per-axis transform `world = offset + record · scale` (format-spec §4.5).
//! With the f32 encoding the transform is the identity. With the unorm16
//! encoding a position is the code `c = round((p − offset) / scale · 65535)`,
//! and record space is what a GPU reads from a normalized UNSIGNED_SHORT
//! attribute, `c / 65535`.
//!
//! Why evaluate in record space rather than dequantise to world space first:
//! the sides and caps shaders then compute the multiplicity contract on the
//! values the GPU fetched, with no extra arithmetic in between, so they agree
//! bit for bit exactly as with f32 files; the transform to world space is
//! folded into the view-projection matrix, and the light is moved into
//! record space once per frame (it is a uniform, so every vertex sees the
//! same rounded value). A positive per-axis affine map preserves the sign of
//! every orientation, so the exact answers are the same in both spaces.
//!
//! Quantising happens before welding: positions that round to the same code
//! become one vertex, and triangles that collapse are dropped as degenerate,
//! so the lexicographic order and the topology are those of the stored codes.

use crate::format::{Encoding, unorm16_to_f32};
use crate::multiplicity::Light;

/// Per-axis map from record space to world space.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordSpace {
    /// World position of record coordinate 0.
    pub offset: [f32; 3],
    /// World length of record coordinate 1 (always > 0).
    pub scale: [f32; 3],
}

impl RecordSpace {
    /// The identity (f32 encoding).
    pub const IDENTITY: RecordSpace = RecordSpace {
        offset: [0.0; 3],
        scale: [1.0; 3],
    };

    /// The unorm16 quantisation box over `lo..hi`: offset `lo`, scale `hi − lo`
    /// rounded up to f32 (1 on an axis with no extent, so the map stays
    /// invertible).
    pub fn unorm16_box(lo: [f32; 3], hi: [f32; 3]) -> RecordSpace {
        let scale = [0, 1, 2].map(|k| {
            let e = hi[k] as f64 - lo[k] as f64;
            if e > 0.0 {
                // Round up so every position maps into 0..=1.
                let s = e as f32;
                if (s as f64) < e { s.next_up() } else { s }
            } else {
                1.0
            }
        });
        RecordSpace { offset: lo, scale }
    }

    /// World position (f64, exact for unorm16 codes up to one rounding) of a
    /// record-space position.
    pub fn to_world(&self, r: [f32; 3]) -> [f64; 3] {
        [0, 1, 2].map(|k| self.offset[k] as f64 + r[k] as f64 * self.scale[k] as f64)
    }

    /// A world-space light moved into record space, computed in f64 and
    /// rounded once to f32: `xyz' = (xyz − offset · w) / scale`, `w' = w`.
    /// For the identity this returns `light` unchanged. Renderers compute the
    /// same value (format-spec §4.5); it only has to be the same for every
    /// vertex of a frame, which a uniform guarantees.
    pub fn light_to_record(&self, light: Light) -> Light {
        let w = light[3] as f64;
        let c = |k: usize| {
            ((light[k] as f64 - self.offset[k] as f64 * w) / self.scale[k] as f64) as f32
        };
        [c(0), c(1), c(2), light[3]]
    }

    /// A world-space point moved into record space (f64, rounded once).
    pub fn point_to_record(&self, p: [f32; 3]) -> [f32; 3] {
        [0, 1, 2].map(|k| ((p[k] as f64 - self.offset[k] as f64) / self.scale[k] as f64) as f32)
    }
}

/// Unorm16 code of a world coordinate on one axis of `space`.
#[inline]
fn code(v: f32, space: &RecordSpace, k: usize) -> u16 {
    let t = (v as f64 - space.offset[k] as f64) / space.scale[k] as f64;
    (t * 65535.0).round().clamp(0.0, 65535.0) as u16
}

/// Positions moved into record space for `enc`: unchanged for f32; for
/// unorm16 each coordinate becomes the record-space value of its code, so
/// that writing it back ([`crate::format::f32_to_unorm16`]) gives the code again.
pub fn to_record_space(
    positions: &[[f32; 3]],
    space: &RecordSpace,
    enc: Encoding,
) -> Vec<[f32; 3]> {
    match enc {
        Encoding::F32 => positions.to_vec(),
        Encoding::Unorm16 => positions
            .iter()
            .map(|p| [0, 1, 2].map(|k| unorm16_to_f32(code(p[k], space, k))))
            .collect(),
    }
}

/// Bounds of the positions that `indices` reference (zeros when none).
pub fn used_bounds(positions: &[[f32; 3]], indices: &[u32]) -> ([f32; 3], [f32; 3]) {
    if indices.is_empty() {
        return ([0.0; 3], [0.0; 3]);
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in indices {
        let p = positions[i as usize];
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::format::f32_to_unorm16;

    #[test]
    fn codes_round_trip_and_cover_the_box() {
        let lo = [-1.5, 2.0, 1e6];
        let hi = [3.25, 2.0, 1e6 + 7.0];
        let s = RecordSpace::unorm16_box(lo, hi);
        assert_eq!(s.scale[1], 1.0, "flat axis gets scale 1");
        let pts = [lo, hi, [0.0, 2.0, 1e6 + 3.0]];
        let r = to_record_space(&pts, &s, Encoding::Unorm16);
        assert_eq!(r[0], [0.0, 0.0, 0.0]);
        assert_eq!(r[1][0], 1.0);
        assert_eq!(r[1][2], 1.0);
        for (p, q) in pts.iter().zip(&r) {
            for k in 0..3 {
                // The stored code is recovered exactly from the record value.
                assert_eq!(unorm16_to_f32(f32_to_unorm16(q[k])), q[k]);
                // Displacement is at most half a step (plus f64 rounding).
                let w = s.to_world(*q)[k];
                assert!((w - p[k] as f64).abs() <= 0.5 * s.scale[k] as f64 / 65535.0 * 1.000001);
            }
        }
    }

    #[test]
    fn every_code_is_distinct_and_ordered() {
        // Lexicographic order on record values must be the order on codes.
        let mut prev = -1.0f32;
        for c in 0..=u16::MAX {
            let u = unorm16_to_f32(c);
            assert!(u > prev);
            assert_eq!(f32_to_unorm16(u), c);
            prev = u;
        }
    }

    #[test]
    fn identity_light_is_unchanged_and_orientation_survives() {
        let l = [1.25, -3.0, 7.5, 1.0];
        assert_eq!(RecordSpace::IDENTITY.light_to_record(l), l);
        let d = [0.5, 0.25, -1.0, 0.0];
        assert_eq!(RecordSpace::IDENTITY.light_to_record(d), d);
        // A directional light is scaled, not translated.
        let s = RecordSpace {
            offset: [10.0, 20.0, 30.0],
            scale: [2.0, 4.0, 8.0],
        };
        assert_eq!(s.light_to_record(d), [0.25, 0.0625, -0.125, 0.0]);
        assert_eq!(
            s.light_to_record([12.0, 24.0, 38.0, 1.0]),
            [1.0, 1.0, 1.0, 1.0]
        );
    }
}
