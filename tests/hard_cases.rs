//! Numerically hard inputs: each is written as OBJ, built, and verified with
//! at least 64 lights (generated: around, inside, on vertices, on edge lines,
//! in triangle planes, directional parallel to faces; plus explicit ones
//! exactly and nearly in planes, inside, on a vertex, on an edge). Every
//! check must hold: no bijection errors, no closedness violations.
//! Plus a property test over random soups.

mod common;

use proptest::prelude::*;
use std::path::Path;
use svpack::build::{BuildConfig, build_file};
use svpack::evaluate::Strategy as Eval;
use svpack::hardcases::{Case, cases, obj};
use svpack::verify::{choose_lights, decode, verify};

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
