//! Topology: every undirected edge with the opposite vertex of every triangle
//! on it. Works on any soup: open, non-manifold, inconsistently wound,
//! duplicated triangles.
//!
//! Vertices come from [`crate::weld`] numbered in lexicographic position order,
//! so the edge orientation A < B of the contract is simply `a < b` on indices.
//! Edges are produced sorted by (a, b); each edge's opposite vertices are in
//! triangle order. Both orders are fully determined by the input.
//!
//! Method: counting sort of the 3·T half-edges by their smaller endpoint
//! (vertex ids are dense), then a stable sort by the larger endpoint inside each
//! bucket, which is tiny for real meshes (the vertex valence).

/// Edges in compressed-row form.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Edges {
    /// Smaller endpoint of each edge (lexicographically smaller position).
    pub a: Vec<u32>,
    /// Larger endpoint of each edge.
    pub b: Vec<u32>,
    /// `opp_start[e]..opp_start[e + 1]` is edge `e`'s range in `opp`/`opp_tri`.
    pub opp_start: Vec<u32>,
    /// Opposite vertex of each (edge, triangle) pair.
    pub opp: Vec<u32>,
    /// Triangle (index into the welded triangle list) of each (edge, triangle) pair.
    pub opp_tri: Vec<u32>,
}

impl Edges {
    /// Number of edges.
    pub fn len(&self) -> usize {
        self.a.len()
    }

    /// True when there are no edges.
    pub fn is_empty(&self) -> bool {
        self.a.is_empty()
    }

    /// Opposite-vertex count of edge `e`.
    #[inline]
    pub fn fan(&self, e: usize) -> usize {
        (self.opp_start[e + 1] - self.opp_start[e]) as usize
    }

    /// Opposite vertices of edge `e`.
    pub fn opposites(&self, e: usize) -> &[u32] {
        &self.opp[self.opp_start[e] as usize..self.opp_start[e + 1] as usize]
    }
}

/// Builds the edge structure of `triangles` (3 vertex ids each, no repeated
/// id within a triangle) over `vertex_count` vertices.
pub fn build_edges(triangles: &[u32], vertex_count: usize) -> Edges {
    // Half-edge record: larger endpoint, opposite vertex, triangle.
    #[derive(Clone, Copy)]
    struct Rec {
        b: u32,
        opp: u32,
        tri: u32,
    }
    let half_edges = triangles.len();
    // Count per smaller endpoint.
    let mut start = vec![0u32; vertex_count + 1];
    for c in triangles.chunks_exact(3) {
        for k in 0..3 {
            let (u, v) = (c[k], c[(k + 1) % 3]);
            start[u.min(v) as usize + 1] += 1;
        }
    }
    for i in 0..vertex_count {
        start[i + 1] += start[i];
    }
    let mut fill = start.clone();
    let mut recs = vec![
        Rec {
            b: 0,
            opp: 0,
            tri: 0
        };
        half_edges
    ];
    for (t, c) in triangles.chunks_exact(3).enumerate() {
        for k in 0..3 {
            let (u, v, w) = (c[k], c[(k + 1) % 3], c[(k + 2) % 3]);
            let (lo, hi) = if u < v { (u, v) } else { (v, u) };
            let slot = &mut fill[lo as usize];
            recs[*slot as usize] = Rec {
                b: hi,
                opp: w,
                tri: t as u32,
            };
            *slot += 1;
        }
    }
    drop(fill);

    // Per smaller endpoint: sort its records by larger endpoint, then emit
    // one edge per distinct larger endpoint. Vertices are cut into fixed
    // blocks that run in parallel: each block sorts its own records (disjoint
    // slices), counts its edges, and after a prefix sum writes them into its
    // own ranges of the output, so the result does not depend on threads.
    use rayon::prelude::*;
    let blocks = vertex_count.div_ceil(VERTEX_BLOCK);
    let mut rec_blocks: Vec<&mut [Rec]> = Vec::with_capacity(blocks);
    let mut rest: &mut [Rec] = &mut recs;
    for blk in 0..blocks {
        let (lo, hi) = (
            blk * VERTEX_BLOCK,
            ((blk + 1) * VERTEX_BLOCK).min(vertex_count),
        );
        let (mine, tail) = rest.split_at_mut((start[hi] - start[lo]) as usize);
        rec_blocks.push(mine);
        rest = tail;
    }
    let edge_counts: Vec<usize> = rec_blocks
        .par_iter_mut()
        .enumerate()
        .map(|(blk, recs)| {
            let base = start[blk * VERTEX_BLOCK];
            let hi = ((blk + 1) * VERTEX_BLOCK).min(vertex_count);
            let mut count = 0;
            for a in blk * VERTEX_BLOCK..hi {
                let bucket = &mut recs[(start[a] - base) as usize..(start[a + 1] - base) as usize];
                // Records were filled in triangle order; a stable sort by `b`
                // keeps triangle order within each edge.
                if bucket.len() <= 16 {
                    for i in 1..bucket.len() {
                        let mut j = i;
                        while j > 0 && bucket[j - 1].b > bucket[j].b {
                            bucket.swap(j - 1, j);
                            j -= 1;
                        }
                    }
                } else {
                    bucket.sort_by_key(|r| r.b);
                }
                count += bucket
                    .iter()
                    .enumerate()
                    .filter(|(i, r)| *i == 0 || bucket[i - 1].b != r.b)
                    .count();
            }
            count
        })
        .collect();
    let edge_total: usize = edge_counts.iter().sum();
    let mut edges = Edges {
        a: vec![0; edge_total],
        b: vec![0; edge_total],
        opp_start: vec![0; edge_total + 1],
        opp: vec![0; half_edges],
        opp_tri: vec![0; half_edges],
    };
    // Cut the outputs into the blocks' ranges.
    let mut outs = Vec::with_capacity(blocks);
    {
        let (mut ra, mut rb) = (&mut edges.a[..], &mut edges.b[..]);
        let mut rs = &mut edges.opp_start[1..];
        let (mut ro, mut rt) = (&mut edges.opp[..], &mut edges.opp_tri[..]);
        for (blk, &n) in edge_counts.iter().enumerate() {
            let m = (start[((blk + 1) * VERTEX_BLOCK).min(vertex_count)]
                - start[blk * VERTEX_BLOCK]) as usize;
            let (a1, a2) = ra.split_at_mut(n);
            let (b1, b2) = rb.split_at_mut(n);
            let (s1, s2) = rs.split_at_mut(n);
            let (o1, o2) = ro.split_at_mut(m);
            let (t1, t2) = rt.split_at_mut(m);
            outs.push((a1, b1, s1, o1, t1));
            (ra, rb, rs, ro, rt) = (a2, b2, s2, o2, t2);
        }
    }
    outs.into_par_iter()
        .zip(rec_blocks.into_par_iter())
        .enumerate()
        .for_each(|(blk, ((oa, ob, os, oo, ot), recs))| {
            let base = start[blk * VERTEX_BLOCK];
            let hi = ((blk + 1) * VERTEX_BLOCK).min(vertex_count);
            let mut e = 0;
            for a in blk * VERTEX_BLOCK..hi {
                let (lo, up) = ((start[a] - base) as usize, (start[a + 1] - base) as usize);
                let mut i = lo;
                while i < up {
                    let b = recs[i].b;
                    while i < up && recs[i].b == b {
                        oo[i] = recs[i].opp;
                        ot[i] = recs[i].tri;
                        i += 1;
                    }
                    oa[e] = a as u32;
                    ob[e] = b;
                    // Opposite ranges are global positions in `opp`.
                    os[e] = base + i as u32;
                    e += 1;
                }
            }
        });
    edges
}

