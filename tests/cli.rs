//! Command-line behaviour: exit codes, error messages naming the file, no
//! partial output, and the reader rejecting damaged files.

mod common;

use common::{svpack, write_fixtures};
use predicates::prelude::*;

fn no_stray_files(dir: &std::path::Path, allowed: &[&str]) {
    for e in std::fs::read_dir(dir).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        assert!(
            allowed.contains(&name.as_str()),
            "unexpected file left behind: {name}"
        );
    }
}

#[test]
fn missing_input_is_exit_1_and_names_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("o.svpk");
    svpack()
        .args(["build", "no/such/model.obj", "-o"])
        .arg(&out)
        .assert()
        .code(1)
        .stderr(predicate::str::contains("no/such/model.obj"));
    assert!(!out.exists());
}

#[test]
fn usage_errors_are_exit_1() {
    svpack().arg("frobnicate").assert().code(1);
    svpack().args(["build", "x.obj"]).assert().code(1); // no -o
    for bad in ["0", "14", "-1", "five"] {
        svpack()
            .args([
                "build",
                "fixtures/cube.obj",
                "-o",
                "/tmp/never.svpk",
                &format!("--max-mult={bad}"),
            ])
            .assert()
            .code(1)
            .stderr(predicate::str::contains("max-mult"));
    }
    svpack().arg("--help").assert().code(0);
    svpack().arg("--version").assert().code(0);
}

#[test]
fn unknown_format_and_empty_models_are_rejected_without_output() {
    let tmp = tempfile::tempdir().unwrap();
    let txt = tmp.path().join("notes.txt");
    std::fs::write(&txt, "hello").unwrap();
    let pts = tmp.path().join("points.obj");
    std::fs::write(&pts, "v 0 0 0\nv 1 0 0\np 1 2\n").unwrap();
    let nan = tmp.path().join("nan.obj");
    std::fs::write(&nan, "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n").unwrap();
    let out = tmp.path().join("o.svpk");
    for (input, msg) in [
        (&txt, "unknown input format"),
        (&pts, "no triangles"),
        (&nan, "non-finite"),
    ] {
        svpack()
            .arg("build")
            .arg(input)
            .arg("-o")
            .arg(&out)
            .assert()
            .code(1)
            .stderr(predicate::str::contains(
                input.file_name().unwrap().to_str().unwrap(),
            ))
            .stderr(predicate::str::contains(msg));
    }
    no_stray_files(tmp.path(), &["notes.txt", "points.obj", "nan.obj"]);
}

#[test]
fn failed_build_keeps_the_previous_output_intact() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let cube = &fx.iter().find(|f| f.0 == "cube.obj").unwrap().1;
    let out = tmp.path().join("o.svpk");
    svpack()
        .arg("build")
        .arg(cube)
        .arg("-o")
        .arg(&out)
        .assert()
        .code(0);
    let before = std::fs::read(&out).unwrap();
    let bad = tmp.path().join("bad.obj");
    std::fs::write(&bad, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n").unwrap();
    svpack()
        .arg("build")
        .arg(&bad)
        .arg("-o")
        .arg(&out)
        .assert()
        .code(1)
        .stderr(predicate::str::contains("bad.obj"));
    assert_eq!(std::fs::read(&out).unwrap(), before);
}

