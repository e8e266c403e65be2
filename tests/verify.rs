//! `svpack verify`: holds on good files, fails (exit 2, failure named) on
//! broken files and broken evaluators.

mod common;

use common::{svpack, write_fixtures};
use predicates::prelude::*;
use svpack::evaluate::Strategy;
use svpack::verify::{check_closedness, check_structure, decode, evaluate};

/// Rewrites payload bytes of a built file and fixes both checksums, so only
/// the semantic checks can notice.
fn patch_payload(path: &std::path::Path, f: impl Fn(&mut [u8], &svpack::format::Header)) {
    let mut bytes = std::fs::read(path).unwrap();
    let h = svpack::format::read_file(path).unwrap().header;
    f(&mut bytes[h.payload_offset as usize..], &h);
    fix_checksums(&mut bytes, &h);
    std::fs::write(path, bytes).unwrap();
}

/// Rewrites both checksums of file bytes whose payload was changed (`h`:
/// the file's header).
fn fix_checksums(bytes: &mut [u8], h: &svpack::format::Header) {
    let mut h = h.clone();
    h.payload_crc32 = crc32fast::hash(&bytes[h.payload_offset as usize..]);
    let hb = svpack::format::encode_header(&h).unwrap();
    bytes[16..20].copy_from_slice(&crc32fast::hash(&hb).to_le_bytes());
    bytes[24..24 + hb.len()].copy_from_slice(&hb);
}

/// `svpack verify FILE --json ARGS`: exit code and report.
fn verify_json(path: &std::path::Path, args: &[&str]) -> (Option<i32>, serde_json::Value) {
    let r = svpack()
        .arg("verify")
        .arg(path)
        .arg("--json")
        .args(args)
        .output()
        .unwrap();
    let j = serde_json::from_slice(&r.stdout)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(&r.stderr)));
    (r.status.code(), j)
}

/// The hard cases written as OBJ files into `dir`, then the shared OBJ
/// models named in `models` when ../shared/meshes is present.
fn hard_cases_and(dir: &std::path::Path, models: &[&str]) -> Vec<std::path::PathBuf> {
    let mut inputs = Vec::new();
    for c in svpack::hardcases::cases() {
        let p = dir.join(format!("{}.obj", c.name));
        std::fs::write(&p, svpack::hardcases::obj(&c.v, &c.f)).unwrap();
        inputs.push(p);
    }
    if let Some(shared) = common::shared_meshes() {
        inputs.extend(models.iter().map(|m| shared.join("obj").join(m)));
    }
    inputs
}

/// Builds fixture `name` into a temp dir: the dir and the file.
fn built_file(name: &str) -> (tempfile::TempDir, std::path::PathBuf) {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let src = &fx.iter().find(|f| f.0 == name).unwrap().1;
    let out = tmp.path().join("fixture.svpk");
    svpack()
        .arg("build")
        .arg(src)
        .arg("-o")
        .arg(&out)
        .assert()
        .code(0);
    (tmp, out)
}

/// Builds fixture `name` into a temp dir and decodes its first mesh.
fn built_fixture(name: &str) -> (tempfile::TempDir, svpack::verify::Decoded) {
    let (tmp, out) = built_file(name);
    let d = decode(&svpack::format::read_file(&out).unwrap(), 0);
    (tmp, d)
}

#[test]
fn fixtures_verify_with_many_lights() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, path) in write_fixtures(tmp.path()) {
        let out = tmp.path().join(format!("{name}.svpk"));
        svpack()
            .arg("build")
            .arg(&path)
            .arg("-o")
            .arg(&out)
            .arg("--verify")
            .arg("--lights=64")
            .assert()
            .code(0);
        let r = svpack()
            .arg("verify")
            .arg(&out)
            .arg("--json")
            .arg("--lights=64")
            .arg("--light=-1e6,2,-3.5,1")
            .output()
            .unwrap();
        assert_eq!(
            r.status.code(),
            Some(0),
            "{name}: {}",
            String::from_utf8_lossy(&r.stdout)
        );
        let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
        assert_eq!(j["ok"], true);
        assert_eq!(j["lights"].as_array().unwrap().len(), 65);
        assert_eq!(j["bijection_errors"], 0);
        assert_eq!(j["closedness_violations"], 0);
        assert_eq!(j["sample_mismatches"], 0);
        assert!(
            j["samples"].as_u64().unwrap() > 65 * 200,
            "{name}: too few samples compared"
        );
        // The explicit light is parsed with its sign and exponent.
        assert_eq!(
            j["lights"][0]["light"],
            serde_json::json!([-1e6, 2.0, -3.5, 1.0])
        );
    }
}

#[test]
fn bad_light_values_are_usage_errors() {
    for bad in ["1,2,3", "1,2,3,0.5", "nan,0,0,1", "0,0,0,0", "a,b,c,d"] {
        svpack()
            .args(["verify", "whatever.svpk", &format!("--light={bad}")])
            .assert()
            .code(1)
            .stderr(predicate::str::contains("light"));
    }
}

