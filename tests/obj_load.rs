//! OBJ loader tests: the shared real-world OBJ files, the malformed ones, and
//! small hand-written files covering triangulation, indices, objects/groups,
//! points/lines and error reporting.
//!
//! Expected values come from a tiny independent OBJ reader in this file (it
//! counts `f` corners and resolves indices itself) and from independent
//! geometry (shoelace areas, point-in-polygon), never from the loader.

mod common;

use common::{cross, dot, sub};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use svpack::load::Soup;
use svpack::load::obj::load_obj;

// ---------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------

/// `../shared/meshes/<sub>`, or None (with a message naming the folder) when
/// the shared corpus is not checked out beside the project.
fn shared(sub: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/meshes")
        .join(sub);
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!("skipping: shared mesh folder {} is absent", dir.display());
        None
    }
}

fn obj_files(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("obj")))
        .collect();
    files.sort();
    files
}

fn load_path(path: &Path) -> svpack::error::Result<Soup> {
    load_obj(path, std::fs::read(path).unwrap())
}

/// Writes `text` to `name` in `dir` and loads it.
fn load_str(dir: &Path, name: &str, text: &str) -> (PathBuf, svpack::error::Result<Soup>) {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    let soup = load_path(&path);
    (path, soup)
}

fn ok(r: svpack::error::Result<Soup>) -> Soup {
    match r {
        Ok(s) => s,
        Err(e) => panic!("load failed: {e}"),
    }
}

/// Positions of triangle `t` in f64.
fn tri(soup: &Soup, t: usize) -> [[f64; 3]; 3] {
    let p = |k: usize| soup.positions[soup.indices[3 * t + k] as usize].map(f64::from);
    [p(0), p(1), p(2)]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}
/// Twice the vector area of a triangle.
fn tri_normal(t: [[f64; 3]; 3]) -> [f64; 3] {
    cross(sub(t[1], t[0]), sub(t[2], t[0]))
}
/// Twice the vector area of a closed polygon (Newell), written out
/// independently of the loader's version.
fn polygon_normal(p: &[[f64; 3]]) -> [f64; 3] {
    let mut n = [0.0; 3];
    for i in 0..p.len() {
        let c = cross(p[i], p[(i + 1) % p.len()]);
        n = [n[0] + c[0], n[1] + c[1], n[2] + c[2]];
    }
    n
}

/// Signed shoelace area of a 2D polygon.
fn shoelace(p: &[[f64; 2]]) -> f64 {
    let mut a = 0.0;
    for i in 0..p.len() {
        let (c, d) = (p[i], p[(i + 1) % p.len()]);
        a += c[0] * d[1] - d[0] * c[1];
    }
    a / 2.0
}

/// Even-odd point-in-polygon test in 2D.
fn inside(pt: [f64; 2], poly: &[[f64; 2]]) -> bool {
    let mut c = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + n - 1) % n]);
        if (a[1] > pt[1]) != (b[1] > pt[1])
            && pt[0] < (b[0] - a[0]) * (pt[1] - a[1]) / (b[1] - a[1]) + a[0]
        {
            c = !c;
        }
    }
    c
}

/// A minimal OBJ reader independent of the loader: vertex positions (x y z,
/// numbers read by their longest valid prefix), and every `f` statement as
/// its list of positions (continuation lines joined, relative indices
/// resolved).
struct Reference {
    faces: Vec<Vec<[f64; 3]>>,
}

impl Reference {
    fn read(path: &Path) -> Reference {
        let text = String::from_utf8_lossy(&std::fs::read(path).unwrap()).replace("\\\r\n", " ");
        let text = text.replace("\\\n", " ");
        let mut verts: Vec<[f64; 3]> = Vec::new();
        let mut faces = Vec::new();
        for line in text.lines() {
            let mut w = line.split_whitespace();
            match w.next() {
                Some("v") => {
                    let mut c = [0.0; 3];
                    for x in &mut c {
                        let s = w.next().unwrap();
                        *x = (1..=s.len())
                            .rev()
                            .find_map(|e| s[..e].parse::<f64>().ok())
                            .unwrap();
                    }
                    verts.push(c);
                }
                Some("f") => {
                    let face = w
                        .map(|c| {
                            let i: i64 = c.split('/').next().unwrap().parse().unwrap();
                            let i = if i < 0 { verts.len() as i64 + i } else { i - 1 };
                            verts[i as usize]
                        })
                        .collect();
                    faces.push(face);
                }
                _ => {}
            }
        }
        Reference { faces }
    }

    fn triangles(&self) -> usize {
        self.faces.iter().map(|f| f.len().saturating_sub(2)).sum()
    }
}

