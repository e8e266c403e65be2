//! Independent read-back check of a built file against its input: every kept
//! triangle is in the caps section, in input order and winding, and every
//! (triangle, edge) pair occurs exactly once among the sides entries
//! (edge instance, opposite slot), with A < B and the documented .w values.
//! Written without the library's weld/topology/layout code on purpose.

use std::collections::HashMap;
use std::path::Path;

type P = [u32; 3];

fn bits(x: f32, y: f32, z: f32) -> P {
    let c = |v: f32| if v == 0.0 { 0u32 } else { v.to_bits() };
    [c(x), c(y), c(z)]
}

fn less(a: P, b: P) -> bool {
    let f = |p: P| {
        [
            f32::from_bits(p[0]),
            f32::from_bits(p[1]),
            f32::from_bits(p[2]),
        ]
    };
    let (a, b) = (f(a), f(b));
    a.partial_cmp(&b) == Some(std::cmp::Ordering::Less)
}

/// Checks `svpk` against the model it was built from; panics with a reason.
pub fn check_file(svpk: &Path, input: &Path) {
    let f = svpack::format::read_file(svpk).unwrap_or_else(|e| panic!("{e}"));
    let soup = svpack::load::load(input).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(f.header.meshes.len(), 1);
    let m = &f.header.meshes[0];

    // Caps = non-degenerate input triangles, same order, same corner order.
    let caps = f.floats(m.caps.offset, m.caps.length);
    let mut expected = Vec::new();
    for c in soup.indices.chunks_exact(3) {
        let t: Vec<P> = c
            .iter()
            .map(|&i| {
                let p = soup.positions[i as usize];
                bits(p[0], p[1], p[2])
            })
            .collect();
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            expected.push([t[0], t[1], t[2]]);
        }
    }
    let got: Vec<[P; 3]> = caps
        .chunks_exact(12)
        .map(|r| {
            for i in 0..3 {
                assert_eq!(r[4 * i + 3], 1.0, "caps w must be 1");
            }
            [
                bits(r[0], r[1], r[2]),
                bits(r[4], r[5], r[6]),
                bits(r[8], r[9], r[10]),
            ]
        })
        .collect();
    assert_eq!(got.len(), expected.len(), "{}: caps count", input.display());
    assert!(
        got == expected,
        "{}: caps differ from the input triangles",
        input.display()
    );

    // Sides entries as a multiset of (A, B, O); per-edge totals for B.w.
    let mut pairs: HashMap<(P, P, P), i64> = HashMap::new();
    let mut totals: HashMap<(P, P), (u64, f32)> = HashMap::new();
    for b in &m.buckets {
        let k = b.k as usize;
        let data = f.floats(b.offset, b.length);
        assert_eq!(data.len(), b.instances as usize * (2 + k) * 4);
        for inst in data.chunks_exact((2 + k) * 4) {
            let a = bits(inst[0], inst[1], inst[2]);
            let bb = bits(inst[4], inst[5], inst[6]);
            assert!(less(a, bb), "edge endpoints not in A < B order");
            assert_eq!(inst[3], k as f32, "A.w must be the used opposite count");
            let t = totals.entry((a, bb)).or_insert((0, inst[7]));
            assert_eq!(t.1, inst[7], "B.w differs between chunks of one edge");
            t.0 += k as u64;
            for j in 0..k {
                let o = &inst[8 + 4 * j..12 + 4 * j];
                assert_eq!(o[3], 1.0, "O.w must be 1");
                *pairs.entry((a, bb, bits(o[0], o[1], o[2]))).or_insert(0) += 1;
            }
        }
    }
    for (edge, (n, bw)) in &totals {
        assert_eq!(
            *n as f32, *bw,
            "B.w of edge {edge:?} is not its opposite count"
        );
    }
    for t in &got {
        for e in 0..3 {
            let (p, q, r) = (t[e], t[(e + 1) % 3], t[(e + 2) % 3]);
            let (a, b) = if less(p, q) { (p, q) } else { (q, p) };
            *pairs.entry((a, b, r)).or_insert(0) -= 1;
        }
    }
    let bad: Vec<_> = pairs.iter().filter(|(_, c)| **c != 0).collect();
    assert!(
        bad.is_empty(),
        "{}: {} (edge, opposite) pairs not matched exactly once, e.g. {:?}",
        input.display(),
        bad.len(),
        bad.first()
    );
    assert_eq!(m.stats.triangles as usize, got.len());
}