/// Damages a good file in several ways; inspect must say what is wrong, exit 1.
#[test]
fn inspect_rejects_damaged_files() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let src = &fx.iter().find(|f| f.0 == "two_tets.obj").unwrap().1;
    let good = tmp.path().join("good.svpk");
    svpack()
        .arg("build")
        .arg(src)
        .arg("-o")
        .arg(&good)
        .assert()
        .code(0);
    svpack().arg("inspect").arg(&good).assert().code(0);
    let bytes = std::fs::read(&good).unwrap();
    let hlen = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;

    let patched = |f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = bytes.clone();
        f(&mut b);
        b
    };
    // A header whose checksum is right but whose sections lie: one more
    // instance in the first bucket than the payload holds.
    let with_header = |f: &dyn Fn(&mut svpack::format::Header)| {
        let mut h = svpack::format::read_file(&good).unwrap().header;
        f(&mut h);
        let hb = svpack::format::encode_header(&h).unwrap();
        assert_eq!(hb.len(), hlen);
        let mut b = bytes.clone();
        b[16..20].copy_from_slice(&crc32fast::hash(&hb).to_le_bytes());
        b[24..24 + hlen].copy_from_slice(&hb);
        b
    };
    let lying_header = with_header(&|h| h.meshes[0].buckets[0].instances += 1);
    // Valid checksums, but an encoding this version does not know, and a
    // record-space scale of zero (no inverse).
    let unknown_encoding = with_header(&|h| h.options.positions = 7);
    let zero_scale = with_header(&|h| h.meshes[0].position_scale[1] = 0.0);
    let last = bytes.len() - 5;
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty", Vec::new(), "truncated"),
        ("truncated_preamble", bytes[..10].to_vec(), "truncated"),
        ("truncated_header", bytes[..40].to_vec(), "truncated"),
        (
            "truncated_payload",
            bytes[..bytes.len() - 16].to_vec(),
            "truncated",
        ),
        (
            "trailing",
            patched(&|b| b.extend_from_slice(&[0; 16])),
            "unexpected bytes",
        ),
        ("magic", patched(&|b| b[0] = b'X'), "bad magic"),
        (
            "version",
            patched(&|b| b[8] = 3),
            "unsupported format version 3.1",
        ),
        (
            "version_1",
            patched(&|b| b[8] = 1),
            "unsupported format version 1.1",
        ),
        ("header_bit", patched(&|b| b[30] ^= 1), "header checksum"),
        (
            "payload_bit",
            patched(&|b| b[last] ^= 0x40),
            "payload checksum",
        ),
        ("lying_header", lying_header, "bucket k=2"),
        (
            "unknown_encoding",
            unknown_encoding,
            "unknown position encoding 7",
        ),
        ("zero_scale", zero_scale, "position transform"),
        (
            "zstd_junk",
            [0x28, 0xB5, 0x2F, 0xFD]
                .iter()
                .chain(&[7u8; 20])
                .copied()
                .collect(),
            "zstd",
        ),
    ];

    for (name, data, msg) in cases {
        let p = tmp.path().join(format!("{name}.svpk"));
        std::fs::write(&p, data).unwrap();
        svpack()
            .arg("inspect")
            .arg(&p)
            .assert()
            .code(1)
            .stderr(predicate::str::contains(format!("{name}.svpk")))
            .stderr(predicate::str::contains(msg));
    }
}

#[test]
fn human_summary_mentions_the_essentials() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("c.svpk");
    svpack()
        .args(["build", "fixtures/fan12.obj", "-o"])
        .arg(&out)
        .assert()
        .code(0)
        .stdout(predicate::str::contains("12 triangles"))
        .stdout(predicate::str::contains("max fan 12"))
        .stdout(predicate::str::contains("k=5"))
        .stdout(predicate::str::contains("uniform layout with maxMult = 12"));
    svpack()
        .arg("inspect")
        .arg(&out)
        .assert()
        .code(0)
        .stdout(predicate::str::contains("max fan 12"));
}

/// `--timings` adds per-stage wall times and peak memory; `--threads` does
/// not change a byte of the output; progress bars never reach a stderr that is
/// not a terminal.
#[test]
fn timings_threads_and_quiet_progress() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let input = &fx.iter().find(|f| f.0 == "fan12.obj").unwrap().1;
    let mut files = Vec::new();
    for threads in ["1", "2"] {
        let out = tmp.path().join(format!("t{threads}.svpk"));
        let o = svpack()
            .args(["build", "--timings", "--json", "--threads", threads, "-o"])
            .arg(&out)
            .arg(input)
            .assert()
            .code(0)
            .get_output()
            .clone();
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let t = &v["timings_ms"];
        let stages: f64 = ["load", "weld", "topology", "layout", "write"]
            .iter()
            .map(|k| {
                t[k].as_f64()
                    .unwrap_or_else(|| panic!("timings_ms.{k}: {t}"))
            })
            .sum();
        let total = t["total"].as_f64().unwrap();
        assert!(stages <= total * 1.0001 + 1e-3, "{stages} > {total}");
        // The copy into the file, summed over the threads that wrote.
        let copy = t["write_calls"].as_f64().unwrap();
        let threads: f64 = threads.parse().unwrap();
        assert!(copy > 0.0 && copy <= threads * total, "write_calls: {t}");
        assert!(v["peak_memory_bytes"].as_u64().unwrap() > 1 << 20);
        // Whichever pages this machine handed out, the field says which.
        assert!(v["cold_memory"].is_boolean(), "cold_memory: {v}");
        assert!(
            o.stderr.is_empty(),
            "stderr: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        files.push(std::fs::read(&out).unwrap());
    }
    assert_eq!(files[0], files[1]);
    // Without --timings the fields are absent.
    let o = svpack()
        .args(["build", "--json", "-o"])
        .arg(tmp.path().join("plain.svpk"))
        .arg(input)
        .assert()
        .code(0)
        .get_output()
        .stdout
        .clone();
    let v: serde_json::Value = serde_json::from_slice(&o).unwrap();
    assert!(
        v.get("timings_ms").is_none()
            && v.get("peak_memory_bytes").is_none()
            && v.get("cold_memory").is_none()
    );
    // A batch (which would show a bar on a terminal) writes nothing to a piped stderr.
    let inputs: Vec<_> = fx.iter().map(|f| f.1.clone()).collect();
    svpack()
        .args(["build", "-o"])
        .arg(tmp.path().join("batch"))
        .args(&inputs)
        .assert()
        .code(0)
        .stderr(predicate::str::is_empty());
}