#[test]
fn flipped_opposite_sign_and_unswapped_cap_break_closedness() {
    let (_tmp, d) = built_fixture("two_tets.obj");
    assert!(check_structure(&d).ok());
    let light = [0.3, 2.0, 0.7, 1.0];
    let good = evaluate(&d, light, Strategy::Reference);
    assert_eq!(check_closedness(&d, light, &good).violations, 0);

    // One opposite vertex's contribution flipped: the edge's m changes by 2.
    let mut bad = good.clone();
    let (b, r) = (0..d.buckets.len())
        .flat_map(|b| (0..good.sides[b].len()).map(move |r| (b, r)))
        .find(|&(b, r)| good.sides[b][r] != 0)
        .unwrap();
    bad.sides[b][r] -= 2 * good.sides[b][r].signum();
    assert!(check_closedness(&d, light, &bad).violations > 0);

    // Every sign negated: still closed (a consistently inverted volume), but
    // the shadow is wrong; only the shadow-truth check can see that.
    let mut inverted = good.clone();
    inverted.caps.iter_mut().for_each(|c| *c = -*c);
    inverted.sides.iter_mut().flatten().for_each(|m| *m = -*m);
    assert_eq!(check_closedness(&d, light, &inverted).violations, 0);
    let index = svpack::shadow::ShadowIndex::new(&d);
    let samples = svpack::shadow::choose_samples(&d, 256, 1);
    let truth = svpack::shadow::check_shadow(&d, &index, light, &good, &samples);
    assert_eq!(truth.mismatches, 0);
    assert!(truth.samples > 200);
    let wrong = svpack::shadow::check_shadow(&d, &index, light, &inverted, &samples);
    assert!(wrong.mismatches > 0, "inverted volume not caught");
    assert!(wrong.first_mismatch.unwrap().contains("winding -"));

    // One cap drawn the wrong way round (orientation flipped for the cap only).
    let mut bad = good.clone();
    let t = good.caps.iter().position(|&c| c != 0).unwrap();
    bad.caps[t] = -bad.caps[t];
    assert!(check_closedness(&d, light, &bad).violations > 0);
}

#[test]
fn corrupted_records_fail_structure_with_exit_2() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let src = &fx.iter().find(|f| f.0 == "cube.obj").unwrap().1;
    type Patch = Box<dyn Fn(&mut [u8], &svpack::format::Header)>;
    let cases: Vec<(&str, Patch, &str)> = vec![
        // O_0.w of the first sides record := -1 (a "negative" opposite vertex).
        (
            "opposite_w",
            Box::new(|p, h| {
                let at = (h.meshes[0].buckets[0].offset - h.payload_offset) as usize + 32 + 12;
                p[at..at + 4].copy_from_slice(&(-1.0f32).to_le_bytes());
            }),
            "record_errors",
        ),
        // An opposite vertex moved: the pair no longer matches any triangle.
        (
            "moved_opposite",
            Box::new(|p, h| {
                let at = (h.meshes[0].buckets[0].offset - h.payload_offset) as usize + 32;
                p[at..at + 4].copy_from_slice(&0.5f32.to_le_bytes());
            }),
            "bijection_errors",
        ),
        // An edge's end moved off every cap corner: the record names a
        // position the caps do not have (the closedness check once indexed
        // past its table there and panicked).
        (
            "moved_edge_end",
            Box::new(|p, h| {
                let at = (h.meshes[0].buckets[0].offset - h.payload_offset) as usize;
                p[at..at + 4].copy_from_slice(&0.5f32.to_le_bytes());
            }),
            "bijection_errors",
        ),
        // A cap corner moved.
        (
            "moved_cap",
            Box::new(|p, h| {
                let at = (h.meshes[0].caps.offset - h.payload_offset) as usize;
                p[at..at + 4].copy_from_slice(&0.25f32.to_le_bytes());
            }),
            "bijection_errors",
        ),
    ];
    for (name, patch, msg) in cases {
        let out = tmp.path().join(format!("{name}.svpk"));
        svpack()
            .arg("build")
            .arg(src)
            .arg("-o")
            .arg(&out)
            .assert()
            .code(0);
        patch_payload(&out, patch);
        svpack().arg("inspect").arg(&out).assert().code(0); // container is intact
        let r = svpack()
            .arg("verify")
            .arg(&out)
            .arg("--json")
            .output()
            .unwrap();
        assert_eq!(r.status.code(), Some(2), "{name}");
        let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
        assert_eq!(j["ok"], false, "{name}");
        assert!(
            j[msg].as_u64().unwrap() > 0,
            "{name}: {msg} should be counted: {j}"
        );
        assert!(j["first_problem"].is_string(), "{name}: failure not named");
    }
}