/// Checks a loaded soup against the reference faces, face by face in file
/// order (the loader emits n-2 triangles per face, in order):
/// * every triangle corner is a corner of its face;
/// * the triangles' vector areas add up to the face's (Newell) vector area;
/// * every triangle faces the same way as the face (winding kept);
/// * for planar faces the triangle areas add up to the face area, so the
///   triangles do not overlap or stick out.
///
/// Returns the number of polygons (>= 4 corners) checked.
fn check_faces(name: &str, soup: &Soup, reference: &Reference) -> usize {
    let mut t = 0;
    let mut polygons = 0;
    for (fi, face) in reference.faces.iter().enumerate() {
        if face.len() < 3 {
            continue;
        }
        let n = polygon_normal(face);
        let size = face
            .iter()
            .map(|p| norm(sub(*p, face[0])))
            .fold(0.0, f64::max);
        let tol = 1e-5 * size * size + 1e-12;
        // Only a planar face has a triangulation whose triangles all face
        // the way of the face; a warped one may need a triangle that leans
        // back (polygonfaces.obj has a corner lifted onto another's edge).
        let unit = n.map(|x| x / norm(n).max(1e-300));
        let planar = face
            .iter()
            .all(|p| dot(sub(*p, face[0]), unit).abs() <= 1e-6 * size);
        let mut vector = [0.0; 3];
        let mut abs_area = 0.0;
        for _ in 0..face.len() - 2 {
            let tr = tri(soup, t);
            for c in tr {
                assert!(
                    face.iter()
                        .any(|p| p.map(|x| x as f32) == c.map(|x| x as f32)),
                    "{name}: face {fi}: triangle {t} corner {c:?} is not a face corner"
                );
            }
            let tn = tri_normal(tr);
            assert!(
                !planar || dot(tn, n) >= -tol * norm(n).max(1e-30),
                "{name}: face {fi}: triangle {t} is wound against the face"
            );
            vector = [vector[0] + tn[0], vector[1] + tn[1], vector[2] + tn[2]];
            abs_area += norm(tn);
            t += 1;
        }
        assert!(
            norm(sub(vector, n)) <= tol * face.len() as f64,
            "{name}: face {fi}: triangle vector areas {vector:?} != face {n:?}"
        );
        if face.len() >= 4 {
            polygons += 1;
            if planar && norm(n) > 0.0 {
                assert!(
                    (abs_area - norm(n)).abs() <= 1e-6 * norm(n) + tol,
                    "{name}: face {fi} ({} corners): triangles cover area {} but the face has {}",
                    face.len(),
                    abs_area / 2.0,
                    norm(n) / 2.0
                );
            }
        }
    }
    assert_eq!(t, soup.triangle_count(), "{name}: triangles left over");
    polygons
}

/// Parts are in order, contiguous, non-empty and cover every triangle;
/// indices are in range.
fn check_structure(name: &str, soup: &Soup) {
    assert_eq!(soup.indices.len() % 3, 0, "{name}");
    let n = soup.positions.len();
    assert!(
        soup.indices.iter().all(|&i| (i as usize) < n),
        "{name}: index out of range"
    );
    let mut next = 0u32;
    for p in &soup.parts {
        assert_eq!(
            p.first_triangle, next,
            "{name}: part {} not contiguous",
            p.name
        );
        assert!(p.triangle_count > 0, "{name}: empty part {}", p.name);
        assert!(
            p.name.starts_with("object \""),
            "{name}: part name {}",
            p.name
        );
        next += p.triangle_count;
    }
    assert_eq!(
        next as usize,
        soup.triangle_count(),
        "{name}: parts do not cover all triangles"
    );
    assert_eq!(soup.stats.primitives, soup.parts.len() as u64, "{name}");
}

// ---------------------------------------------------------------------------
// (1) The shared real-world OBJ files
// ---------------------------------------------------------------------------

#[test]
fn every_shared_obj_loads_with_the_right_triangles() {
    let Some(dir) = shared("obj") else { return };
    let files = obj_files(&dir);
    assert!(
        files.len() >= 10,
        "expected the shared OBJ corpus in {}",
        dir.display()
    );
    let mut counts = Vec::new();
    let mut polygons = 0;
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        let bytes = std::fs::read(f).unwrap();
        let soup = ok(load_obj(f, bytes.clone()));
        let reference = Reference::read(f);
        assert_eq!(
            soup.triangle_count(),
            reference.triangles(),
            "{name}: triangle count"
        );
        check_structure(&name, &soup);
        polygons += check_faces(&name, &soup, &reference);
        assert_eq!(soup.input_bytes, bytes.len() as u64, "{name}");
        assert_eq!(
            soup.stats.skipped_points + soup.stats.skipped_lines,
            0,
            "{name}"
        );
        if !soup.stats.warnings.is_empty() {
            eprintln!("{name}: warnings {:?}", soup.stats.warnings);
        }
        counts.push((name, soup.triangle_count()));
    }
    eprintln!("triangle counts: {counts:?}");
    let count = |n: &str| counts.iter().find(|(f, _)| f == n).map(|c| c.1);
    // Known sizes (also in shared/meshes/README.md).
    assert_eq!(count("stanford-bunny.obj"), Some(69_451));
    assert_eq!(count("armadillo.obj"), Some(86_482));
    // 6 quads given with relative indices: a 2x2x2 cube of area 24.
    assert_eq!(count("negative_indices.obj"), Some(12));
    // suzanne: 32 triangles + 468 quads.
    assert_eq!(count("suzanne.obj"), Some(32 + 2 * 468));
    // One pentagon.
    assert_eq!(count("polygonfaces.obj"), Some(3));
    // wallhole: 13 polygons of 6 to 11 corners, three of them continued
    // over two lines with `\`.
    assert_eq!(count("wallhole.obj"), Some(66));
    assert!(polygons > 400, "only {polygons} polygons checked");
}

