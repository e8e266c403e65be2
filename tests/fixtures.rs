//! Generated fixtures with hand-computed expectations, the read-back property,
//! size formulas and reproducibility.

mod common;
mod readback;

use common::{fixtures, svpack, write_fixtures};
use serde_json::Value;

/// Expected figures, worked out by hand (see the comments in tests/common).
struct Expect {
    name: &'static str,
    input_triangles: u64,
    input_vertices: u64,
    welded_vertices: u64,
    degenerate: u64,
    triangles: u64,
    edges: u64,
    open: u64,
    non_manifold: u64,
    max_fan: u64,
    /// (k, instances, bytes) with the default K = 5.
    buckets: &'static [(u64, u64, u64)],
}

const EXPECT: &[Expect] = &[
    // 12 cube edges + 6 face diagonals, all with 2 opposite vertices: 18 × 16·(2+2).
    Expect {
        name: "cube.obj",
        input_triangles: 12,
        input_vertices: 8,
        welded_vertices: 8,
        degenerate: 0,
        triangles: 12,
        edges: 18,
        open: 0,
        non_manifold: 0,
        max_fan: 2,
        buckets: &[(2, 18, 1152)],
    },
    // Same cube, 24 corners weld to 8.
    Expect {
        name: "seamed_cube.obj",
        input_triangles: 12,
        input_vertices: 24,
        welded_vertices: 8,
        degenerate: 0,
        triangles: 12,
        edges: 18,
        open: 0,
        non_manifold: 0,
        max_fan: 2,
        buckets: &[(2, 18, 1152)],
    },
    // 4 boundary edges (48 B each) + the diagonal (64 B).
    Expect {
        name: "quad.obj",
        input_triangles: 2,
        input_vertices: 4,
        welded_vertices: 4,
        degenerate: 0,
        triangles: 2,
        edges: 5,
        open: 4,
        non_manifold: 0,
        max_fan: 2,
        buckets: &[(1, 4, 192), (2, 1, 64)],
    },
    // Shared edge with 12 = 5 + 5 + 2 opposites, 24 open fin edges.
    Expect {
        name: "fan12.obj",
        input_triangles: 12,
        input_vertices: 14,
        welded_vertices: 14,
        degenerate: 0,
        triangles: 12,
        edges: 25,
        open: 24,
        non_manifold: 1,
        max_fan: 12,
        buckets: &[(1, 24, 1152), (2, 1, 64), (5, 2, 224)],
    },
    // 6 + 6 − 1 edges; the shared one has 4 opposites.
    Expect {
        name: "two_tets.obj",
        input_triangles: 8,
        input_vertices: 6,
        welded_vertices: 6,
        degenerate: 0,
        triangles: 8,
        edges: 11,
        open: 0,
        non_manifold: 1,
        max_fan: 4,
        buckets: &[(2, 10, 640), (4, 1, 96)],
    },
    // 8 input, 2 degenerate; the duplicated face's 3 edges have 4 opposites.
    Expect {
        name: "dup_degen.obj",
        input_triangles: 8,
        input_vertices: 5,
        welded_vertices: 4,
        degenerate: 2,
        triangles: 6,
        edges: 6,
        open: 0,
        non_manifold: 3,
        max_fan: 4,
        buckets: &[(2, 3, 192), (4, 3, 288)],
    },
    // Two instances of a tetrahedron, disjoint.
    Expect {
        name: "mirrored.gltf",
        input_triangles: 8,
        input_vertices: 8,
        welded_vertices: 8,
        degenerate: 0,
        triangles: 8,
        edges: 12,
        open: 0,
        non_manifold: 0,
        max_fan: 2,
        buckets: &[(2, 12, 768)],
    },
];

