//! Lint tests: one small generated input per code that triggers exactly that
//! finding with a hand-computed count, plus clean inputs that trigger nothing.

use svpack::lint::{CODES, Finding, Severity, lint_file, lint_soup};
use svpack::load::{LoadStats, Part, Soup};

// ---------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------

const TET_POS: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
];
/// Closed, consistently wound tetrahedron (each edge traversed both ways).
const TET_IDX: [u32; 12] = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];

fn part(name: &str, first: u32, count: u32) -> Part {
    Part {
        name: name.into(),
        first_triangle: first,
        triangle_count: count,
    }
}

/// Soup with one part "all" covering every triangle.
fn soup(positions: Vec<[f32; 3]>, indices: Vec<u32>) -> Soup {
    let n = (indices.len() / 3) as u32;
    Soup {
        positions,
        indices,
        parts: vec![part("all", 0, n)],
        ..Default::default()
    }
}

fn tet() -> Soup {
    soup(TET_POS.to_vec(), TET_IDX.to_vec())
}

fn codes(f: &[Finding]) -> Vec<&'static str> {
    f.iter().map(|f| f.code).collect()
}

/// The only finding, which must have `code` and `count`.
fn only<'a>(f: &'a [Finding], code: &str, count: u64) -> &'a Finding {
    assert_eq!(codes(f), vec![code], "{f:#?}");
    assert_eq!(f[0].count, count, "{f:#?}");
    assert_eq!(f[0].file, "t");
    let expected_examples = match code {
        "empty" | "skipped-points" | "skipped-lines" => 0,
        _ => count.min(3),
    };
    assert_eq!(
        f[0].examples.len() as u64,
        expected_examples,
        "examples of {code}"
    );
    &f[0]
}

fn triangles(f: &Finding) -> Vec<u64> {
    f.examples.iter().map(|e| e.triangle).collect()
}

fn write_obj(text: &str) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.obj");
    std::fs::write(&path, text).unwrap();
    (dir, path)
}

// ---------------------------------------------------------------------------
// Clean inputs and the code table
// ---------------------------------------------------------------------------

#[test]
fn clean_tetrahedron_has_no_findings() {
    assert!(lint_soup("t", &tet(), 5).is_empty());
}

#[test]
fn clean_tetrahedron_obj_file() {
    let (_d, path) = write_obj(
        "o tet\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n",
    );
    let f = lint_file(&path, 5).unwrap();
    assert!(f.is_empty(), "{f:#?}");
}

#[test]
fn lint_file_propagates_load_errors() {
    let dir = tempfile::tempdir().unwrap();
    assert!(lint_file(&dir.path().join("missing.obj"), 5).is_err());
}

#[test]
fn codes_table_is_sorted_unique_and_kebab() {
    assert_eq!(CODES.len(), 12);
    assert!(CODES.windows(2).all(|w| w[0].0 < w[1].0));
    for (c, _, d) in CODES {
        assert!(c.chars().all(|ch| ch.is_ascii_lowercase() || ch == '-'));
        assert!(!d.is_empty());
    }
    let sev = |c: &str| CODES.iter().find(|x| x.0 == c).unwrap().1;
    assert_eq!(sev("non-finite"), Severity::Error);
    assert_eq!(sev("open-edge"), Severity::Info);
    assert_eq!(sev("non-manifold-edge"), Severity::Warning);
}

#[test]
fn findings_serialize_lowercase_severity() {
    let f = lint_soup("t", &Soup::default(), 5);
    let j = serde_json::to_value(&f).unwrap();
    assert_eq!(j[0]["code"], "empty");
    assert_eq!(j[0]["severity"], "warning");
}

// ---------------------------------------------------------------------------
// One test per code
// ---------------------------------------------------------------------------

#[test]
fn empty() {
    let f = lint_soup("t", &Soup::default(), 5);
    let f = only(&f, "empty", 1);
    assert_eq!(f.severity, Severity::Warning);
    assert!(f.examples.is_empty());
}