#[test]
fn negative_indices_make_a_cube() {
    let Some(dir) = shared("obj") else { return };
    let soup = ok(load_path(&dir.join("negative_indices.obj")));
    let area: f64 = (0..soup.triangle_count())
        .map(|t| norm(tri_normal(tri(&soup, t))) / 2.0)
        .sum();
    assert!((area - 24.0).abs() < 1e-9, "cube area {area}");
    // Closed and outward: the signed volume is +8.
    let volume: f64 = (0..soup.triangle_count())
        .map(|t| {
            let [a, b, c] = tri(&soup, t);
            dot(a, cross(b, c)) / 6.0
        })
        .sum();
    assert!((volume - 8.0).abs() < 1e-9, "cube volume {volume}");
}

#[test]
fn input_digest_is_recorded() {
    use sha2::{Digest, Sha256};
    let tmp = tempfile::tempdir().unwrap();
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    let (_, soup) = load_str(tmp.path(), "t.obj", text);
    let soup = ok(soup);
    assert_eq!(soup.input_bytes, text.len() as u64);
    let expected: [u8; 32] = Sha256::digest(text.as_bytes()).into();
    assert_eq!(soup.input_sha256, expected);
}

// ---------------------------------------------------------------------------
// (2) The malformed files
// ---------------------------------------------------------------------------

#[test]
fn every_malformed_obj_loads_sensibly_or_fails_cleanly() {
    let Some(dir) = shared("malformed") else {
        return;
    };
    let files = obj_files(&dir);
    assert!(
        files.len() >= 8,
        "expected the malformed OBJ files in {}",
        dir.display()
    );
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        let result = catch_unwind(AssertUnwindSafe(|| svpack::load::load(f)));
        match result {
            Err(_) => panic!("{name}: the loader panicked"),
            Ok(Err(e)) => {
                let msg = e.to_string();
                assert!(
                    msg.contains(&name),
                    "{name}: error does not name the file: {msg}"
                );
                eprintln!("{name}: error: {msg}");
            }
            Ok(Ok(soup)) => {
                check_structure(&name, &soup);
                eprintln!(
                    "{name}: {} triangles, {} points, {} lines skipped, warnings {:?}",
                    soup.triangle_count(),
                    soup.stats.skipped_points,
                    soup.stats.skipped_lines,
                    soup.stats.warnings
                );
            }
        }
    }
}

#[test]
fn points_and_lines_only_files_give_no_triangles() {
    let Some(dir) = shared("malformed") else {
        return;
    };
    // Three bare vertices: a point cloud, each vertex counted as a point.
    let s = ok(load_path(&dir.join("point_cloud.obj")));
    assert_eq!(s.triangle_count(), 0);
    assert_eq!(s.stats.skipped_points, 3);
    // Six `p` statements with four vertices each: 24 point elements.
    let s = ok(load_path(&dir.join("testpoints.obj")));
    assert_eq!(s.triangle_count(), 0);
    assert_eq!(s.stats.skipped_points, 24);
    assert_eq!(s.stats.skipped_lines, 0);
    // Six `l` polylines of four vertices each: must not become quads.
    let s = ok(load_path(&dir.join("testline.obj")));
    assert_eq!(s.triangle_count(), 0);
    assert_eq!(s.stats.skipped_lines, 6);
    assert_eq!(s.stats.skipped_points, 0);
    assert!(s.parts.is_empty());
}

#[test]
fn concave_polygon_obj_triangulates_exactly() {
    let Some(dir) = shared("malformed") else {
        return;
    };
    let path = dir.join("concave_polygon.obj");
    let soup = ok(load_path(&path));
    let reference = Reference::read(&path);
    assert_eq!(reference.faces.len(), 1);
    let face = &reference.faces[0];
    assert_eq!(face.len(), 66);
    assert_eq!(soup.triangle_count(), 64, "n-2 triangles");
    // The face lies in the plane x = -1.146: shoelace in (y, z). It is a ring
    // joined to its hole by a doubled edge, so the area is outer - inner.
    assert!(face.iter().all(|p| p[0] == face[0][0]));
    let poly: Vec<[f64; 2]> = face.iter().map(|p| [p[1], p[2]]).collect();
    let area = shoelace(&poly);
    let mut total = 0.0;
    for t in 0..soup.triangle_count() {
        let tr = tri(&soup, t);
        let a = shoelace(&tr.map(|p| [p[1], p[2]]));
        assert!(
            a * area.signum() >= -1e-12,
            "triangle {t} wound against the face"
        );
        total += a.abs();
    }
    assert!(
        (total - area.abs()).abs() < 1e-6 * area.abs(),
        "triangles cover {total}, polygon area {}",
        area.abs()
    );
    check_faces("concave_polygon.obj", &soup, &reference);
}