/// Outputs get the mode any new file gets (0666 less the umask), not the
/// 0600 of the temp file they are written to before the rename. The umask
/// is set for the child alone, through `sh`, so the expected modes are
/// exact whatever the test runner's umask.
#[cfg(unix)]
#[test]
fn outputs_are_created_with_the_usual_file_mode() {
    use std::os::unix::fs::PermissionsExt;
    let tmp = tempfile::tempdir().unwrap();
    let cube = common::root().join("fixtures/cube.obj");
    let bin = assert_cmd::cargo::cargo_bin("svpack");
    // Streamed (uncompressed) and whole-buffer (compressed) writers.
    for (umask, expected) in [("022", 0o644), ("027", 0o640), ("002", 0o664)] {
        for (name, args) in [("cube.svpk", ""), ("cube_z.svpk", " --compress")] {
            let out = tmp.path().join(format!("{umask}_{name}"));
            let script = format!("umask {umask} && exec \"$0\" build \"$1\" -o \"$2\"{args}");
            let status = std::process::Command::new("sh")
                .args(["-c", &script])
                .arg(&bin)
                .arg(&cube)
                .arg(&out)
                .stdout(std::process::Stdio::null())
                .status()
                .unwrap();
            assert!(status.success(), "{umask} {name}");
            let mode = std::fs::metadata(&out).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, expected, "umask {umask}, {name}: mode {mode:o}");
        }
    }
}

/// Rebuilding over an existing output, which on Linux swaps the new file in
/// (`renameat2` with `RENAME_EXCHANGE`) and removes the old one, must behave
/// as the plain rename did: the path gets the new bytes, a hard link to the
/// old file keeps the old bytes, a symlink at the path is replaced (its
/// target untouched), and no temp file is left behind; for the streamed and
/// the compressed writer. (A directory given as `-o` receives the output
/// inside it; `format::tests` checks `persist` itself with one.)
#[cfg(unix)]
#[test]
fn rebuilding_in_place_replaces_the_output_whole() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let root = common::root();
    let (cube, tets) = (
        root.join("fixtures/cube.obj"),
        root.join("fixtures/two_tets.obj"),
    );
    for (compress, suffix) in [(false, ""), (true, "_z")] {
        let build = |input: &std::path::Path, out: &std::path::Path| {
            let mut c = svpack();
            c.arg("build").arg(input).arg("-o").arg(out).arg("-q");
            if compress {
                c.arg("--compress");
            }
            c.assert()
        };
        // The bytes each input gives, built into fresh paths.
        let (want_cube, want_tets) = (
            dir.join(format!("want_cube{suffix}")),
            dir.join(format!("want_tets{suffix}")),
        );
        build(&cube, &want_cube).success();
        build(&tets, &want_tets).success();
        let (want_cube, want_tets) = (
            std::fs::read(&want_cube).unwrap(),
            std::fs::read(&want_tets).unwrap(),
        );
        assert_ne!(want_cube, want_tets);

        // A regular file, hard-linked elsewhere.
        let out = dir.join(format!("out{suffix}.svpk"));
        let link = dir.join(format!("link{suffix}"));
        build(&cube, &out).success();
        std::fs::hard_link(&out, &link).unwrap();
        build(&tets, &out).success();
        assert!(
            std::fs::read(&out).unwrap() == want_tets,
            "new bytes in place"
        );
        assert!(
            std::fs::read(&link).unwrap() == want_cube,
            "old file kept by its link"
        );
        build(&cube, &out).success();
        assert!(std::fs::read(&out).unwrap() == want_cube, "and back");

        // A symlink: replaced by the output, its target untouched.
        let target = dir.join(format!("target{suffix}"));
        let sym = dir.join(format!("sym{suffix}.svpk"));
        std::fs::write(&target, b"not an svpk").unwrap();
        std::os::unix::fs::symlink(&target, &sym).unwrap();
        build(&tets, &sym).success();
        assert!(
            std::fs::symlink_metadata(&sym)
                .unwrap()
                .file_type()
                .is_file()
        );
        assert!(std::fs::read(&sym).unwrap() == want_tets);
        assert_eq!(std::fs::read(&target).unwrap(), b"not an svpk");
    }
    let mut allowed = vec![];
    for s in ["", "_z"] {
        allowed.extend([
            format!("want_cube{s}"),
            format!("want_tets{s}"),
            format!("out{s}.svpk"),
            format!("link{s}"),
            format!("target{s}"),
            format!("sym{s}.svpk"),
        ]);
    }
    no_stray_files(dir, &allowed.iter().map(String::as_str).collect::<Vec<_>>());
}