#[test]
fn empty_file_with_only_points_and_lines() {
    let (_d, path) = write_obj("v 0 0 0\nv 1 0 0\np 1\nl 1 2\n");
    let f = lint_file(&path, 5).unwrap();
    assert_eq!(
        codes(&f),
        vec!["empty", "skipped-lines", "skipped-points"],
        "{f:#?}"
    );
    assert_eq!(f[1].count, 1);
    assert_eq!(f[2].count, 1);
}

#[test]
fn skipped_points() {
    let mut s = tet();
    s.stats = LoadStats {
        skipped_points: 2,
        ..Default::default()
    };
    let f = lint_soup("t", &s, 5);
    let f = only(&f, "skipped-points", 2);
    assert_eq!(f.severity, Severity::Info);
}

#[test]
fn skipped_lines() {
    let mut s = tet();
    s.stats = LoadStats {
        skipped_lines: 7,
        ..Default::default()
    };
    let f = lint_soup("t", &s, 5);
    only(&f, "skipped-lines", 7);
}

#[test]
fn non_finite() {
    let mut pos = TET_POS.to_vec();
    pos.extend([[5.0, 5.0, 5.0], [f32::NAN, 0.0, 0.0], [6.0, 5.0, 5.0]]);
    pos.push([f32::INFINITY, 0.0, 0.0]);
    let mut idx = TET_IDX.to_vec();
    idx.extend([4, 5, 6, 4, 6, 7]);
    let s = Soup {
        positions: pos,
        indices: idx,
        parts: vec![part("tet", 0, 4), part("bad", 4, 2)],
        ..Default::default()
    };
    let f = lint_soup("t", &s, 5);
    let f = only(&f, "non-finite", 2);
    assert_eq!(f.severity, Severity::Error);
    assert_eq!(triangles(f), vec![4, 5]);
    assert!(f.examples.iter().all(|e| e.part == "bad"));
    assert!(f.examples[0].positions[1][0].is_nan());
}

#[test]
fn degenerate_triangle() {
    let mut pos = TET_POS.to_vec();
    pos.push([1.0, 0.0, 0.0]); // same position as vertex 1
    let mut idx = TET_IDX.to_vec();
    idx.extend([0, 1, 4, 2, 2, 3]);
    let s = Soup {
        positions: pos,
        indices: idx,
        parts: vec![part("tet", 0, 4), part("junk", 4, 2)],
        ..Default::default()
    };
    let f = lint_soup("t", &s, 5);
    let f = only(&f, "degenerate-triangle", 2);
    assert_eq!(triangles(f), vec![4, 5]);
    assert_eq!(f.examples[0].part, "junk");
}

#[test]
fn zero_area_triangle() {
    // A closed two-triangle "pillow" on three collinear points, beside the tet.
    let mut pos = TET_POS.to_vec();
    pos.extend([[5.0, 5.0, 5.0], [6.0, 6.0, 5.5], [7.0, 7.0, 6.0]]);
    let mut idx = TET_IDX.to_vec();
    idx.extend([4, 5, 6, 4, 6, 5]);
    let f = lint_soup("t", &soup(pos, idx), 5);
    let f = only(&f, "zero-area-triangle", 2);
    assert_eq!(triangles(f), vec![4, 5]);
    assert_eq!(f.examples[0].part, "all");
    assert_eq!(
        f.examples[0].positions,
        vec![[5.0, 5.0, 5.0], [6.0, 6.0, 5.5], [7.0, 7.0, 6.0]]
    );
}

#[test]
fn zero_area_is_exact() {
    // Off the line by one ulp in z: not collinear, so no finding.
    let mut pos = TET_POS.to_vec();
    let z = f32::from_bits(6.0f32.to_bits() + 1);
    pos.extend([[5.0, 5.0, 5.0], [6.0, 6.0, 5.5], [7.0, 7.0, z]]);
    let mut idx = TET_IDX.to_vec();
    idx.extend([4, 5, 6, 4, 6, 5]);
    let f = lint_soup("t", &soup(pos, idx), 5);
    assert!(f.is_empty(), "{f:#?}");
}