#[test]
fn number_formats_obj_reads_the_right_values() {
    let Some(dir) = shared("malformed") else {
        return;
    };
    let path = dir.join("number_formats.obj");
    let soup = ok(load_path(&path));
    assert_eq!(soup.triangle_count(), 1);
    assert_eq!(
        [0, 1, 2].map(|k| soup.positions[soup.indices[k] as usize]),
        [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0], [-1.0, -2.0, -3.0]]
    );
    // Reference every vertex so all values can be checked.
    let tmp = tempfile::tempdir().unwrap();
    let mut text = std::fs::read_to_string(&path).unwrap();
    text.push_str("\nf 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15\n");
    let (_, soup) = load_str(tmp.path(), "all.obj", &text);
    let soup = ok(soup);
    // Distinct positions in first-use order.
    let mut seen = Vec::new();
    for &i in &soup.indices[3..] {
        let p = soup.positions[i as usize];
        if !seen.contains(&p) {
            seen.push(p);
        }
    }
    let expected: [[f32; 3]; 15] = [
        [0.0, 0.0, 0.0],
        [1.0, 2.0, 3.0],
        [1.0, 2.0, 3.0],
        [-1.0, -2.0, -3.0],
        [100.0, 20.0, 310.0],
        [100.0, 20.0, 310.0],
        [-100.0, -20.0, -310.0],
        // `3.1+e2` and `3.1-e2` are malformed; read like C's strtod: 3.1.
        [100.0, 20.0, 3.1],
        [100.0, 20.0, 3.1],
        [-100.0, -20.0, -3.1],
        [0.01, 0.2, 3.1],
        [0.01, 0.2, 3.1],
        [-0.01, -0.2, -3.1],
        [1e10, 20.0, 3.1e10],
        [100.0, 20.0, 310.0],
    ];
    let mut distinct: Vec<[f32; 3]> = Vec::new();
    for p in expected {
        if !distinct.contains(&p) {
            distinct.push(p);
        }
    }
    assert_eq!(seen, distinct);
    assert!(
        soup.stats.warnings.iter().any(|w| w.contains("3.1+e2")),
        "{:?}",
        soup.stats.warnings
    );
}

#[test]
fn utf16_obj_is_decoded() {
    let Some(dir) = shared("malformed") else {
        return;
    };
    let soup = ok(load_path(&dir.join("box_UTF16BE.obj")));
    assert_eq!(soup.triangle_count(), 12);
    assert!(soup.stats.warnings.iter().any(|w| w.contains("UTF-16")));
}

// ---------------------------------------------------------------------------
// (3) Small hand-written files
// ---------------------------------------------------------------------------

/// The L-shaped hexagon (area 3), starting at a corner from which a fan is
/// wrong: the fan's diagonal (2,0)-(1,2) leaves the polygon.
const L_SHAPE: [[f64; 2]; 6] = [
    [2.0, 0.0],
    [2.0, 1.0],
    [1.0, 1.0],
    [1.0, 2.0],
    [0.0, 2.0],
    [0.0, 0.0],
];

/// Places 2D point `p` in 3D on a plane spanned by `u`, `v` through `o`.
fn place(p: [f64; 2], o: [f64; 3], u: [f64; 3], v: [f64; 3]) -> [f64; 3] {
    [
        o[0] + p[0] * u[0] + p[1] * v[0],
        o[1] + p[0] * u[1] + p[1] * v[1],
        o[2] + p[0] * u[2] + p[1] * v[2],
    ]
}

