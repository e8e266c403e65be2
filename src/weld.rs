//! Welding: merge corners with bit-identical positions and renumber vertices in
//! lexicographic (x, y, z) order.
//!
//! Renumbering in lexicographic order makes "vertex index a < vertex index b"
//! the same statement as "position a < position b" in the order the
//! multiplicity contract uses, so topology can orient edges by comparing
//! integers. It also makes the welded vertex numbering independent of how the
//! input happened to order its vertices.

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

/// Triangles per parallel block of the degenerate filter.
const TRI_BLOCK: usize = 1 << 14;

/// One sortable word per input vertex: the position's order key in the high
/// 96 bits, the vertex's input index in the low 32. Sorting these words sorts
/// by position, and equal positions by index, so the order is total and no
/// two words are equal.
#[inline(always)]
fn vertex_word(p: [f32; 3], index: usize) -> u128 {
    ((order_key(canonical(p[0])) as u128) << 96)
        | ((order_key(canonical(p[1])) as u128) << 64)
        | ((order_key(canonical(p[2])) as u128) << 32)
        | index as u128
}

/// Welds the soup `positions`/`indices` (3 indices per triangle, all in range,
/// all positions used by a triangle finite). Drops triangles with two equal
/// welded corners.
///
/// Method: one sort. Every input vertex becomes a 128-bit word (position key
/// above index, [`vertex_word`]); after sorting, runs of equal position keys
/// are the welded vertices, already in lexicographic order, so numbering the
/// runs welds and orders in one pass. A hash map of positions followed by a
/// sort of the distinct ones did the same work twice, with a cache miss per
/// vertex in the map.
pub fn weld(positions: &[[f32; 3]], indices: &[u32]) -> Welded {
    use rayon::prelude::*;
    // 1. Sort all input vertices by position. Words are distinct, so the
    //    parallel unstable sort has one possible result whatever the threads.
    let mut words: Vec<u128> = positions
        .par_iter()
        .enumerate()
        .map(|(i, &p)| vertex_word(p, i))
        .collect();
    words.par_sort_unstable();

    // 2. Number the runs of equal positions: `run[i]` is input vertex i's
    //    welded id before unused vertices are removed.
    let mut run = vec![0u32; positions.len()];
    let mut run_first: Vec<u32> = Vec::with_capacity(positions.len());
    let mut prev_key = None;
    for &w in &words {
        let key = w >> 32;
        if prev_key != Some(key) {
            prev_key = Some(key);
            run_first.push(w as u32);
        }
        run[w as u32 as usize] = run_first.len() as u32 - 1;
    }
    drop(words);

    // 3. Keep non-degenerate triangles, in run ids, in input order: fixed
    //    blocks in parallel, concatenated in block order.
    let kept: Vec<(Vec<u32>, Vec<u32>)> = indices
        .par_chunks(3 * TRI_BLOCK)
        .enumerate()
        .map(|(blk, block)| {
            let mut tris = Vec::with_capacity(block.len());
            let mut source = Vec::with_capacity(block.len() / 3);
            for (i, c) in block.chunks_exact(3).enumerate() {
                let (a, b, d) = (run[c[0] as usize], run[c[1] as usize], run[c[2] as usize]);
                if a != b && b != d && a != d {
                    tris.extend_from_slice(&[a, b, d]);
                    source.push((blk * TRI_BLOCK + i) as u32);
                }
            }
            (tris, source)
        })
        .collect();
    let kept_count: usize = kept.iter().map(|k| k.1.len()).sum();
    let degenerate = (indices.len() / 3 - kept_count) as u64;
    let mut triangles = Vec::with_capacity(3 * kept_count);
    let mut source_triangle = Vec::with_capacity(kept_count);
    for (tris, source) in kept {
        triangles.extend_from_slice(&tris);
        source_triangle.extend_from_slice(&source);
    }
    let mut used = vec![false; run_first.len()];
    for &v in &triangles {
        used[v as usize] = true;
    }
    drop(run);

    // 4. Drop unused runs (vertices no kept triangle references) and renumber
    //    densely; the order stays lexicographic.
    let mut rank = vec![u32::MAX; run_first.len()];
    let mut out_positions = Vec::with_capacity(run_first.len());
    for (r, &first) in run_first.iter().enumerate() {
        if used[r] {
            rank[r] = out_positions.len() as u32;
            out_positions.push(positions[first as usize].map(canonical));
        }
    }
    if out_positions.len() != run_first.len() {
        triangles
            .par_iter_mut()
            .for_each(|v| *v = rank[*v as usize]);
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

    /// The obvious implementation: a sorted map of canonical positions.
    fn naive(pos: &[[f32; 3]], idx: &[u32]) -> Welded {
        use std::collections::BTreeMap;
        let key = |i: u32| pos[i as usize].map(canonical).map(order_key);
        let mut kept = Vec::new();
        let mut out = Welded::default();
        for (t, c) in idx.chunks_exact(3).enumerate() {
            let k = [key(c[0]), key(c[1]), key(c[2])];
            if k[0] == k[1] || k[1] == k[2] || k[0] == k[2] {
                out.degenerate += 1;
            } else {
                kept.push((t as u32, c));
            }
        }
        let mut ids: BTreeMap<[u32; 3], u32> = BTreeMap::new();
        for (_, c) in &kept {
            for &i in c.iter() {
                ids.insert(key(i), 0);
            }
        }
        for (n, (k, id)) in ids.iter_mut().enumerate() {
            *id = n as u32;
            let first = (0..pos.len() as u32).find(|&i| key(i) == *k).unwrap();
            out.positions.push(pos[first as usize].map(canonical));
        }
        for (t, c) in kept {
            out.triangles.extend(c.iter().map(|&i| ids[&key(i)]));
            out.source_triangle.push(t);
        }
        out
    }

    #[test]
    fn matches_the_obvious_implementation() {
        // A lattice small enough that positions repeat (weld), with -0.0,
        // degenerate triangles, an unused and a NaN unreferenced vertex, and
        // more triangles than one parallel block.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rng = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed >> 11
        };
        let coord = |r: u64| [-1.0, -0.0, 0.0, 0.5, 1.0, 2.0][(r % 6) as usize];
        let mut pos: Vec<[f32; 3]> = (0..400)
            .map(|_| [coord(rng()), coord(rng()), coord(rng())])
            .collect();
        pos.push([9.0, 9.0, 9.0]); // never referenced
        pos.push([f32::NAN, 0.0, 0.0]); // never referenced
        let idx: Vec<u32> = (0..3 * (TRI_BLOCK + 999))
            .map(|_| (rng() % 400) as u32)
            .collect();
        let w = weld(&pos, &idx);
        let n = naive(&pos, &idx);
        assert!(w.degenerate > 0 && w.positions.len() < 400);
        assert_eq!(w.positions, n.positions);
        assert_eq!(w.triangles, n.triangles);
        assert_eq!(w.source_triangle, n.source_triangle);
        assert_eq!(w.degenerate, n.degenerate);
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