#[test]
fn kim_evaluator_cracks_on_real_models_reference_does_not() {
    let Some(shared) = common::shared_meshes() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("bunny.svpk");
    svpack()
        .arg("build")
        .arg(shared.join("obj/stanford-bunny.obj"))
        .arg("-o")
        .arg(&out)
        .assert()
        .code(0);
    svpack()
        .arg("verify")
        .arg(&out)
        .arg("--lights=32")
        .assert()
        .code(0);
    let r = svpack()
        .arg("verify")
        .arg(&out)
        .arg("--lights=32")
        .arg("--evaluator=kim")
        .arg("--json")
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(2));
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    assert!(j["closedness_violations"].as_u64().unwrap() > 0, "{j}");
    assert!(j["sample_mismatches"].as_u64().unwrap() > 0, "{j}");
    assert_eq!(j["bijection_errors"], 0);
    // Lights run in parallel: one thread reports the same, light by light,
    // first mismatch included (only the times differ).
    let r1 = svpack()
        .arg("verify")
        .arg(&out)
        .arg("--lights=32")
        .arg("--evaluator=kim")
        .arg("--json")
        .arg("--threads=1")
        .output()
        .unwrap();
    let mut j1: serde_json::Value = serde_json::from_slice(&r1.stdout).unwrap();
    let mut j = j;
    for j in [&mut j, &mut j1] {
        j.as_object_mut().unwrap().remove("time_ms");
        for l in j["lights"].as_array_mut().unwrap() {
            l.as_object_mut().unwrap().remove("time_ms");
        }
    }
    assert!(j["first_mismatch"].is_string());
    assert_eq!(j, j1);
}

/// Check 2 as it was first written, the oracle: every directed edge of what
/// the shaders draw, keyed by its undirected edge, all sorted at once, and
/// the keys whose weights do not cancel counted.
fn closedness_by_sorting(
    d: &svpack::verify::Decoded,
    light: [f32; 4],
    ev: &svpack::verify::Evaluation,
) -> svpack::verify::Closedness {
    use svpack::multiplicity::{cap_corner, side_corner, to_infinity};
    let n = d.positions.len() as u32;
    let mut inf: Vec<([u32; 3], u32)> = d
        .positions
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            let q = to_infinity(p, light);
            let key = [q[0], q[1], q[2]].map(|v| if v == 0.0 { 0 } else { v.to_bits() });
            (key, i as u32)
        })
        .collect();
    inf.sort_unstable();
    let mut inf_id = vec![0u32; d.positions.len()];
    let mut next = n;
    for (i, e) in inf.iter().enumerate() {
        if i > 0 && inf[i - 1].0 != e.0 {
            next += 1;
        }
        inf_id[e.1 as usize] = next;
    }
    let mut rep = svpack::verify::Closedness::default();
    let mut edges: Vec<(u64, i32)> = Vec::new();
    let mut emit = |tri: [u32; 3], weight: i32| {
        for e in 0..3 {
            let (x, y) = (tri[e], tri[(e + 1) % 3]);
            if x != y {
                let key = ((x.min(y) as u64) << 32) | x.max(y) as u64;
                edges.push((key, if x < y { weight } else { -weight }));
            }
        }
    };
    for (t, &c) in d.caps.iter().zip(&ev.caps) {
        if c != 0 {
            rep.caps += 1;
            let corner = |v: u32| {
                let (i, at_inf) = cap_corner(v, c as i32);
                let p = t[i as usize];
                if at_inf { inf_id[p as usize] } else { p }
            };
            emit([corner(0), corner(1), corner(2)], 1);
            emit([corner(3), corner(4), corner(5)], 1);
        }
    }
    for (b, ms) in d.buckets.iter().zip(&ev.sides) {
        for (ids, &m) in b.ids.chunks_exact(2 + b.k).zip(ms) {
            if m != 0 {
                rep.silhouette_instances += 1;
                rep.side_quads += m.unsigned_abs() as u64;
                let (a, b) = (ids[0] as usize, ids[1] as usize);
                let quad = [ids[0], ids[1], inf_id[a], inf_id[b]];
                let corner = |v: u32| quad[side_corner(v, m as i32) as usize];
                let w = m.unsigned_abs() as i32;
                emit([corner(0), corner(1), corner(2)], w);
                emit([corner(3), corner(4), corner(5)], w);
            }
        }
    }
    edges.sort_unstable_by_key(|e| e.0);
    for group in edges.chunk_by(|a, b| a.0 == b.0) {
        rep.violations += (group.iter().map(|e| e.1 as i64).sum::<i64>() != 0) as u64;
    }
    rep
}