#[test]
fn concave_polygons_are_triangulated_inside_with_winding_kept() {
    let tmp = tempfile::tempdir().unwrap();
    // Planes whose normals point along +-x, +-y, +-z and obliquely, and both
    // windings, so every projection and handedness case is exercised.
    let planes: [([f64; 3], [f64; 3]); 7] = [
        ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        ([0.0, 1.0, 0.0], [1.0, 0.0, 0.0]),
        ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
        ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
        ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
        ([0.6, 0.0, 0.8], [0.0, 0.96, -0.28]),
    ];
    let mut case = 0;
    for (u, v) in planes {
        for reversed in [false, true] {
            let mut poly = L_SHAPE.to_vec();
            if reversed {
                poly.reverse();
            }
            let o = [10.0, -5.0, 3.0];
            let mut text = String::from("o L\n");
            for p in &poly {
                let q = place(*p, o, u, v);
                text += &format!("v {} {} {}\n", q[0], q[1], q[2]);
            }
            text += "f 1 2 3 4 5 6\n";
            case += 1;
            let (_, soup) = load_str(tmp.path(), &format!("l{case}.obj"), &text);
            let soup = ok(soup);
            assert_eq!(soup.triangle_count(), 4, "case {case}");
            let face3: Vec<[f64; 3]> = poly.iter().map(|p| place(*p, o, u, v)).collect();
            let face_n = polygon_normal(&face3);
            let mut area = 0.0;
            for t in 0..soup.triangle_count() {
                let tr = tri(&soup, t);
                // Back to plane coordinates by matching the corners.
                let tr2: [[f64; 2]; 3] = tr.map(|c| {
                    let k = face3
                        .iter()
                        .position(|p| norm(sub(*p, c)) < 1e-5)
                        .expect("triangle corner is a polygon corner");
                    poly[k]
                });
                let a = shoelace(&tr2);
                assert!(a.abs() > 1e-9, "case {case}: degenerate triangle {tr2:?}");
                let centroid = [
                    (tr2[0][0] + tr2[1][0] + tr2[2][0]) / 3.0,
                    (tr2[0][1] + tr2[1][1] + tr2[2][1]) / 3.0,
                ];
                assert!(
                    inside(centroid, &poly),
                    "case {case}: triangle {tr2:?} lies outside the L"
                );
                assert!(
                    dot(tri_normal(tr), face_n) > 0.0,
                    "case {case}: triangle {tr2:?} wound against the face"
                );
                area += a.abs();
            }
            assert!((area - 3.0).abs() < 1e-9, "case {case}: area {area}");
            assert_eq!(soup.parts.len(), 1);
            assert_eq!(soup.parts[0].name, "object \"L\"");
        }
    }
}

#[test]
fn concave_quad_and_collinear_corners_are_handled() {
    let tmp = tempfile::tempdir().unwrap();
    // An arrowhead (concave quad) whose reflex corner is (1, 0): only the
    // diagonal from that corner stays inside. Every rotation of the corner
    // order is tried, so the reflex corner takes every position.
    for (k, order) in [[0, 1, 2, 3], [1, 2, 3, 0], [2, 3, 0, 1], [3, 0, 1, 2]]
        .iter()
        .enumerate()
    {
        let corners = [[0.0, 0.0], [2.0, -1.0], [1.0, 0.0], [2.0, 1.0]];
        let mut text = String::new();
        for &i in order {
            let p = corners[i];
            text += &format!("v {} {} 0\n", p[0], p[1]);
        }
        text += "f 1 2 3 4\n";
        let (_, soup) = load_str(tmp.path(), &format!("dart{k}.obj"), &text);
        let soup = ok(soup);
        assert_eq!(soup.triangle_count(), 2);
        let poly: Vec<[f64; 2]> = order.iter().map(|&i| corners[i]).collect();
        let mut area = 0.0;
        for t in 0..2 {
            let tr = tri(&soup, t).map(|p| [p[0], p[1]]);
            let a = shoelace(&tr);
            assert!(
                a > 0.0,
                "rotation {k}: triangle {tr:?} not counter-clockwise"
            );
            area += a;
        }
        assert!(
            (area - shoelace(&poly)).abs() < 1e-9,
            "rotation {k}: area {area}"
        );
    }

    // Concave hexagon with an extra corner in the middle of its bottom edge:
    // seven corners, five triangles, the middle corner used (it bounds the
    // neighbouring face), area kept.
    let text = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 2 2 0\nv 1.5 0.5 0\nv 0.5 0.5 0\nv 0 2 0\n\
                f 1 2 3 4 5 6 7\n";
    let (_, soup) = load_str(tmp.path(), "collinear.obj", text);
    let soup = ok(soup);
    assert_eq!(soup.triangle_count(), 5);
    let mut used_middle = false;
    let mut area = 0.0;
    for t in 0..5 {
        let tr = tri(&soup, t);
        used_middle |= tr.contains(&[1.0, 0.0, 0.0]);
        let a = shoelace(&tr.map(|p| [p[0], p[1]]));
        assert!(a >= 0.0, "triangle {t} wound against the face");
        area += a;
    }
    assert!(used_middle, "corner on the edge dropped");
    let poly = [
        [0.0, 0.0],
        [1.0, 0.0],
        [2.0, 0.0],
        [2.0, 2.0],
        [1.5, 0.5],
        [0.5, 0.5],
        [0.0, 2.0],
    ];
    assert!((area - shoelace(&poly)).abs() < 1e-9, "area {area}");
    assert!(soup.stats.warnings.is_empty(), "{:?}", soup.stats.warnings);
}

#[test]
fn quad_becomes_two_triangles() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, soup) = load_str(
        tmp.path(),
        "quad.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
    );
    let soup = ok(soup);
    assert_eq!(soup.triangle_count(), 2);
    assert_eq!(soup.positions.len(), 4);
    for t in 0..2 {
        let n = tri_normal(tri(&soup, t));
        assert!((n[2] - 1.0).abs() < 1e-12 && n[0] == 0.0 && n[1] == 0.0);
    }
    assert_eq!(soup.parts.len(), 1);
    assert_eq!(soup.stats.primitives, 1);
}