#[test]
fn open_edge() {
    let f = lint_soup("t", &soup(TET_POS[..3].to_vec(), vec![0, 1, 2]), 5);
    let f = only(&f, "open-edge", 3);
    assert_eq!(f.severity, Severity::Info);
    assert_eq!(triangles(f), vec![0, 0, 0]);
    assert_eq!(f.examples[0].positions.len(), 2);
}

/// Two tetrahedra sharing edge 0–1 (the second is the first rotated 180°
/// about x): closed, consistently wound, one edge with fan 4.
fn two_tets() -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut pos = TET_POS.to_vec();
    pos.extend([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]);
    let mut idx = TET_IDX.to_vec();
    idx.extend(TET_IDX.iter().map(|&i| match i {
        2 => 4,
        3 => 5,
        i => i,
    }));
    (pos, idx)
}

#[test]
fn non_manifold_edge() {
    let (pos, idx) = two_tets();
    let f = lint_soup("t", &soup(pos, idx), 5);
    let f = only(&f, "non-manifold-edge", 1);
    assert!(f.message.contains("largest fan 4"), "{}", f.message);
    // Edge 0-1: first triangle on it is triangle 0.
    assert_eq!(triangles(f), vec![0]);
    assert_eq!(
        f.examples[0].positions,
        vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
    );
}

#[test]
fn non_manifold_edge_obj_part_names() {
    let (pos, idx) = two_tets();
    let mut text = String::new();
    for p in &pos {
        text += &format!("v {} {} {}\n", p[0], p[1], p[2]);
    }
    for (t, c) in idx.chunks(3).enumerate() {
        if t == 0 {
            text += "o second\n";
        }
        if t == 1 {
            text += "o first\n";
        }
        text += &format!("f {} {} {}\n", c[0] + 1, c[1] + 1, c[2] + 1);
    }
    let (_d, path) = write_obj(&text);
    let f = lint_file(&path, 5).unwrap();
    assert_eq!(codes(&f), vec!["non-manifold-edge"], "{f:#?}");
    assert_eq!(f[0].examples[0].triangle, 0);
    assert_eq!(f[0].examples[0].part, "object \"second\"");
    assert_eq!(f[0].file, path.display().to_string());
}

#[test]
fn split_edge() {
    let f = lint_soup("t", &tet(), 1);
    let f = only(&f, "split-edge", 6);
    assert_eq!(f.severity, Severity::Info);
    assert!(lint_soup("t", &tet(), 2).is_empty());
    // With the fan-4 edge: split only below 4.
    let (pos, idx) = two_tets();
    let s = soup(pos, idx);
    assert_eq!(
        codes(&lint_soup("t", &s, 3)),
        vec!["non-manifold-edge", "split-edge"]
    );
    assert_eq!(codes(&lint_soup("t", &s, 4)), vec!["non-manifold-edge"]);
}

#[test]
fn inconsistent_winding() {
    let mut idx = TET_IDX.to_vec();
    idx.swap(10, 11); // flip triangle 3
    let s = Soup {
        positions: TET_POS.to_vec(),
        indices: idx,
        parts: vec![part("a", 0, 3), part("b", 3, 1)],
        ..Default::default()
    };
    let f = lint_soup("t", &s, 5);
    let f = only(&f, "inconsistent-winding", 3);
    assert_eq!(triangles(f), vec![3, 3, 3]);
    assert!(f.examples.iter().all(|e| e.part == "b"));
}

#[test]
fn inconsistent_winding_obj() {
    let (_d, path) = write_obj(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\no a\nf 1 3 2\nf 1 2 4\no b\nf 1 3 4\no c\nf 2 3 4\n",
    );
    let f = lint_file(&path, 5).unwrap();
    assert_eq!(codes(&f), vec!["inconsistent-winding"], "{f:#?}");
    assert_eq!(f[0].count, 3);
    // Edges 0-2 and 0-3 pair the flipped triangle 2 (the later one) with
    // triangles 0 and 1; edge 2-3 pairs it with triangle 3, which comes later.
    let ex: Vec<(u64, &str)> = f[0]
        .examples
        .iter()
        .map(|e| (e.triangle, e.part.as_str()))
        .collect();
    assert_eq!(
        ex,
        vec![
            (2, "object \"b\""),
            (2, "object \"b\""),
            (3, "object \"c\"")
        ]
    );
}

