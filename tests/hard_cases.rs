//! Numerically hard inputs: each is written as OBJ, built, and verified with
//! at least 64 lights (generated: around, inside, on vertices, on edge lines,
//! in triangle planes, directional parallel to faces; plus explicit ones
//! exactly and nearly in planes, inside, on a vertex, on an edge). Every
//! check must hold: no bijection errors, no closedness violations.
//! Plus a property test over random soups.

mod common;

use proptest::prelude::*;
use std::fmt::Write;
use std::path::Path;
use svpack::build::{BuildConfig, build_file};
use svpack::evaluate::Strategy as Eval;
use svpack::verify::{choose_lights, decode, verify};

struct Rng(u64);
impl Rng {
    fn f(&mut self) -> f32 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }
}

/// A triangle soup as OBJ text.
fn obj(v: &[[f32; 3]], f: &[[usize; 3]]) -> String {
    let mut s = String::new();
    for p in v {
        // {:?} prints the shortest text that reads back as the same f32.
        let _ = writeln!(s, "v {:?} {:?} {:?}", p[0], p[1], p[2]);
    }
    for t in f {
        let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    s
}

/// A grid of `n × n` quads (two triangles each) through `at(i, j)`.
fn grid(n: usize, at: impl Fn(f32, f32) -> [f32; 3]) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            v.push(at(i as f32 / n as f32, j as f32 / n as f32));
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i;
    let mut f = Vec::new();
    for j in 0..n {
        for i in 0..n {
            f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (v, f)
}

/// Closed box from a subdivided cube (every face a grid), outward.
fn closed_box(n: usize, scale: f32, offset: [f32; 3]) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let mut v = Vec::new();
    let mut f = Vec::new();
    let tf = |p: [f32; 3]| {
        [
            p[0] * scale + offset[0],
            p[1] * scale + offset[1],
            p[2] * scale + offset[2],
        ]
    };
    // Six faces as maps from (s, t) in [0,1]² with outward orientation.
    let faces: [fn(f32, f32) -> [f32; 3]; 6] = [
        |s, t| [s, t, 1.0],
        |s, t| [t, s, 0.0],
        |s, t| [1.0, s, t],
        |s, t| [0.0, t, s],
        |s, t| [t, 1.0, s],
        |s, t| [s, 0.0, t],
    ];
    for face in faces {
        let (gv, gf) = grid(n, |s, t| tf(face(s, t)));
        let base = v.len();
        v.extend(gv);
        f.extend(gf.iter().map(|t| [t[0] + base, t[1] + base, t[2] + base]));
    }
    (v, f)
}

struct Case {
    name: &'static str,
    v: Vec<[f32; 3]>,
    f: Vec<[usize; 3]>,
    lights: Vec<[f32; 4]>,
}

fn cases() -> Vec<Case> {
    let mut rng = Rng(0x9E3779B97F4A7C15);
    let mut out = Vec::new();

    // Many triangles in one axis-aligned plane; lights exactly and nearly in it.
    let (v, f) = grid(12, |s, t| [s * 2.0 - 1.0, t * 2.0 - 1.0, 0.0]);
    out.push(Case {
        name: "plane_axis",
        v,
        f,
        lights: vec![
            [3.0, 0.25, 0.0, 1.0],
            [0.1, 0.2, 0.0, 1.0],
            [0.3, 0.1, 1e-7, 1.0],
            [5.0, -2.0, -1e-7, 1.0],
            [1.0, 0.5, 0.0, 0.0],
            [1.0, 0.5, 1e-7, 0.0],
        ],
    });

    // Tilted plane (rounded per vertex): coplanarity only up to rounding.
    let (v, f) = grid(12, |s, t| [s, t, 0.1 * s + 0.37 * t]);
    out.push(Case {
        name: "plane_tilted",
        v,
        f,
        lights: vec![
            [2.0, 2.0, 0.2 + 0.74, 1.0],
            [-1.0, 0.5, -0.1 + 0.185, 1.0],
            [1.0, 0.0, 0.1, 0.0],
            [0.0, 1.0, 0.37, 0.0],
            [0.5, 0.5, 0.235 + 1e-7, 1.0],
        ],
    });

    // Slivers and needles (aspect ~1e-7), collinear and zero-area triangles.
    let mut v = Vec::new();
    let mut f = Vec::new();
    for i in 0..40 {
        let x = i as f32 * 0.1;
        let b = v.len();
        v.push([x, 0.0, 0.0]);
        v.push([x + 1.0, 0.0, 0.0]);
        v.push([x + 0.5, 1e-7, 1e-7 * rng.f()]); // sliver
        v.push([x + 0.5, 0.0, 0.0]); // collinear with the first two
        v.push([x + 0.2, 1.0, 0.3]);
        v.push([x + 0.2 + 1e-7, 1.0, 0.3]); // needle with the previous
        f.push([b, b + 1, b + 2]);
        f.push([b, b + 1, b + 3]);
        f.push([b + 4, b + 5, b]);
    }
    out.push(Case {
        name: "slivers_collinear",
        v,
        f,
        lights: vec![
            [0.5, 0.0, 0.0, 1.0],
            [10.0, 1e-7, 0.0, 1.0],
            [1.0, 0.0, 0.0, 0.0],
        ],
    });

    // Closed boxes far from the origin and tiny; lights inside, on a vertex, on an edge.
    let (v, f) = closed_box(3, 1.0, [1e6, 1e6, -1e6]);
    out.push(Case {
        name: "offset_1e6",
        v,
        f,
        lights: vec![
            [1e6 + 0.5, 1e6 + 0.5, -1e6 + 0.5, 1.0],
            [1e6, 1e6, -1e6, 1.0],
            [1e6 + 0.5, 1e6, -1e6, 1.0],
            [1e6 + 2.0, 1e6 + 3.0, -1e6 - 1.0, 1.0],
        ],
    });
    let (v, f) = closed_box(3, 1e-5, [0.0, 0.0, 0.0]);
    out.push(Case {
        name: "scaled_1e-5",
        v,
        f,
        lights: vec![
            [0.5e-5, 0.5e-5, 0.5e-5, 1.0],
            [0.0, 0.0, 0.0, 1.0],
            [0.5e-5, 0.0, 0.0, 1.0],
            [1.0, 2.0, 3.0, 1.0],
            [0.0, 0.0, 1.0, 0.0],
        ],
    });

    // Non-manifold fans of 3..150 triangles with random orientation.
    let mut v = Vec::new();
    let mut f = Vec::new();
    for (e, &n) in [3usize, 7, 16, 40, 150].iter().enumerate() {
        let b = v.len();
        let z = e as f32 * 2.0;
        v.push([0.0, 0.0, z]);
        v.push([1.0, 0.0, z]);
        for i in 0..n {
            let a = std::f32::consts::TAU * i as f32 / n as f32;
            v.push([0.5 + 0.1 * rng.f(), a.cos(), z + a.sin()]);
            let t = if rng.f() > 0.0 {
                [b, b + 1, b + 2 + i]
            } else {
                [b + 1, b, b + 2 + i]
            };
            f.push(t);
        }
    }
    out.push(Case {
        name: "fans_3_to_150",
        v,
        f,
        lights: vec![
            [0.5, 0.0, 0.0, 1.0],
            [0.5, 0.0, 8.0, 1.0],
            [1.0, 0.0, 0.0, 0.0],
            [0.5, 3.0, 1.0, 1.0],
        ],
    });

    // Inconsistent winding, duplicates, back-to-back and coplanar overlapping triangles.
    let (mut v, mut f) = closed_box(2, 1.0, [0.0; 3]);
    for t in f.iter_mut().step_by(3) {
        t.swap(0, 1);
    }
    let dups: Vec<[usize; 3]> = f.iter().step_by(5).copied().collect();
    for t in dups {
        f.push(t);
        f.push([t[1], t[0], t[2]]);
    }
    let b = v.len();
    v.extend([
        [0.1, 0.1, 1.0],
        [0.9, 0.2, 1.0],
        [0.3, 0.8, 1.0],
        [0.2, 0.15, 1.0],
        [0.7, 0.9, 1.0],
    ]);
    f.push([b, b + 1, b + 2]);
    f.push([b + 3, b + 4, b + 1]);
    out.push(Case {
        name: "winding_dups_overlaps",
        v,
        f,
        lights: vec![
            [0.5, 0.5, 0.5, 1.0],
            [0.5, 0.5, 1.0, 1.0],
            [0.5, 0.5, 3.0, 1.0],
            [0.0, 0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0, 0.0],
        ],
    });

    // Open mesh: a box without its top, light inside the opening.
    let (v, f) = closed_box(3, 1.0, [0.0; 3]);
    let f: Vec<[usize; 3]> = f
        .into_iter()
        .filter(|t| !t.iter().all(|&i| v[i][2] == 1.0))
        .collect();
    out.push(Case {
        name: "open_box",
        v,
        f,
        lights: vec![
            [0.5, 0.5, 1.0, 1.0],
            [0.5, 0.5, 0.5, 1.0],
            [0.0, 0.0, 1.0, 1.0],
            [0.0, 0.0, -1.0, 0.0],
        ],
    });
    out
}

fn build_and_verify(
    dir: &Path,
    c: &Case,
    extra_generated: usize,
    eval: Eval,
) -> svpack::verify::VerifyReport {
    let input = dir.join(format!("{}.obj", c.name));
    std::fs::write(&input, obj(&c.v, &c.f)).unwrap();
    let output = dir.join(format!("{}.svpk", c.name));
    build_file(&input, &output, &BuildConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    let file = svpack::format::read_file(&output).unwrap();
    let mut lights = c.lights.clone();
    lights.extend(choose_lights(&decode(&file, 0), extra_generated, 7));
    verify(&file, &lights, eval, 128)
}

#[test]
fn hard_cases_verify_with_64_lights() {
    let tmp = tempfile::tempdir().unwrap();
    for c in cases() {
        let rep = build_and_verify(tmp.path(), &c, 64, Eval::Reference);
        assert!(rep.lights.len() >= 64);
        assert!(
            rep.lights.iter().any(|l| l.light[3] == 0.0)
                && rep.lights.iter().any(|l| l.light[3] == 1.0)
        );
        assert!(
            rep.ok,
            "{}: {} bijection, {} record errors, {} closedness violations ({:?})",
            c.name,
            rep.bijection_errors,
            rep.record_errors,
            rep.closedness_violations,
            rep.first_problem
        );
        eprintln!(
            "{}: {} triangles, {} lights, {} samples ({} on faces), silhouette instances {}..{}",
            c.name,
            rep.triangles,
            rep.lights.len(),
            rep.samples,
            rep.samples_on_faces,
            rep.lights
                .iter()
                .map(|l| l.silhouette_instances)
                .min()
                .unwrap(),
            rep.lights
                .iter()
                .map(|l| l.silhouette_instances)
                .max()
                .unwrap()
        );
    }
}

/// The same cases replayed with Kim 2008's evaluator: some must crack,
/// otherwise these cases would not be hard.
#[test]
fn hard_cases_crack_the_naive_evaluator() {
    let tmp = tempfile::tempdir().unwrap();
    let mut cracked = Vec::new();
    for c in cases() {
        if !build_and_verify(tmp.path(), &c, 64, Eval::Kim).ok {
            cracked.push(c.name);
        }
    }
    eprintln!("Kim 2008 cracks on: {cracked:?}");
    assert!(
        cracked.len() >= 2,
        "naive evaluator cracked only on {cracked:?}"
    );
}

fn soup_strategy() -> impl Strategy<Value = (Vec<[f32; 3]>, Vec<[usize; 3]>)> {
    // Positions from a small lattice (many coincidences, coplanarities and
    // duplicates) mixed with arbitrary floats.
    let coord = prop_oneof![
        (-2i32..=2).prop_map(|i| i as f32 * 0.5),
        -1.0e3f32..1.0e3f32,
        (-1.0f32..1.0).prop_map(|x| x * 1e-6),
    ];
    let point = [coord.clone(), coord.clone(), coord].prop_map(|p| p);
    proptest::collection::vec(point, 3..24).prop_flat_map(|v| {
        let n = v.len();
        let tri = [0..n, 0..n, 0..n].prop_map(|t| t);
        (Just(v), proptest::collection::vec(tri, 1..40))
    })
}

fn light_strategy() -> impl Strategy<Value = [f32; 4]> {
    let c = prop_oneof![(-2i32..=2).prop_map(|i| i as f32 * 0.5), -10.0f32..10.0];
    (c.clone(), c.clone(), c, prop::bool::ANY).prop_filter_map(
        "zero direction",
        |(x, y, z, point)| {
            let l = [x, y, z, if point { 1.0 } else { 0.0 }];
            (point || [x, y, z] != [0.0; 3]).then_some(l)
        },
    )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, .. ProptestConfig::default() })]

    #[test]
    fn random_soups_verify((v, f) in soup_strategy(), lights in proptest::collection::vec(light_strategy(), 4..8)) {
        let tmp = tempfile::tempdir().unwrap();
        let input = tmp.path().join("soup.obj");
        std::fs::write(&input, obj(&v, &f)).unwrap();
        let output = tmp.path().join("soup.svpk");
        match build_file(&input, &output, &BuildConfig::default()) {
            Ok(_) => {
                let file = svpack::format::read_file(&output).unwrap();
                let rep = verify(&file, &lights, Eval::Reference, 128);
                // Structure and closedness hold exactly, always.
                prop_assert!(rep.bijection_errors == 0 && rep.record_errors == 0, "{:?}", rep);
                prop_assert_eq!(rep.closedness_violations, 0, "{:?}", rep);
                // A wrong shadow is only allowed where f32 orientation itself
                // is wrong (a light within rounding distance of a plane), and
                // then only under that light.
                for l in &rep.lights {
                    prop_assert!(
                        l.sample_mismatches == 0 || l.orientation_errors > 0,
                        "mismatch without an orientation error: {:?}", rep
                    );
                }
            }
            // Only an all-degenerate soup may fail to build.
            Err(e) => prop_assert!(e.to_string().contains("no triangles"), "{e}"),
        }
    }
}

#[test]
fn shared_models_verify() {
    let Some(shared) = common::shared_meshes() else {
        return;
    };
    let files = common::shared_models(&shared);
    let tmp = tempfile::tempdir().unwrap();
    let mut checked = 0;
    for f in files {
        let out = tmp.path().join("m.svpk");
        if build_file(&f, &out, &BuildConfig::default()).is_err() {
            continue; // points/lines-only samples (covered by tests/shared_meshes.rs)
        }
        let file = svpack::format::read_file(&out).unwrap();
        let lights = choose_lights(&decode(&file, 0), 16, 3);
        let rep = verify(&file, &lights, Eval::Reference, 64);
        assert!(
            rep.ok,
            "{}: {:?} {:?}",
            f.display(),
            rep.first_problem,
            rep.first_mismatch
        );
        checked += 1;
    }
    assert!(checked >= 20);
}