#[test]
fn negative_indices_resolve_against_vertices_so_far() {
    let tmp = tempfile::tempdir().unwrap();
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nf -3 -2 -1\n\
                v 5 5 5\nv 6 5 5\nv 5 6 5\nf -3 -2 -1\nf 1 -3 -1\n";
    let (_, soup) = load_str(tmp.path(), "neg.obj", text);
    let soup = ok(soup);
    assert_eq!(soup.triangle_count(), 3);
    let corners: Vec<[f32; 3]> = soup
        .indices
        .iter()
        .map(|&i| soup.positions[i as usize])
        .collect();
    assert_eq!(
        corners,
        [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [5.0, 5.0, 5.0],
            [6.0, 5.0, 5.0],
            [5.0, 6.0, 5.0],
            [0.0, 0.0, 0.0],
            [5.0, 5.0, 5.0],
            [5.0, 6.0, 5.0],
        ]
    );
}

#[test]
fn objects_and_groups_become_parts() {
    let tmp = tempfile::tempdir().unwrap();
    let text = "\
v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
o Cube\nf 1 2 3\nf 1 3 4\n\
o Plane\nusemtl a\nf 1 2 3\nusemtl b\nf 1 2 4\n\
g wheels\nf 1 2 3 4\n\
g only_lines\nl 1 2 3\n\
o Tail\nf 2 3 4\n";
    let (_, soup) = load_str(tmp.path(), "parts.obj", text);
    let soup = ok(soup);
    check_structure("parts.obj", &soup);
    let parts: Vec<(&str, u32, u32)> = soup
        .parts
        .iter()
        .map(|p| (p.name.as_str(), p.first_triangle, p.triangle_count))
        .collect();
    assert_eq!(
        parts,
        [
            ("object \"Cube\"", 0, 2),
            ("object \"Plane\"", 2, 2),
            ("object \"wheels\"", 4, 2),
            ("object \"Tail\"", 6, 1),
        ]
    );
    assert_eq!(soup.stats.primitives, 4);
    assert_eq!(soup.stats.skipped_lines, 1);
}

#[test]
fn index_out_of_range_is_an_error_naming_the_file_and_line() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, text, what) in [
        ("oor.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "line 4"),
        (
            "zero.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 0 1 2\n",
            "line 5",
        ),
        (
            "rel.obj",
            "v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n",
            "line 3",
        ),
        (
            "bigquad.obj",
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 4000000000\n",
            "line 4",
        ),
    ] {
        let (path, r) = load_str(tmp.path(), name, text);
        let msg = r.expect_err(name).to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert!(msg.contains(what), "{name}: {msg}");
        assert!(msg.contains("index"), "{name}: {msg}");
    }
}

#[test]
fn bad_text_is_an_error_with_a_clear_message() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, text, what) in [
        (
            "num.obj",
            "v 0 0 0\nv 1 abc 0\nv 0 1 0\nf 1 2 3\n",
            "line 2",
        ),
        (
            "comma.obj",
            "v 0 0 0\nv 1,5 0 0\nv 0 1 0\nf 1 2 3\n",
            "\"1,5\"",
        ),
        ("face.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", "line 4"),
        ("few.obj", "v 0 0\n", "line 1"),
        ("w0.obj", "v 1 2 3 0\n", "w = 0"),
    ] {
        let (path, r) = load_str(tmp.path(), name, text);
        let msg = r.expect_err(name).to_string();
        assert!(msg.contains(&path.display().to_string()), "{msg}");
        assert!(msg.contains(what), "{name}: {msg}");
    }

    // UTF-16 without byte-order mark, and binary data.
    let utf16: Vec<u8> = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
        .encode_utf16()
        .flat_map(|u| u.to_le_bytes())
        .collect();
    let path = tmp.path().join("u16.obj");
    let msg = load_obj(&path, utf16).expect_err("utf16").to_string();
    assert!(msg.contains("UTF-16") && msg.contains("u16.obj"), "{msg}");
    let msg = load_obj(&path, vec![0x89, b'P', b'N', b'G', 0, 0, 0, 13, 1, 2, 3])
        .expect_err("binary")
        .to_string();
    assert!(msg.contains("NUL"), "{msg}");
    // Invalid UTF-8 in a vertex line is an error, in a comment only a warning.
    let msg = load_obj(&path, b"v 0 0 \xff\n".to_vec())
        .expect_err("latin1")
        .to_string();
    assert!(msg.contains("line 1") && msg.contains("UTF-8"), "{msg}");
    let soup = ok(load_obj(
        &path,
        b"# W\xfcrfel\no W\xfcrfel\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".to_vec(),
    ));
    assert_eq!(soup.triangle_count(), 1);
    assert_eq!(soup.parts[0].name, "object \"W?rfel\"");
    assert_eq!(soup.stats.warnings.len(), 1, "{:?}", soup.stats.warnings);
}