/// The linear closedness check (counting sort by the smaller vertex) and the
/// indexed one (pairs numbered once per file) count exactly what sorting
/// every edge counts: on the hard cases and real
/// models (open, non-manifold), under the reference (no violations), Kim's
/// evaluator (cracks) and evaluations with signs flipped at random (many
/// unbalanced edges, some at infinity), with one scratch reused throughout;
/// lights include far ones, under which many positions share a point at
/// infinity.
#[test]
fn closedness_counts_what_sorting_every_edge_counts() {
    use svpack::verify::{
        ClosednessIndex, ClosednessScratch, check_closedness_indexed, check_closedness_with,
        choose_lights,
    };
    let tmp = tempfile::tempdir().unwrap();
    let inputs = hard_cases_and(tmp.path(), &["chair_model.obj", "stanford-bunny.obj"]);
    let mut scratch = ClosednessScratch::default();
    let mut flips = 0x9E37_79B9_7F4A_7C15u64;
    let mut unbalanced = 0;
    let mut far_merged = 0;
    for input in inputs {
        let out = tmp.path().join("x.svpk");
        svpack::build::build_file(&input, &out, &Default::default()).unwrap();
        let d = decode(&svpack::format::read_file(&out).unwrap(), 0);
        let index = ClosednessIndex::new(&d);
        // Also point lights so far away along x, or along y and z, that many
        // positions extrude to one point at infinity, not all of them next
        // to each other in position order.
        let (lo, hi) = svpack::build::bounds(&d.positions);
        let size = (0..3).map(|k| hi[k] - lo[k]).fold(1e-3f32, f32::max);
        let far = [
            [lo[0] + 3e7 * size, 0.5 * (lo[1] + hi[1]), hi[2], 1.0],
            [hi[0], lo[1] - 2e7 * size, hi[2] + 5e7 * size, 1.0],
        ];
        for light in far {
            let mut extruded: Vec<[u32; 3]> = d
                .positions
                .iter()
                .map(|&p| {
                    let q = svpack::multiplicity::to_infinity(p, light);
                    [0, 1, 2].map(|k| if q[k] == 0.0 { 0 } else { q[k].to_bits() })
                })
                .collect();
            extruded.sort_unstable();
            extruded.dedup();
            far_merged += d.positions.len() - extruded.len();
        }
        for light in choose_lights(&d, 12, 3).into_iter().chain(far) {
            for s in [Strategy::Reference, Strategy::Kim] {
                let mut ev = evaluate(&d, light, s);
                for flip in [false, true] {
                    if flip {
                        for c in ev.caps.iter_mut().chain(ev.sides.iter_mut().flatten()) {
                            flips ^= flips << 13;
                            flips ^= flips >> 7;
                            flips ^= flips << 17;
                            if flips.is_multiple_of(16) {
                                *c = -*c;
                            }
                        }
                    }
                    let want = closedness_by_sorting(&d, light, &ev);
                    let got = check_closedness_with(&d, light, &ev, &mut scratch);
                    assert_eq!(got, want, "{} {s:?} {light:?} flip {flip}", input.display());
                    let got = check_closedness_indexed(&d, &index, light, &ev, &mut scratch);
                    assert_eq!(
                        got,
                        want,
                        "indexed: {} {s:?} {light:?} flip {flip}",
                        input.display()
                    );
                    unbalanced += want.violations;
                }
            }
        }
    }
    assert!(
        unbalanced > 1000,
        "the flips must unbalance edges: {unbalanced}"
    );
    assert!(
        far_merged > 1000,
        "far lights must merge points at infinity: {far_merged}"
    );
}