#[test]
fn shipped_fixtures_are_the_generated_ones() {
    let dir = common::root().join("fixtures");
    let bless = std::env::var_os("SVPACK_BLESS").is_some();
    for (name, data) in fixtures() {
        let p = dir.join(name);
        if bless {
            std::fs::write(&p, &data).unwrap();
        }
        let on_disk = std::fs::read(&p)
            .unwrap_or_else(|_| panic!("fixtures/{name} missing (run with SVPACK_BLESS=1)"));
        assert!(
            on_disk == data,
            "fixtures/{name} differs from the generator (run with SVPACK_BLESS=1)"
        );
    }
    assert_eq!(EXPECT.len(), fixtures().len());
}

fn build_json(input: &std::path::Path, output: &std::path::Path, extra: &[&str]) -> Value {
    let out = svpack()
        .arg("build")
        .arg(input)
        .arg("-o")
        .arg(output)
        .arg("--json")
        .args(extra)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "build {} failed: {}",
        input.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn fixtures_match_hand_counts() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, path) in write_fixtures(tmp.path()) {
        let e = EXPECT.iter().find(|e| e.name == name).unwrap();
        let j = build_json(&path, &tmp.path().join(format!("{name}.svpk")), &[]);
        let g = |k: &str| {
            j[k].as_u64()
                .unwrap_or_else(|| panic!("{name}: field {k} missing"))
        };
        assert_eq!(g("input_triangles"), e.input_triangles, "{name}");
        assert_eq!(g("input_vertices"), e.input_vertices, "{name}");
        assert_eq!(g("welded_vertices"), e.welded_vertices, "{name}");
        assert_eq!(g("degenerate_triangles"), e.degenerate, "{name}");
        assert_eq!(g("triangles"), e.triangles, "{name}");
        assert_eq!(g("edges"), e.edges, "{name}");
        assert_eq!(g("open_edges"), e.open, "{name}");
        assert_eq!(g("non_manifold_edges"), e.non_manifold, "{name}");
        assert_eq!(g("max_fan"), e.max_fan, "{name}");
        let buckets: Vec<(u64, u64, u64)> = j["buckets"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| {
                (
                    b["k"].as_u64().unwrap(),
                    b["instances"].as_u64().unwrap(),
                    b["bytes"].as_u64().unwrap(),
                )
            })
            .collect();
        assert_eq!(buckets, e.buckets, "{name}");
        // Size formulas, exactly.
        let sides: u64 = e.buckets.iter().map(|b| 16 * (2 + b.0) * b.1).sum();
        assert_eq!(g("sides_bytes"), sides, "{name}");
        assert_eq!(g("caps_bytes"), 48 * e.triangles, "{name}");
        assert_eq!(
            g("edge_instances"),
            e.buckets.iter().map(|b| b.1).sum::<u64>(),
            "{name}"
        );
        assert_eq!(
            g("paper_bytes"),
            16 * (2 + e.max_fan) * e.edges + 48 * e.triangles,
            "{name}"
        );
        assert_eq!(
            g("file_bytes"),
            g("header_bytes") + sides + 48 * e.triangles,
            "{name}"
        );
        assert_eq!(g("header_bytes") % 16, 0);
    }
}

#[test]
fn splitting_follows_max_mult() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let fan = &fx.iter().find(|f| f.0 == "fan12.obj").unwrap().1;
    let cases: &[(&str, &[(u64, u64)])] = &[
        ("1", &[(1, 36)]),                 // 24 fins + 12 chunks of 1
        ("3", &[(1, 24), (3, 4)]),         // 12 = 4 × 3
        ("5", &[(1, 24), (2, 1), (5, 2)]), // 12 = 5 + 5 + 2
        ("12", &[(1, 24), (12, 1)]),
        ("13", &[(1, 24), (12, 1)]),
    ];
    for (k, want) in cases {
        let j = build_json(fan, &tmp.path().join("fan.svpk"), &["--max-mult", k]);
        let got: Vec<(u64, u64)> = j["buckets"]
            .as_array()
            .unwrap()
            .iter()
            .map(|b| (b["k"].as_u64().unwrap(), b["instances"].as_u64().unwrap()))
            .collect();
        assert_eq!(&got, want, "--max-mult {k}");
        readback::check_file(&tmp.path().join("fan.svpk"), fan);
    }
}