#[test]
fn polylines_and_points_are_skipped_and_counted() {
    let tmp = tempfile::tempdir().unwrap();
    let text = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
                l 1 2 3 4\n  l 1 3\np 1 2 3\nf 1\nf 1 2\nf 1 2 3\n";
    let (_, soup) = load_str(tmp.path(), "lp.obj", text);
    let soup = ok(soup);
    assert_eq!(
        soup.triangle_count(),
        1,
        "`l 1 2 3 4` must not become a quad"
    );
    // Lines: two `l` statements and `f 1 2`; points: `p 1 2 3` (3) and `f 1`.
    assert_eq!(soup.stats.skipped_lines, 3);
    assert_eq!(soup.stats.skipped_points, 4);
    // A continued `l` statement is still one line element.
    let (_, soup) = load_str(
        tmp.path(),
        "lc.obj",
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nl 1 2 \\\n3 4\n",
    );
    let soup = ok(soup);
    assert_eq!((soup.triangle_count(), soup.stats.skipped_lines), (0, 1));
}

#[test]
fn missing_material_library_is_not_fatal() {
    let tmp = tempfile::tempdir().unwrap();
    let text = "mtllib does_not_exist.mtl\nmtllib\nusemtl\tred\nusemtl\n\
                v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/1/1 2/1/1 3/1/1\n";
    let (_, soup) = load_str(tmp.path(), "mat.obj", text);
    let soup = ok(soup);
    assert_eq!(soup.triangle_count(), 1);
}

#[test]
fn unused_attribute_indices_do_not_matter() {
    // Texture/normal indices out of range (or 0) are not svpack's business.
    let tmp = tempfile::tempdir().unwrap();
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/0/7 2/99/-9 3//99999999999\n";
    let (_, soup) = load_str(tmp.path(), "attr.obj", text);
    assert_eq!(ok(soup).triangle_count(), 1);
}

#[test]
fn odd_but_valid_files_load() {
    let tmp = tempfile::tempdir().unwrap();
    // Empty file and comments only: no triangles, no error.
    for (name, text) in [("empty.obj", ""), ("comments.obj", "# nothing\n\n")] {
        let (_, soup) = load_str(tmp.path(), name, text);
        let soup = ok(soup);
        assert_eq!(soup.triangle_count(), 0);
        assert!(soup.parts.is_empty());
    }
    // UTF-8 BOM, CRLF, no final newline, w coordinate, continuation line.
    let text = "\u{feff}v 0 0 0\r\nv 2 0 0 2\r\nv 0 1 0\r\nv 1 1 0\r\nf 1 2 \\\r\n 4 3";
    let (_, soup) = load_str(tmp.path(), "bom.obj", text);
    let soup = ok(soup);
    assert_eq!(soup.triangle_count(), 2);
    assert!(soup.positions.contains(&[1.0, 0.0, 0.0]), "w divides");
    // Classic Mac line ends.
    let (_, soup) = load_str(tmp.path(), "cr.obj", "v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r");
    assert_eq!(ok(soup).triangle_count(), 1);
    // NaN/Inf positions are passed through, not rejected here.
    let (_, soup) = load_str(
        tmp.path(),
        "nan.obj",
        "v nan 0 0\nv inf 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\nf 1 2 3 4 4\n",
    );
    let soup = ok(soup);
    assert_eq!(soup.triangle_count(), 5);
    assert!(soup.positions.iter().any(|p| p[0].is_nan()));
    // Vertex colours on only some vertices.
    let (_, soup) = load_str(
        tmp.path(),
        "col.obj",
        "v 0 0 0 1 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
    );
    assert_eq!(ok(soup).triangle_count(), 1);
    // A self-intersecting polygon is fanned (n-2 triangles) with a warning.
    let (_, soup) = load_str(
        tmp.path(),
        "bowtie.obj",
        "v 0 0 0\nv 2 2 0\nv 2 0 0\nv 0 2 0\nv 1 3 0\nf 1 2 3 4 5\n",
    );
    let soup = ok(soup);
    assert_eq!(soup.triangle_count(), 3);
}