/// Points at infinity are compared as values: under a light far along y,
/// an octahedron's corners (-0, -1, 0) and (0, 1, 0) extrude to
/// (-0, -1e9, 0) and (+0, -1e9, 0), one point, so the edges at infinity
/// between them collapse and the others join. The indexed check merges
/// them as the general one does, under every sign flip (signs flipped
/// one by one and in pairs unbalance the pairs the merge touches).
#[test]
fn closedness_merges_signed_zeros_at_infinity() {
    use svpack::verify::{ClosednessIndex, ClosednessScratch, check_closedness_indexed};
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("octahedron.obj");
    let v = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [-0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let f = [
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    std::fs::write(&src, svpack::hardcases::obj(&v, &f)).unwrap();
    let out = tmp.path().join("octahedron.svpk");
    svpack::build::build_file(&src, &out, &Default::default()).unwrap();
    // The build writes +0.0: the corner (0, -1, 0) becomes (-0, -1, 0) in
    // every record that names it, caps and sides. The positions still
    // increase strictly as values (that corner has the smallest y of those
    // with x = 0), so the indexed check runs.
    patch_payload(&out, |p, h| {
        let m = &h.meshes[0];
        let sections = std::iter::once((m.caps.offset, m.caps.length))
            .chain(m.buckets.iter().map(|b| (b.offset, b.length)));
        for (offset, length) in sections {
            let at = (offset - h.payload_offset) as usize;
            for row in p[at..at + length as usize].chunks_exact_mut(16) {
                if row[..12] == [0.0f32, -1.0, 0.0].map(f32::to_le_bytes).concat()[..] {
                    row[..4].copy_from_slice(&(-0.0f32).to_le_bytes());
                }
            }
        }
    });
    let d = decode(&svpack::format::read_file(&out).unwrap(), 0);
    assert!(d.positions.iter().any(|p| p[0].to_bits() == 0x8000_0000));
    assert!(d.ordered.is_some());
    let light = [0.0, 1e9, 0.0, 1.0];
    let inf = |p: [f32; 3]| svpack::multiplicity::to_infinity(p, light);
    let (minus, plus) = (inf([-0.0, -1.0, 0.0]), inf([0.0, 1.0, 0.0]));
    assert!(minus == plus && minus[0].to_bits() != plus[0].to_bits());
    let index = ClosednessIndex::new(&d);
    let mut scratch = ClosednessScratch::default();
    let ev = evaluate(&d, light, Strategy::Reference);
    let signs = ev.caps.len() + ev.sides.iter().map(Vec::len).sum::<usize>();
    // Sign `at` (the caps', then the records') negated, or 0 made 1.
    let flip = |ev: &mut svpack::verify::Evaluation, at: usize| {
        let c = match at.checked_sub(ev.caps.len()) {
            None => &mut ev.caps[at],
            Some(r) => ev.sides.iter_mut().flatten().nth(r).unwrap(),
        };
        *c = if *c == 0 { 1 } else { -*c };
    };
    let mut unbalanced = 0;
    for (i, j) in (0..signs).flat_map(|i| (i..signs).map(move |j| (i, j))) {
        let mut flipped = ev.clone();
        flip(&mut flipped, i);
        if j != i {
            flip(&mut flipped, j);
        }
        let want = closedness_by_sorting(&d, light, &flipped);
        let got = check_closedness_indexed(&d, &index, light, &flipped, &mut scratch);
        assert_eq!(got, want, "signs {i} and {j} flipped");
        unbalanced += want.violations;
    }
    assert!(unbalanced > 0);
}

/// `orientation_errors` counts the caps whose evaluated sign differs from
/// the exact orientation of their stored corners towards the light, as
/// the exact predicate on every cap counts them: on the hard cases and a
/// real model, under point and directional lights, with the reference
/// evaluation, Kim's, and signs flipped or zeroed at random.
#[test]
fn orientation_errors_count_what_the_exact_predicate_counts() {
    use svpack::verify::{choose_lights, orientation_errors};
    let tmp = tempfile::tempdir().unwrap();
    let inputs = hard_cases_and(tmp.path(), &["stanford-bunny.obj"]);
    let mut bits = 0x2545_F491_4F6C_DD1Du64;
    let (mut errors, mut checked) = (0, 0);
    for input in inputs {
        let out = tmp.path().join("x.svpk");
        svpack::build::build_file(&input, &out, &Default::default()).unwrap();
        let d = decode(&svpack::format::read_file(&out).unwrap(), 0);
        if !d.positions.iter().flatten().all(|v| v.is_finite()) {
            continue;
        }
        for light in choose_lights(&d, 8, 5) {
            for s in [Strategy::Reference, Strategy::Kim] {
                let mut ev = evaluate(&d, light, s);
                for c in ev.caps.iter_mut() {
                    bits ^= bits << 13;
                    bits ^= bits >> 7;
                    bits ^= bits << 17;
                    match bits % 32 {
                        0 => *c = -*c,
                        1 => *c = 0,
                        _ => {}
                    }
                }
                let h = |p: [f32; 3]| [p[0] as f64, p[1] as f64, p[2] as f64, 1.0];
                let l = light.map(|v| v as f64);
                let want = d
                    .caps
                    .iter()
                    .zip(&ev.caps)
                    .filter(|&(t, &c)| {
                        let p = t.map(|i| h(d.positions[i as usize]));
                        -svpack::exact::det4_sign([p[0], p[1], p[2], l]) != c as i32
                    })
                    .count() as u64;
                assert_eq!(
                    orientation_errors(&d, light, &ev),
                    want,
                    "{} {s:?} {light:?}",
                    input.display()
                );
                errors += want;
                checked += d.caps.len();
            }
        }
    }
    assert!(
        errors > 1000 && errors * 4 < checked as u64,
        "{errors} of {checked}"
    );
}

/// A damaged file whose side records name triangles the caps do not have:
/// the ordered evaluation (`evaluate_ordered`) leaves those records' blocks
/// to the input-order loop, and the whole evaluation still equals
/// evaluating every record as the shaders do.
#[test]
fn ordered_evaluation_of_a_damaged_file_equals_per_record_evaluation() {
    #[path = "../examples/sphere.rs"]
    mod sphere;
    use svpack::verify::{UNKNOWN, choose_lights, evaluate_per_record};
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("sphere.obj");
    std::fs::write(&src, sphere::sphere_obj(40)).unwrap();
    let out = tmp.path().join("sphere.svpk");
    svpack::build::build_file(&src, &out, &Default::default()).unwrap();
    // The first opposite vertex of every 50th record of the first bucket
    // moved off the sphere: its slot names no caps triangle.
    patch_payload(&out, |p, h| {
        let b = &h.meshes[0].buckets[0];
        let stride = (2 + b.k as usize) * 16;
        let start = (b.offset - h.payload_offset) as usize;
        for r in (0..b.instances as usize).step_by(50) {
            let at = start + r * stride + 32;
            p[at..at + 4].copy_from_slice(&7.5f32.to_le_bytes());
        }
    });
    let d = decode(&svpack::format::read_file(&out).unwrap(), 0);
    let o = d.ordered.as_ref().expect("a built file's table");
    let b = &d.buckets[0];
    let unknown = b.slot_tri.iter().filter(|&&t| t == UNKNOWN).count();
    assert_eq!(unknown, b.records().div_ceil(50));
    // Left over: each whole block of 16 records with an unknown slot, and
    // the bucket's tail.
    let block = svpack::evaluate_ordered::BLOCK;
    let whole = b.records() / block;
    let with_unknown = (0..whole)
        .filter(|&i| (i * block..(i + 1) * block).any(|r| r % 50 == 0))
        .count();
    let left: usize = o.leftovers(0).iter().map(|r| r.len()).sum();
    assert_eq!(left, with_unknown * block + b.records() % block);
    let lights = choose_lights(&d, 8, 3);
    // The same lights in groups of four (`evaluate_many_into`), whose
    // leftovers (the blocks with a slot that names no triangle, evaluated
    // on the records with each light) go through the same loop.
    let mut evs = vec![svpack::verify::Evaluation::default(); lights.len()];
    svpack::verify::evaluate_many_into(&d, &lights, Strategy::Reference, &mut evs);
    for (&light, many) in lights.iter().zip(&evs) {
        let got = evaluate(&d, light, Strategy::Reference);
        let want = evaluate_per_record(&d, light, Strategy::Reference);
        assert!(got.caps == want.caps, "caps differ for {light:?}");
        assert!(got.sides == want.sides, "sides differ for {light:?}");
        assert!(
            many.caps == want.caps,
            "caps of a group differ for {light:?}"
        );
        assert!(
            many.sides == want.sides,
            "sides of a group differ for {light:?}"
        );
    }
}

/// A damaged file's side record may name a position no cap has (`UNKNOWN`
/// in the decoded ids): the check counts it, it does not panic.
#[test]
fn closedness_survives_records_naming_unknown_positions() {
    let (_tmp, mut d) = built_fixture("two_tets.obj");
    let light = [0.3, 2.0, 0.7, 1.0];
    let ev = evaluate(&d, light, Strategy::Reference);
    let (b, r) = (0..d.buckets.len())
        .flat_map(|b| (0..ev.sides[b].len()).map(move |r| (b, r)))
        .find(|&(b, r)| ev.sides[b][r] != 0)
        .unwrap();
    let k = d.buckets[b].k;
    d.buckets[b].ids[r * (2 + k)] = svpack::verify::UNKNOWN;
    let general = check_closedness(&d, light, &ev);
    assert!(general.violations > 0);
    // The indexed check leaves such a file to the general one.
    let index = svpack::verify::ClosednessIndex::new(&d);
    let indexed =
        svpack::verify::check_closedness_indexed(&d, &index, light, &ev, &mut Default::default());
    assert_eq!(indexed, general);
}

#[test]
fn samples_on_volume_faces_are_reported_not_compared() {
    let (_tmp, d) = built_fixture("quad.obj");
    let light = [0.5, 0.5, 1.0, 1.0];
    let ev = evaluate(&d, light, Strategy::Reference);
    let index = svpack::shadow::ShadowIndex::new(&d);
    let on_faces = [
        [0.25, 0.5, 0.0],   // on the quad itself (front cap)
        [0.5, -0.5, -1.0],  // in the side plane through the edge y = 0 and the light
        [-0.5, -0.5, -1.0], // on the line from the light through the corner (0, 0, 0)
    ];
    let r = svpack::shadow::check_shadow(&d, &index, light, &ev, &on_faces);
    assert_eq!((r.on_faces, r.samples, r.mismatches), (3, 0, 0), "{r:?}");
    let clear = [[0.3, 0.6, -1.0], [3.0, 0.5, -1.0], [0.5, 0.5, 0.5]];
    let r = svpack::shadow::check_shadow(&d, &index, light, &ev, &clear);
    assert_eq!((r.on_faces, r.samples, r.mismatches), (0, 3, 0), "{r:?}");
}

/// The evaluator's shared path (each triangle once, from sorted corner ids;
/// sides as signed sums of cap signs) gives exactly what evaluating every
/// record as the shader does gives, for every consistent strategy, on the
/// hard cases and a real model.
#[test]
fn shared_evaluation_equals_per_record_evaluation() {
    use svpack::evaluate::Strategy;
    use svpack::verify::{choose_lights, decode, evaluate, evaluate_per_record};
    let tmp = tempfile::tempdir().unwrap();
    let inputs = hard_cases_and(tmp.path(), &["chair_model.obj"]);
    for input in inputs {
        let out = tmp.path().join("x.svpk");
        svpack::build::build_file(&input, &out, &Default::default()).unwrap();
        let d = decode(&svpack::format::read_file(&out).unwrap(), 0);
        assert!(
            d.buckets
                .iter()
                .all(|b| b.slot_tri.iter().all(|&t| t != u32::MAX))
        );
        // A built file's position table is strictly increasing, so the
        // shared path runs on the caps from sorted corner ids, numbered in
        // the sides' order (evaluate_ordered).
        assert!(d.ordered.is_some(), "{}", input.display());
        for light in choose_lights(&d, 24, 5) {
            for s in Strategy::ALL {
                let (a, b) = (evaluate(&d, light, s), evaluate_per_record(&d, light, s));
                assert_eq!(a.caps, b.caps);
                assert_eq!(a.sides, b.sides, "{} {s:?} {light:?}", input.display());
            }
        }
    }
}

/// Caps corners set to `-0.0` beside `+0.0`, and to NaNs of both signs: the
/// decoded positions are distinct by bits and in the documented total order
/// (the earlier comparison sort had no total order with NaNs), every caps
/// id names its corner's exact bits, and `verify` reports the damage (exit
/// 2: the NaNs are record errors) instead of failing; the exact predicates
/// of the geometric checks, which need finite values, are not run on them
/// (a debug build asserted inside them).
#[test]
fn signed_zeros_and_nans_decode_in_a_total_order() {
    let (_tmp, out) = built_file("seamed_cube.obj");
    let clean = decode(&svpack::format::read_file(&out).unwrap(), 0);
    let zero = clean
        .positions
        .iter()
        .position(|p| p[0] == 0.0)
        .expect("a corner with x = 0");
    let bits_of = |p: [f32; 3]| p.map(f32::to_bits);
    let zero_bits = bits_of(clean.positions[zero]);
    patch_payload(&out, |p, h| {
        let caps = (h.meshes[0].caps.offset - h.payload_offset) as usize;
        let corners = h.meshes[0].caps.count as usize * 3;
        let mut seen_zero = 0;
        for c in 0..corners {
            let at = caps + 16 * c;
            let x: [u8; 4] = p[at..at + 4].try_into().unwrap();
            let y: [u8; 4] = p[at + 4..at + 8].try_into().unwrap();
            let z: [u8; 4] = p[at + 8..at + 12].try_into().unwrap();
            let b = [x, y, z].map(u32::from_le_bytes);
            // One corner at the zero position becomes -0.0 in x; two other
            // corners become NaNs of either sign.
            let new_x = if b == zero_bits {
                seen_zero += 1;
                (seen_zero == 1).then_some(0x8000_0000u32)
            } else if c == 5 {
                Some(0x7fc0_0001)
            } else if c == 7 {
                Some(0xffc0_0002)
            } else {
                None
            };
            if let Some(v) = new_x {
                p[at..at + 4].copy_from_slice(&v.to_le_bytes());
            }
        }
    });
    let file = svpack::format::read_file(&out).unwrap();
    let d = decode(&file, 0);
    let key = |v: u32| v ^ ((((v as i32) >> 31) as u32) | 0x8000_0000);
    let keys: Vec<[u32; 3]> = d.positions.iter().map(|p| bits_of(*p).map(key)).collect();
    assert!(keys.windows(2).all(|w| w[0] < w[1]), "{:?}", d.positions);
    assert!(d.positions[0][0].is_nan() && d.positions[0][0].is_sign_negative());
    let last = d.positions[d.positions.len() - 1];
    assert!(last[0].is_nan() && last[0].is_sign_positive());
    let minus = (0..d.positions.len())
        .find(|&i| d.positions[i][0].to_bits() == 0x8000_0000)
        .expect("the -0.0 corner is a position of its own");
    assert_eq!(
        bits_of(d.positions[minus + 1]),
        zero_bits,
        "-0.0 just before +0.0"
    );
    // Every caps id names its corner's bits.
    let caps = file.floats(
        file.header.meshes[0].caps.offset,
        file.header.meshes[0].caps.length,
    );
    for (t, ids) in d.caps.iter().enumerate() {
        for (c, &id) in ids.iter().enumerate() {
            let r = &caps[12 * t + 4 * c..12 * t + 4 * c + 3];
            assert_eq!(
                bits_of(d.positions[id as usize]),
                bits_of([r[0], r[1], r[2]]),
                "triangle {t} corner {c}"
            );
        }
    }
    assert!(
        d.ordered.is_none(),
        "a ±0.0 pair and NaNs: no sorted-id caps"
    );
    let (code, j) = verify_json(&out, &[]);
    assert_eq!(code, Some(2), "{j}");
    assert_eq!(j["ok"], false);
    assert_eq!(j["record_errors"], 2, "{j}");
    assert!(
        j["first_problem"]
            .as_str()
            .unwrap()
            .contains("is not finite"),
        "{j}"
    );
    assert_eq!(j["samples"], 0, "{j}");
    assert_eq!(j["orientation_errors"], 0, "{j}");
    let s = check_structure(&d);
    assert_eq!(s.record_errors, 2, "{s:?}");
}

/// Check 1's bijection as it was first written: every (a, b, o) triple of
/// the sides and of the caps sorted, and the multiset difference counted;
/// the first problem is the smallest unmatched triple.
fn bijection_by_sorting(d: &svpack::verify::Decoded) -> (u64, Option<String>) {
    let mut sides = Vec::new();
    for b in &d.buckets {
        for ids in b.ids.chunks_exact(2 + b.k) {
            sides.extend(ids[2..].iter().map(|&o| [ids[0], ids[1], o]));
        }
    }
    let mut caps: Vec<[u32; 3]> = d
        .caps
        .iter()
        .flat_map(|t| {
            (0..3).map(move |e| {
                let (p, q, o) = (t[e], t[(e + 1) % 3], t[(e + 2) % 3]);
                [p.min(q), p.max(q), o]
            })
        })
        .collect();
    sides.sort_unstable();
    caps.sort_unstable();
    let points = |t: [u32; 3]| {
        t.iter()
            .map(|&i| d.positions.get(i as usize).copied())
            .collect::<Vec<_>>()
    };
    let (mut i, mut j, mut errors, mut first) = (0, 0, 0, None);
    while i < sides.len() || j < caps.len() {
        if j == caps.len() || (i < sides.len() && sides[i] < caps[j]) {
            errors += 1;
            first.get_or_insert_with(|| {
                format!(
                    "sides entry (A, B, O) = {:?} matches no caps triangle",
                    points(sides[i])
                )
            });
            i += 1;
        } else if i == sides.len() || caps[j] < sides[i] {
            errors += 1;
            first.get_or_insert_with(|| {
                format!(
                    "caps (triangle, edge) {:?} has no sides entry",
                    points(caps[j])
                )
            });
            j += 1;
        } else {
            i += 1;
            j += 1;
        }
    }
    (errors, first)
}

/// Check 1's bijection (regular triples counted per corner set, the rest
/// sorted) against sorting every triple, on files damaged at random: vec4s
/// of the sides and caps overwritten with other positions of the file
/// (moved ends, swapped A and B, degenerate and duplicated caps).
#[test]
fn bijection_counts_what_sorting_every_triple_counts() {
    let mut bits = {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        }
    };
    let (mut damaged, mut firsts) = (0, 0);
    for name in [
        "fan12.obj",
        "dup_degen.obj",
        "two_tets.obj",
        "seamed_cube.obj",
    ] {
        let (_tmp, out) = built_file(name);
        let clean = std::fs::read(&out).unwrap();
        let h = svpack::format::read_file(&out).unwrap().header;
        let po = h.payload_offset as usize;
        let vec4s = (clean.len() - po) / 16;
        for case in 0..150 {
            let mut bytes = clean.clone();
            // 1 to 3 vec4s (xyz only) overwritten by other vec4s' xyz.
            for _ in 0..1 + case % 3 {
                let (to, from) = (bits() as usize % vec4s, bits() as usize % vec4s);
                let (to, from) = (po + 16 * to, po + 16 * from);
                let xyz: Vec<u8> = bytes[from..from + 12].to_vec();
                bytes[to..to + 12].copy_from_slice(&xyz);
            }
            fix_checksums(&mut bytes, &h);
            let file = svpack::format::decode(&out, bytes).unwrap();
            let d = decode(&file, 0);
            let s = check_structure(&d);
            let (errors, first) = bijection_by_sorting(&d);
            assert_eq!(s.bijection_errors, errors, "{name} case {case}");
            damaged += usize::from(errors > 0);
            if s.record_errors == 0 {
                assert_eq!(s.first_problem, first, "{name} case {case}");
                firsts += usize::from(first.is_some());
            }
        }
    }
    assert!(
        damaged > 300 && firsts > 100,
        "{damaged} damaged, {firsts} compared"
    );
}

/// Lights evaluated in groups (`evaluate_many_into`: the caps of each group
/// of `LIGHT_GROUP` lights in one pass, the sides from the group's table)
/// give every light what `evaluate` gives it, for every strategy (the
/// others evaluate light by light), with the buffers reused for a second
/// set of lights; nine lights, so that one is left after the two groups.
#[test]
fn lights_in_groups_equal_lights_one_by_one() {
    use svpack::verify::{Evaluation, choose_lights, evaluate_many_into};
    let tmp = tempfile::tempdir().unwrap();
    for input in hard_cases_and(tmp.path(), &["chair_model.obj"]) {
        let out = tmp.path().join("x.svpk");
        svpack::build::build_file(&input, &out, &Default::default()).unwrap();
        let d = decode(&svpack::format::read_file(&out).unwrap(), 0);
        let lights = choose_lights(&d, 18, 9);
        for s in Strategy::ALL {
            let mut evs = vec![Evaluation::default(); 9];
            for set in [&lights[..9], &lights[9..]] {
                evaluate_many_into(&d, set, s, &mut evs);
                for (&l, ev) in set.iter().zip(&evs) {
                    let one = evaluate(&d, l, s);
                    assert!(ev.caps == one.caps, "{} {s:?} {l:?}: caps", input.display());
                    assert!(
                        ev.sides == one.sides,
                        "{} {s:?} {l:?}: sides",
                        input.display()
                    );
                }
            }
        }
    }
}