/// Vertices per parallel block of the edge pass.
const VERTEX_BLOCK: usize = 1 << 14;

/// Edge statistics for summaries.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct EdgeStats {
    /// Number of edges.
    pub edges: u64,
    /// Edges with exactly one opposite vertex (boundary).
    pub open_edges: u64,
    /// Edges with more than two opposite vertices.
    pub non_manifold_edges: u64,
    /// Largest opposite-vertex count.
    pub max_fan: u32,
    /// `(n, edges with n opposite vertices)`, increasing n, only nonzero counts.
    pub histogram: Vec<(u32, u64)>,
}

/// Computes [`EdgeStats`].
pub fn edge_stats(edges: &Edges) -> EdgeStats {
    let mut hist: Vec<u64> = Vec::new();
    for e in 0..edges.len() {
        let n = edges.fan(e);
        if n >= hist.len() {
            hist.resize(n + 1, 0);
        }
        hist[n] += 1;
    }
    let histogram: Vec<(u32, u64)> = hist
        .iter()
        .enumerate()
        .filter(|(_, c)| **c > 0)
        .map(|(n, &c)| (n as u32, c))
        .collect();
    EdgeStats {
        edges: edges.len() as u64,
        open_edges: hist.get(1).copied().unwrap_or(0),
        non_manifold_edges: hist.iter().skip(3).sum(),
        max_fan: histogram.last().map(|h| h.0).unwrap_or(0),
        histogram,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tetrahedron_is_closed() {
        let tris = [0, 1, 2, 0, 3, 1, 1, 3, 2, 2, 3, 0];
        let e = build_edges(&tris, 4);
        assert_eq!(e.len(), 6);
        assert!((0..6).all(|i| e.fan(i) == 2));
        assert!(e.a.iter().zip(&e.b).all(|(a, b)| a < b));
        // Sorted by (a, b).
        let keys: Vec<(u32, u32)> = e.a.iter().copied().zip(e.b.iter().copied()).collect();
        let mut sorted = keys.clone();
        sorted.sort();
        assert_eq!(keys, sorted);
    }

    #[test]
    fn fan_keeps_triangle_order_and_duplicates() {
        // Edge (0,1) shared by 4 triangles, one duplicated with reversed winding.
        let tris = [0, 1, 2, 1, 0, 3, 4, 1, 0, 0, 2, 1];
        let e = build_edges(&tris, 5);
        let i = (0..e.len()).find(|&i| e.a[i] == 0 && e.b[i] == 1).unwrap();
        assert_eq!(e.opposites(i), &[2, 3, 4, 2]);
        assert_eq!(
            &e.opp_tri[e.opp_start[i] as usize..e.opp_start[i + 1] as usize],
            &[0, 1, 2, 3]
        );
        let s = edge_stats(&e);
        assert_eq!(s.max_fan, 4);
        assert_eq!(s.non_manifold_edges, 1);
    }
}