/// Big generated files and polygons (correctness; it also prints load times). Run with
/// `cargo test --release --test obj_load -- --ignored --nocapture`.
#[test]
#[ignore]
fn large_files_and_big_polygons_load() {
    use std::fmt::Write;
    let tmp = tempfile::tempdir().unwrap();
    let side = 1000usize;
    let mut verts = String::new();
    for y in 0..=side {
        for x in 0..=side {
            writeln!(verts, "v {x} {y} {}", (x * y) % 7).unwrap();
        }
    }
    let id = |x: usize, y: usize| y * (side + 1) + x + 1;
    let mut tris = verts.clone();
    let mut quads = verts;
    for y in 0..side {
        for x in 0..side {
            let (a, b, c, d) = (id(x, y), id(x + 1, y), id(x + 1, y + 1), id(x, y + 1));
            writeln!(tris, "f {a} {b} {c}\nf {a} {c} {d}").unwrap();
            writeln!(quads, "f {a} {b} {c} {d}").unwrap();
        }
    }
    for (name, text, expected) in [
        ("tris", tris, 2 * side * side),
        ("quads", quads, 2 * side * side),
    ] {
        let path = tmp.path().join(format!("{name}.obj"));
        std::fs::write(&path, &text).unwrap();
        let t = std::time::Instant::now();
        let soup = ok(load_path(&path));
        eprintln!(
            "{name}: {} MB, {} triangles in {:?}",
            text.len() / 1_000_000,
            soup.triangle_count(),
            t.elapsed()
        );
        assert_eq!(soup.triangle_count(), expected);
    }

    // Big polygons: a valid concave star and a self-intersecting one.
    for n in [1000usize, 5000] {
        let mut valid = String::new();
        let mut random = String::new();
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) as f64 / (1u64 << 31) as f64
        };
        for i in 0..n {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            let r = if i % 2 == 0 { 1.0 } else { 0.6 };
            writeln!(valid, "v {} {} 0", r * a.cos(), r * a.sin()).unwrap();
            writeln!(random, "v {} {} 0", next(), next()).unwrap();
        }
        let face: String = (1..=n).map(|i| format!(" {i}")).collect();
        for (name, mut text) in [("star", valid), ("random", random)] {
            writeln!(text, "f{face}").unwrap();
            let t = std::time::Instant::now();
            let (_, soup) = load_str(tmp.path(), "big.obj", &text);
            let soup = ok(soup);
            eprintln!("{name} {n}-gon: {:?}", t.elapsed());
            assert_eq!(soup.triangle_count(), n - 2);
            if name == "star" {
                assert!(soup.stats.warnings.is_empty(), "{:?}", soup.stats.warnings);
            }
        }
    }
}

/// Long models are handed to tobj in blocks of faces (the pre-scan repeats
/// the model's `o`/`g` statement), which must not show: the same parts,
/// triangles, counters and `input_vertices` as the whole-text path, which
/// never cuts (a file with CR-only line ends takes that path).
#[test]
fn models_cut_into_blocks_load_like_whole_models() {
    use std::fmt::Write as _;
    let dir = tempfile::tempdir().unwrap();
    // A 300 × 400 grid: 120,701 vertices, every interior one used by six
    // triangles that are often in different blocks.
    let (nx, ny) = (300usize, 400usize);
    let mut text = String::from("# grid\n");
    for j in 0..=ny {
        for i in 0..=nx {
            let _ = writeln!(text, "v {i} {j} {}", (i * j) % 7);
        }
    }
    let id = |i: usize, j: usize| j * (nx + 1) + i + 1;
    let mut faces = 0;
    for j in 0..ny {
        // 70,200 faces before any name (tobj's "unnamed_object"), then a
        // group whose name has a space and a trailing comment, then an object.
        if j == 117 {
            text.push_str("g part one # the middle\n");
        }
        if j == ny - 1 {
            text.push_str("o third\n");
        }
        for i in 0..nx {
            let _ = writeln!(text, "f {} {} {}", id(i, j), id(i + 1, j), id(i + 1, j + 1));
            let _ = writeln!(text, "f {} {} {}", id(i, j), id(i + 1, j + 1), id(i, j + 1));
            faces += 2;
        }
    }
    let (_, blocked) = load_str(dir.path(), "lf.obj", &text);
    let blocked = ok(blocked);
    let (_, whole) = load_str(dir.path(), "cr.obj", &text.replace('\n', "\r"));
    let whole = ok(whole);

    let parts = |s: &Soup| -> Vec<(String, u32, u32)> {
        s.parts
            .iter()
            .map(|p| (p.name.clone(), p.first_triangle, p.triangle_count))
            .collect()
    };
    let expected = vec![
        ("object \"unnamed_object\"".to_string(), 0, 70_200),
        (
            "object \"part one # the middle\"".to_string(),
            70_200,
            169_200,
        ),
        ("object \"third\"".to_string(), 239_400, 600),
    ];
    assert_eq!(parts(&blocked), expected);
    assert_eq!(parts(&whole), expected);
    assert_eq!(blocked.triangle_count(), faces);
    for t in 0..faces {
        assert_eq!(tri(&blocked, t), tri(&whole, t), "triangle {t}");
    }
    assert_eq!(blocked.stats.primitives, 3);
    assert_eq!(whole.stats.primitives, 3);
    assert_eq!(blocked.input_vertices, ((nx + 1) * (ny + 1)) as u64);
    assert_eq!(whole.input_vertices, blocked.input_vertices);
    // The blocks did happen: vertices shared by two blocks came out twice.
    assert!(blocked.positions.len() > whole.positions.len());
}