#[test]
fn readback_property_holds_for_fixtures() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, path) in write_fixtures(tmp.path()) {
        let out = tmp.path().join(format!("{name}.svpk"));
        build_json(&path, &out, &[]);
        readback::check_file(&out, &path);
    }
}

#[test]
fn mirrored_instance_keeps_outward_winding() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let src = &fx.iter().find(|f| f.0 == "mirrored.gltf").unwrap().1;
    let out = tmp.path().join("m.svpk");
    build_json(src, &out, &[]);
    let f = svpack::format::read_file(&out).unwrap();
    let m = &f.header.meshes[0];
    let caps = f.floats(m.caps.offset, m.caps.length);
    // Signed volume per instance (split by x: the mirrored copy is at x in [2, 3]).
    let (mut left, mut right) = (0.0f64, 0.0f64);
    for t in caps.chunks_exact(12) {
        let p = |i: usize| [t[4 * i] as f64, t[4 * i + 1] as f64, t[4 * i + 2] as f64];
        let (a, b, c) = (p(0), p(1), p(2));
        let vol = (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]))
            / 6.0;
        if a[0] + b[0] + c[0] > 4.5 {
            right += vol
        } else {
            left += vol
        }
    }
    assert!(
        (left - 1.0 / 6.0).abs() < 1e-9,
        "plain instance volume {left}"
    );
    assert!(
        (right - 1.0 / 6.0).abs() < 1e-9,
        "mirrored instance volume {right} (winding not reversed?)"
    );
}

#[test]
fn build_twice_is_byte_identical_and_compress_round_trips() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, path) in write_fixtures(tmp.path()) {
        let a = tmp.path().join("a.svpk");
        let b = tmp.path().join("b.svpk");
        let c = tmp.path().join("c.svpk");
        let ja = build_json(&path, &a, &[]);
        build_json(&path, &b, &[]);
        let jc = build_json(&path, &c, &["--compress"]);
        let (ba, bb, bc) = (
            std::fs::read(&a).unwrap(),
            std::fs::read(&b).unwrap(),
            std::fs::read(&c).unwrap(),
        );
        assert_eq!(ba, bb, "{name}: two builds differ");
        assert_eq!(
            &bc[..4],
            &[0x28, 0xB5, 0x2F, 0xFD],
            "{name}: not a zstd frame"
        );
        assert_eq!(jc["file_bytes"].as_u64().unwrap(), bc.len() as u64);
        assert!(jc["compressed"].as_bool().unwrap());
        // The wrapped container is the plain one except for the compress flag.
        let inner = zstd::decode_all(&bc[..]).unwrap();
        assert_eq!(inner.len(), ba.len(), "{name}");
        for key in [
            "triangles",
            "edges",
            "sides_bytes",
            "caps_bytes",
            "container_bytes",
        ] {
            assert_eq!(ja[key], jc[key], "{name}: {key}");
        }
        // inspect reads both back and reports the same figures as build.
        for (file, j) in [(&a, &ja), (&c, &jc)] {
            let out = svpack()
                .arg("inspect")
                .arg(file)
                .arg("--json")
                .output()
                .unwrap();
            assert!(out.status.success());
            let mut ji: Value = serde_json::from_slice(&out.stdout).unwrap();
            let mut jb = j.clone();
            jb.as_object_mut().unwrap().remove("time_ms");
            ji.as_object_mut().unwrap().remove("time_ms");
            ji.as_object_mut().unwrap().remove("zstd_bytes");
            // The level: inspect's for its size of a plain file, build's for
            // a compressed one (a frame does not record it).
            let (li, lb) = (
                ji.as_object_mut().unwrap().remove("zstd_level"),
                jb.as_object_mut().unwrap().remove("zstd_level"),
            );
            let compressed = file == &c;
            assert_eq!(li, (!compressed).then(|| Value::from(9)), "{name}");
            assert_eq!(lb, compressed.then(|| Value::from(9)), "{name}");
            assert_eq!(ji, jb, "{name}: inspect differs from build");
        }
    }
}
