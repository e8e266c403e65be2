//! Welding: merge corners with bit-identical positions and renumber vertices in
//! lexicographic (x, y, z) order.
//!
//! Renumbering in lexicographic order makes "vertex index a < vertex index b"
//! the same statement as "position a < position b" in the order the
//! multiplicity contract uses, so topology can orient edges by comparing
//! integers. It also makes the welded vertex numbering independent of how the
//! input happened to order its vertices.

use rustc_hash::FxHashMap;

/// Result of [`weld`].
#[derive(Debug, Clone, Default)]
pub struct Welded {
    /// Distinct positions used by kept triangles, strictly increasing in
    /// lexicographic (x, y, z) order; no `-0.0`.
    pub positions: Vec<[f32; 3]>,
    /// Kept triangles, 3 indices each into `positions`, in input order and input winding.
    pub triangles: Vec<u32>,
    /// For each kept triangle, its index in the input soup.
    pub source_triangle: Vec<u32>,
    /// Triangles dropped because two corners welded to the same position.
    pub degenerate: u64,
}

impl Welded {
    /// Number of kept triangles.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len() / 3
    }

    /// The three corner positions of kept triangle `t`.
    pub fn corners(&self, t: usize) -> [[f32; 3]; 3] {
        let i = &self.triangles[3 * t..3 * t + 3];
        [
            self.positions[i[0] as usize],
            self.positions[i[1] as usize],
            self.positions[i[2] as usize],
        ]
    }
}

/// `+0.0` for both zeros, the value itself otherwise.
#[inline(always)]
pub fn canonical(v: f32) -> f32 {
    if v == 0.0 { 0.0 } else { v }
}

/// Maps an f32 to a u32 whose unsigned order equals the float order (for
/// non-NaN values; `-0.0` must already be canonical).
#[inline(always)]
fn order_key(v: f32) -> u32 {
    let b = v.to_bits();
    if b & 0x8000_0000 != 0 {
        !b
    } else {
        b | 0x8000_0000
    }
}

#[inline(always)]
fn position_key(p: [f32; 3]) -> u128 {
    ((order_key(p[0]) as u128) << 64) | ((order_key(p[1]) as u128) << 32) | order_key(p[2]) as u128
}

/// Welds the soup `positions`/`indices` (3 indices per triangle, all in range,
/// all positions finite). Drops triangles with two equal welded corners.
pub fn weld(positions: &[[f32; 3]], indices: &[u32]) -> Welded {
    // 1. Distinct canonical positions among referenced vertices, by hashing the
    //    bit patterns (exact equality is what we want, not a tolerance).
    let mut first_id: Vec<u32> = vec![u32::MAX; positions.len()];
    let mut unique: Vec<[f32; 3]> = Vec::new();
    let mut map: FxHashMap<[u32; 3], u32> = FxHashMap::default();
    for &i in indices {
        let i = i as usize;
        if first_id[i] != u32::MAX {
            continue;
        }
        let p = positions[i].map(canonical);
        let key = p.map(f32::to_bits);
        let next = unique.len() as u32;
        let id = *map.entry(key).or_insert_with(|| {
            unique.push(p);
            next
        });
        first_id[i] = id;
    }
    drop(map);

    // 2. Keep non-degenerate triangles (in unique-id space).
    let tri_count = indices.len() / 3;
    let mut triangles = Vec::with_capacity(indices.len());
    let mut source_triangle = Vec::with_capacity(tri_count);
    let mut used = vec![false; unique.len()];
    let mut degenerate = 0u64;
    for (t, c) in indices.chunks_exact(3).enumerate() {
        let (a, b, d) = (
            first_id[c[0] as usize],
            first_id[c[1] as usize],
            first_id[c[2] as usize],
        );
        if a == b || b == d || a == d {
            degenerate += 1;
            continue;
        }
        triangles.extend_from_slice(&[a, b, d]);
        source_triangle.push(t as u32);
        used[a as usize] = true;
        used[b as usize] = true;
        used[d as usize] = true;
    }

    // 3. Sort the used distinct positions lexicographically and renumber.
    let mut order: Vec<(u128, u32)> = unique
        .iter()
        .enumerate()
        .filter(|(i, _)| used[*i])
        .map(|(i, &p)| (position_key(p), i as u32))
        .collect();
    // Keys are distinct, so the parallel sort is deterministic.
    rayon::slice::ParallelSliceMut::par_sort_unstable_by_key(&mut order[..], |e| e.0);
    let mut rank = vec![u32::MAX; unique.len()];
    let mut out_positions = Vec::with_capacity(order.len());
    for (r, &(_, i)) in order.iter().enumerate() {
        rank[i as usize] = r as u32;
        out_positions.push(unique[i as usize]);
    }
    for v in triangles.iter_mut() {
        *v = rank[*v as usize];
    }

    Welded {
        positions: out_positions,
        triangles,
        source_triangle,
        degenerate,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::multiplicity::lex_less;

    #[test]
    fn merges_signed_zero_and_sorts() {
        let pos = [
            [1.0, 0.0, 0.0],
            [0.0, -0.0, 0.0],
            [0.0, 1.0, 0.0],
            [-0.0, 0.0, 0.0], // same as vertex 1
            [1.0, 0.0, 0.0],  // same as vertex 0
        ];
        let idx = [0, 1, 2, 4, 3, 2];
        let w = weld(&pos, &idx);
        assert_eq!(w.positions.len(), 3);
        assert!(w.positions.windows(2).all(|p| lex_less(p[0], p[1])));
        assert!(
            w.positions
                .iter()
                .flatten()
                .all(|v| v.to_bits() != (-0.0f32).to_bits())
        );
        assert_eq!(w.triangle_count(), 2);
        // Both triangles are the same triangle, same winding.
        assert_eq!(w.triangles[0..3], w.triangles[3..6]);
        assert_eq!(
            w.corners(0),
            [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
        );
    }

    #[test]
    fn drops_degenerates_and_unused() {
        let pos = [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [5.0, 5.0, 5.0], // only in the degenerate triangle
        ];
        let idx = [0, 1, 2, 1, 3, 4];
        let w = weld(&pos, &idx);
        assert_eq!(w.degenerate, 1);
        assert_eq!(w.triangle_count(), 1);
        assert_eq!(w.positions.len(), 3);
        assert_eq!(w.source_triangle, vec![0]);
    }

    #[test]
    fn negative_values_order() {
        let pos = [[-2.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, -3.0, 0.0]];
        let w = weld(&pos, &[0, 1, 2]);
        assert_eq!(
            w.positions,
            vec![[-2.0, 0.0, 0.0], [-1.0, -3.0, 0.0], [-1.0, 0.0, 0.0]]
        );
        assert_eq!(w.triangles, vec![0, 2, 1]);
    }
}