#[test]
fn unwelded_seam_signed_zero() {
    let mut pos = TET_POS.to_vec();
    pos.push([-0.0, 0.0, 0.0]);
    let mut idx = TET_IDX.to_vec();
    idx[0] = 4; // triangle 0 uses -0 where the others use +0
    let f = lint_soup("t", &soup(pos, idx), 5);
    let f = only(&f, "unwelded-seam", 1);
    assert_eq!(f.severity, Severity::Warning);
    let p = &f.examples[0].positions;
    assert_eq!(p.len(), 2);
    assert_ne!(p[0][0].to_bits(), p[1][0].to_bits());
    assert_eq!(p[0][0], p[1][0]);
    assert!([0, 1, 2].contains(&f.examples[0].triangle));
}

/// The same seam on a vertex with one zero coordinate only, (1, ±0, 2):
/// the check looks at every vertex with a zero coordinate, not only at the
/// origin.
#[test]
fn unwelded_seam_signed_zero_in_one_coordinate() {
    let mut pos: Vec<[f32; 3]> = TET_POS
        .iter()
        .map(|p| [p[0] + 1.0, p[1], p[2] + 2.0])
        .collect();
    let at = pos.iter().position(|p| p[1] == 0.0 && p[0] != 0.0).unwrap();
    let mut flipped = pos[at];
    flipped[1] = -0.0;
    pos.push(flipped);
    let mut idx = TET_IDX.to_vec();
    let corner = idx.iter().position(|&i| i as usize == at).unwrap();
    idx[corner] = 4;
    let f = lint_soup("t", &soup(pos, idx), 5);
    let f = only(&f, "unwelded-seam", 1);
    let p = &f.examples[0].positions;
    assert_ne!(p[0][1].to_bits(), p[1][1].to_bits());
    assert_eq!(p[0], p[1]);
}

fn tet_at(dx: f32) -> (Vec<[f32; 3]>, Vec<u32>) {
    let mut pos = TET_POS.to_vec();
    pos.extend(TET_POS.iter().map(|p| [p[0] + dx, p[1], p[2]]));
    let mut idx = TET_IDX.to_vec();
    idx.extend(TET_IDX.iter().map(|i| i + 4));
    (pos, idx)
}

#[test]
fn unwelded_seam_within_tolerance() {
    // Second tet's vertex 0 is 4 ulps (4.8e-7) from the first tet's vertex 1;
    // bounds diagonal sqrt(6), tolerance 2.4e-6.
    let (pos, idx) = tet_at(f32::from_bits(1.0f32.to_bits() + 4));
    let s = Soup {
        parts: vec![part("a", 0, 4), part("b", 4, 4)],
        ..soup(pos, idx)
    };
    let f = lint_soup("t", &s, 5);
    let f = only(&f, "unwelded-seam", 1);
    // Vertex [1,0,0] (lexicographically first of the pair) is first used by triangle 0.
    assert_eq!(triangles(f), vec![0]);
    assert_eq!(f.examples[0].part, "a");
    assert_eq!(f.examples[0].positions[0], [1.0, 0.0, 0.0]);
}

#[test]
fn unwelded_seam_outside_tolerance() {
    let (pos, idx) = tet_at(1.0 + 1e-5);
    assert!(lint_soup("t", &soup(pos, idx), 5).is_empty());
    // Exactly shared vertex: welded, no seam.
    let (pos, idx) = tet_at(1.0);
    assert!(lint_soup("t", &soup(pos, idx), 5).is_empty());
}

