//! `--positions unorm16` (format-spec §4.5): 16-bit quantised positions.
//! Sizes halve, codes decode to within half a step of the input, volumes stay
//! closed on the hard cases and a non-manifold model, nearby vertices weld,
//! and a tampered code is caught.

mod common;

use common::{svpack, write_fixtures};
use std::path::{Path, PathBuf};
use svpack::build::{BuildConfig, build_file};
use svpack::evaluate::Strategy;
use svpack::format::{Encoding, read_file};
use svpack::verify::{VerifyLight, choose_lights, decode, verify};

fn unorm16() -> BuildConfig {
    BuildConfig {
        positions: Encoding::Unorm16,
        ..BuildConfig::default()
    }
}

fn build_both(input: &Path, dir: &Path) -> (PathBuf, PathBuf) {
    let stem = input.file_stem().unwrap().to_string_lossy().into_owned();
    let f = dir.join(format!("{stem}.f32.svpk"));
    let q = dir.join(format!("{stem}.q.svpk"));
    build_file(input, &f, &BuildConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    build_file(input, &q, &unorm16()).unwrap_or_else(|e| panic!("{e}"));
    (f, q)
}

/// Reads the caps section of a unorm16 file straight from the bytes, as the
/// spec describes it (u16 codes, not through the library's decoder).
fn raw_caps_codes(bytes: &[u8], offset: u64, count: u64) -> Vec<[u16; 4]> {
    (0..count * 3)
        .map(|i| {
            let at = (offset + 8 * i) as usize;
            [0, 1, 2, 3].map(|c| u16::from_le_bytes([bytes[at + 2 * c], bytes[at + 2 * c + 1]]))
        })
        .collect()
}

#[test]
fn fixtures_halve_and_decode_within_half_a_step() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, input) in write_fixtures(tmp.path()) {
        let (f, q) = build_both(&input, tmp.path());
        let (ff, qf) = (read_file(&f).unwrap(), read_file(&q).unwrap());
        assert_eq!(qf.encoding(), Encoding::Unorm16);
        let (fm, qm) = (&ff.header.meshes[0], &qf.header.meshes[0]);
        // Section sizes: 8 bytes per vec4, sections 16-aligned.
        assert_eq!(qm.caps.length, 24 * qm.caps.count, "{name}");
        for b in &qm.buckets {
            assert_eq!(b.length, 8 * (2 + b.k as u64) * b.instances, "{name}");
            assert_eq!(b.offset % 16, 0, "{name}");
        }
        assert!(qf.file_bytes < ff.file_bytes, "{name}");
        assert_eq!(fm.position_offset, [0.0; 3]);
        assert_eq!(fm.position_scale, [1.0; 3]);
        // Offset and scale are the bounds box.
        assert_eq!(qm.position_offset, qm.bounds_min, "{name}");
        if qm.caps.count != fm.caps.count {
            continue; // quantisation collapsed a triangle: corners no longer pair up
        }
        let codes = raw_caps_codes(&qf.bytes, qm.caps.offset, qm.caps.count);
        let exact = ff.floats(fm.caps.offset, fm.caps.length);
        for (i, c) in codes.iter().enumerate() {
            assert_eq!(c[3], 1, "{name}: caps w is the raw integer 1");
            for k in 0..3 {
                let world = qm.position_offset[k] as f64
                    + (c[k] as f64 / 65535.0) * qm.position_scale[k] as f64;
                let want = exact[4 * i + k] as f64;
                let step = qm.position_scale[k] as f64 / 65535.0;
                assert!(
                    (world - want).abs() <= 0.5 * step * (1.0 + 1e-9) + 1e-12,
                    "{name}: corner {i} axis {k}: {world} vs {want}"
                );
            }
        }
    }
}

#[test]
fn unorm16_builds_are_reproducible_and_inspectable() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let input = &fx.iter().find(|f| f.0 == "two_tets.obj").unwrap().1;
    let a = tmp.path().join("a.svpk");
    let b = tmp.path().join("b.svpk");
    for out in [&a, &b] {
        svpack()
            .args(["build", "--positions", "unorm16", "-o"])
            .arg(out)
            .arg(input)
            .assert()
            .code(0);
    }
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    let out = svpack()
        .args(["inspect", "--json"])
        .arg(&a)
        .assert()
        .code(0)
        .get_output()
        .stdout
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert_eq!(v["positions"], "unorm16");
    svpack()
        .args(["verify", "--lights", "16"])
        .arg(&a)
        .assert()
        .code(0);
}

/// Verifies a unorm16 build with the case's own (world) lights and 48
/// generated in record space.
fn verify_q(q: &Path, world: &[[f32; 4]]) -> svpack::verify::VerifyReport {
    let file = read_file(q).unwrap();
    let mut lights: Vec<VerifyLight> = world.iter().map(|&l| VerifyLight::World(l)).collect();
    lights.extend(
        choose_lights(&decode(&file, 0), 48, 3)
            .into_iter()
            .map(VerifyLight::Record),
    );
    verify(&file, &lights, Strategy::Reference, 96)
}