#[test]
fn precision() {
    // Offset 65536: ulp(65546) = 2^-7, so edges shorter than 7.8125 fire:
    // 0-2, 0-3 (length 1) and 2-3 (sqrt 2); the three edges to vertex 1 are ~10.
    let o = 65536.0;
    let pos = vec![
        [o, 0.0, 0.0],
        [o + 10.0, 0.0, 0.0],
        [o, 1.0, 0.0],
        [o, 0.0, 1.0],
    ];
    let f = lint_soup("t", &soup(pos.clone(), TET_IDX.to_vec()), 5);
    let f = only(&f, "precision", 3);
    assert!(f.message.contains("1/1000"));
    // Same shape near the origin: fine.
    let near: Vec<[f32; 3]> = pos.iter().map(|p| [p[0] - 65000.0, p[1], p[2]]).collect();
    assert!(lint_soup("t", &soup(near, TET_IDX.to_vec()), 5).is_empty());
}

#[test]
fn findings_sorted_by_code() {
    let mut pos = TET_POS.to_vec();
    pos.push([f32::NAN, 0.0, 0.0]);
    let mut idx = TET_IDX.to_vec();
    idx.extend([0, 1, 4, 0, 1, 2]);
    let mut s = soup(pos, idx);
    s.stats.skipped_lines = 1;
    let f = lint_soup("t", &s, 1);
    let c = codes(&f);
    let mut sorted = c.clone();
    sorted.sort();
    assert_eq!(c, sorted);
    assert!(c.contains(&"non-finite") && c.contains(&"split-edge"));
}

#[test]
fn unwelded_seam_matches_brute_force() {
    // Random triangles over clustered points (cluster members 0.3..3 tolerances
    // apart); the grid hash must find exactly the pairs an O(n²) scan finds.
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for round in 0..20 {
        let mut pos: Vec<[f32; 3]> = Vec::new();
        for _ in 0..40 {
            let c = [0, 1, 2].map(|_| (rnd() % 1000) as f32 / 100.0);
            pos.push(c);
            for _ in 0..(rnd() % 3) {
                // About 10 * sqrt(3) diagonal -> tolerance ~1.7e-5.
                let d = [0, 1, 2].map(|_| (rnd() % 60) as f32 * 1e-6);
                pos.push([c[0] + d[0], c[1] + d[1], c[2] + d[2]]);
            }
        }
        let n = pos.len() as u64;
        let idx: Vec<u32> = (0..3 * 60).map(|_| (rnd() % n) as u32).collect();
        let s = soup(pos, idx);
        let w = svpack::weld::weld(&s.positions, &s.indices);
        let p = &w.positions;
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for q in p {
            for k in 0..3 {
                lo[k] = lo[k].min(q[k] as f64);
                hi[k] = hi[k].max(q[k] as f64);
            }
        }
        let diag =
            ((hi[0] - lo[0]).powi(2) + (hi[1] - lo[1]).powi(2) + (hi[2] - lo[2]).powi(2)).sqrt();
        let tol = 1e-6 * diag;
        let mut expected = 0u64;
        for i in 0..p.len() {
            for j in i + 1..p.len() {
                let d: [f64; 3] = std::array::from_fn(|k| p[i][k] as f64 - p[j][k] as f64);
                if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() <= tol {
                    expected += 1;
                }
            }
        }
        let f = lint_soup("t", &s, 5);
        let got = f
            .iter()
            .find(|f| f.code == "unwelded-seam")
            .map_or(0, |f| f.count);
        assert_eq!(got, expected, "round {round}");
        if round == 0 {
            assert!(expected > 0, "test data should contain near pairs");
        }
    }
}

#[test]
fn shipped_fixture_two_tets() {
    // README: 0 open edges, 1 non-manifold edge with fan 4.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/two_tets.obj");
    let f = lint_file(&path, 5).unwrap();
    let nm = f.iter().find(|f| f.code == "non-manifold-edge").unwrap();
    assert_eq!(nm.count, 1);
    assert!(nm.message.contains("largest fan 4"));
    assert!(f.iter().all(|f| f.code != "open-edge"), "{f:#?}");
}