#[test]
fn hard_cases_stay_closed_when_quantised() {
    let tmp = tempfile::tempdir().unwrap();
    for c in svpack::hardcases::cases() {
        let input = tmp.path().join(format!("{}.obj", c.name));
        std::fs::write(&input, svpack::hardcases::obj(&c.v, &c.f)).unwrap();
        let q = tmp.path().join(format!("{}.svpk", c.name));
        build_file(&input, &q, &unorm16()).unwrap_or_else(|e| panic!("{e}"));
        let rep = verify_q(&q, &c.lights);
        assert!(
            rep.ok,
            "{}: {} bijection, {} record errors, {} closedness violations, {} mismatches ({:?})",
            c.name,
            rep.bijection_errors,
            rep.record_errors,
            rep.closedness_violations,
            rep.sample_mismatches,
            rep.first_mismatch.or(rep.first_problem)
        );
    }
}

#[test]
fn nearby_vertices_weld_and_collapsed_triangles_drop() {
    // A unit square of two triangles plus a sliver whose third corner is
    // 1e-7 from a square corner: a different f32 position, the same code.
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("near.obj");
    std::fs::write(
        &input,
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 1.0000001 1 0\nv 0.5 0.5 1\n\
         f 1 2 3\nf 1 3 4\nf 3 5 6\nf 1 2 6\n",
    )
    .unwrap();
    let (f, q) = build_both(&input, tmp.path());
    let (ff, qf) = (read_file(&f).unwrap(), read_file(&q).unwrap());
    let (fs, qs) = (&ff.header.meshes[0].stats, &qf.header.meshes[0].stats);
    assert_eq!(fs.welded_vertices, 6);
    assert_eq!(fs.degenerate_triangles, 0);
    assert_eq!(qs.welded_vertices, 5, "1.0000001 and 1 share a code");
    assert_eq!(qs.degenerate_triangles, 1, "the sliver collapses");
    assert_eq!(qs.triangles, 3);
    assert!(verify_q(&q, &[[0.3, 0.2, 2.0, 1.0]]).ok);
}

#[test]
fn non_manifold_model_stays_closed_when_quantised() {
    let Some(shared) = common::shared_meshes() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let (_, q) = build_both(&shared.join("obj/chair_model.obj"), tmp.path());
    let rep = verify_q(&q, &[]);
    assert!(rep.ok, "{:?}", rep.first_mismatch.or(rep.first_problem));
    assert!(rep.closedness_violations == 0 && rep.lights.len() >= 48);
}

/// Recomputes both checksums of an edited file, so only the checks that
/// look at the data can object.
fn restamp(bytes: &mut [u8]) {
    let hlen = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
    // The 2.0 fields; these small files have no header room
    // (`Header::reserved` 0), which the length check below confirms.
    let (mut h, _): (svpack::format::Header, usize) =
        bincode::serde::decode_from_slice(&bytes[24..24 + hlen], bincode::config::legacy())
            .unwrap();
    h.payload_crc32 = crc32fast::hash(&bytes[h.payload_offset as usize..]);
    let hb = svpack::format::encode_header(&h).unwrap();
    assert_eq!(hb.len(), hlen);
    bytes[24..24 + hlen].copy_from_slice(&hb);
    bytes[16..20].copy_from_slice(&crc32fast::hash(&hb).to_le_bytes());
}

#[test]
fn a_tampered_code_is_caught() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let input = &fx.iter().find(|f| f.0 == "two_tets.obj").unwrap().1;
    let q = tmp.path().join("q.svpk");
    build_file(input, &q, &unorm16()).unwrap();
    let good = std::fs::read(&q).unwrap();
    let h = read_file(&q).unwrap().header;
    let m = &h.meshes[0];
    // Move the x code of the first opposite vertex of the first side record.
    let at = (m.buckets[0].offset + 16) as usize;
    let mut bad = good.clone();
    let c = u16::from_le_bytes([bad[at], bad[at + 1]]);
    bad[at..at + 2].copy_from_slice(&(c ^ 0x0100).to_le_bytes());
    restamp(&mut bad);
    let p = tmp.path().join("bad.svpk");
    std::fs::write(&p, &bad).unwrap();
    let out = svpack()
        .args(["verify", "--lights", "4", "--json"])
        .arg(&p)
        .assert()
        .code(2)
        .get_output()
        .stdout
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&out).unwrap();
    assert!(v["bijection_errors"].as_u64().unwrap() > 0, "{v}");
    // The untouched file passes.
    svpack()
        .args(["verify", "--lights", "4"])
        .arg(&q)
        .assert()
        .code(0);
}
