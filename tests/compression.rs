//! `build --compress-level`, `inspect --compress-level` and `bench
//! --compression`: the level reaches the frame, the container inside is the
//! same at every level, the sizes reported are the sizes written, and bad
//! levels are refused before anything is written.

mod common;

use common::svpack;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// Builds `input` into `dir/name` with `args`; the summary as JSON.
fn build(dir: &Path, input: &Path, name: &str, args: &[&str]) -> (PathBuf, Value) {
    let out = dir.join(name);
    let o = svpack()
        .arg("build")
        .arg(input)
        .arg("-o")
        .arg(&out)
        .arg("--json")
        .args(args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    (out, serde_json::from_slice(&o.stdout).unwrap())
}

/// Bytes of the file `build --compress-level level` writes for `input`.
fn frame_len(dir: &Path, input: &Path, level: &str) -> u64 {
    let (frame, _) = build(
        dir,
        input,
        &format!("l{level}.svpk"),
        &["--compress-level", level],
    );
    std::fs::metadata(&frame).unwrap().len()
}

/// Each level writes its own frame, the same bytes for one thread or two;
/// `--compress` alone is level 9; every frame holds the same container;
/// the summary names the level. Caught: the level ignored (every frame
/// level 9's bytes).
#[test]
fn the_level_reaches_the_frame_and_not_the_container() {
    let tmp = tempfile::tempdir().unwrap();
    let input = common::torus(tmp.path(), 120, 2, 0.5);
    let (plain, _) = build(tmp.path(), &input, "plain.svpk", &[]);
    let (one, j1) = build(tmp.path(), &input, "l1.svpk", &["--compress-level", "1"]);
    let (one_t1, _) = build(
        tmp.path(),
        &input,
        "l1t1.svpk",
        &["--compress-level", "1", "--threads", "1"],
    );
    let (nineteen, _) = build(tmp.path(), &input, "l19.svpk", &["--compress-level", "19"]);
    let (nine, j9) = build(tmp.path(), &input, "l9.svpk", &["--compress-level", "9"]);
    let (default, jd) = build(tmp.path(), &input, "d.svpk", &["--compress"]);
    let read = |p: &Path| std::fs::read(p).unwrap();
    assert_eq!(read(&one), read(&one_t1), "level 1, one thread or two");
    assert_eq!(read(&default), read(&nine), "--compress is level 9");
    assert_ne!(read(&one), read(&nine));
    assert!(
        read(&nineteen).len() < read(&one).len(),
        "level 19 {} bytes, level 1 {}",
        read(&nineteen).len(),
        read(&one).len()
    );
    let inner: Vec<Vec<u8>> = [&one, &nine, &nineteen]
        .iter()
        .map(|p| zstd::decode_all(&read(p)[..]).unwrap())
        .collect();
    assert!(inner.iter().all(|c| *c == inner[0]), "containers differ");
    assert_eq!(inner[0].len(), read(&plain).len());
    assert_eq!(j1["zstd_level"], 1);
    assert_eq!(j9["zstd_level"], 9);
    assert_eq!(jd["zstd_level"], 9);
    assert_eq!(j1["file_bytes"].as_u64().unwrap(), read(&one).len() as u64);
    // The text summary too.
    svpack()
        .args(["build", "--compress-level", "3", "-o"])
        .arg(tmp.path().join("l3.svpk"))
        .arg(&input)
        .assert()
        .code(0)
        .stdout(predicates::str::contains("(zstd level 3;"));
    // A plain build's summary has no level.
    let (_, jp) = build(tmp.path(), &input, "plain2.svpk", &[]);
    assert!(jp.get("zstd_level").is_none(), "{jp}");
}

/// `inspect --compress-level L` sizes a plain file exactly as `build
/// --compress-level L` writes it. A compressed file reports its own size
/// and no level. Caught: inspect's size at its default level whatever the
/// option; the plain container compressed as it is (its header's
/// `--compress` record unset: 7 bytes off at level 1 here).
#[test]
fn inspect_sizes_the_frame_of_its_level() {
    let tmp = tempfile::tempdir().unwrap();
    let input = common::torus(tmp.path(), 100, 0, 0.5);
    let (plain, _) = build(tmp.path(), &input, "plain.svpk", &[]);
    let inspect = |file: &Path, args: &[&str]| -> Value {
        let o = svpack()
            .arg("inspect")
            .arg(file)
            .arg("--json")
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    for level in ["1", "9", "19"] {
        let written = frame_len(tmp.path(), &input, level);
        let j = inspect(&plain, &["--compress-level", level]);
        assert_eq!(j["zstd_bytes"].as_u64().unwrap(), written, "level {level}");
        assert_eq!(j["zstd_level"].to_string(), level);
        let frame = tmp.path().join(format!("l{level}.svpk"));
        let back = inspect(&frame, &["--compress-level", "1"]);
        assert_eq!(back["zstd_bytes"].as_u64().unwrap(), written);
        assert!(back.get("zstd_level").is_none(), "{back}");
    }
    // Without the option: level 9, named in the text.
    let j = inspect(&plain, &[]);
    assert_eq!(j["zstd_level"], 9);
    svpack()
        .arg("inspect")
        .arg(&plain)
        .assert()
        .code(0)
        .stdout(predicates::str::contains("at level 9"));
}

/// Levels outside 1..=22 are refused by `build`, `inspect` and `bench`
/// with exit 1 and a message naming the option, and `build` leaves no
/// output. Caught: a parser without the range (zstd clamps 23 to 22 and
/// writes a file).
#[test]
fn levels_outside_the_range_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let input = common::torus(tmp.path(), 20, 0, 0.5);
    let out = tmp.path().join("o.svpk");
    for bad in ["0", "23", "-1", "x"] {
        svpack()
            .args(["build", "--compress-level", bad, "-o"])
            .arg(&out)
            .arg(&input)
            .assert()
            .code(1)
            .stderr(predicates::str::contains("--compress-level"));
        assert!(!out.exists(), "level {bad} wrote a file");
    }
    let (plain, _) = build(tmp.path(), &input, "plain.svpk", &[]);
    svpack()
        .args(["inspect", "--compress-level", "23"])
        .arg(&plain)
        .assert()
        .code(1)
        .stderr(predicates::str::contains("--compress-level"));
    svpack()
        .args(["bench", "--compression", "--levels", "1,23", "--out"])
        .arg(tmp.path().join("b"))
        .arg(&input)
        .assert()
        .code(1)
        .stderr(predicates::str::contains("--levels"));
    // --compression needs inputs; bench needs one of its two kinds.
    svpack()
        .args(["bench", "--compression", "--out"])
        .arg(tmp.path().join("b"))
        .assert()
        .code(1);
    svpack()
        .args(["bench", "--out"])
        .arg(tmp.path().join("b"))
        .arg(&input)
        .assert()
        .code(1);
    assert!(!tmp.path().join("b").exists());
}

/// `bench --compression`: both encodings per input, each level asked for
/// once, and sizes that are the sizes `build --compress-level` writes (the f32
/// rows; the plain size is the plain build's); the three files. Caught: the
/// bench compressing with the default level whatever `--levels` said.
#[test]
fn the_compression_bench_reports_the_sizes_build_writes() {
    let tmp = tempfile::tempdir().unwrap();
    let input = common::torus(tmp.path(), 90, 1, 0.3);
    let out = tmp.path().join("bench");
    svpack()
        .args([
            "bench",
            "--compression",
            "--levels",
            "1,19,1",
            "--reps",
            "1",
            "--out",
        ])
        .arg(&out)
        .arg(&input)
        .assert()
        .code(0)
        .stdout(predicates::str::contains("| level | bytes |"));
    let r: Value =
        serde_json::from_slice(&std::fs::read(out.join("compression.json")).unwrap()).unwrap();
    let rows = r["inputs"].as_array().unwrap();
    let encodings: Vec<&str> = rows
        .iter()
        .map(|i| i["positions"].as_str().unwrap())
        .collect();
    assert_eq!(encodings, ["f32", "unorm16"]);
    let (plain, _) = build(tmp.path(), &input, "plain.svpk", &[]);
    let f32_row = &rows[0];
    assert_eq!(
        f32_row["plain_bytes"].as_u64().unwrap(),
        std::fs::metadata(&plain).unwrap().len()
    );
    for row in rows {
        let levels: Vec<i64> = row["levels"]
            .as_array()
            .unwrap()
            .iter()
            .map(|l| l["level"].as_i64().unwrap())
            .collect();
        assert_eq!(levels, [1, 19]);
        let plain_bytes = row["plain_bytes"].as_f64().unwrap();
        for l in row["levels"].as_array().unwrap() {
            let bytes = l["bytes"].as_f64().unwrap();
            assert!((l["fraction"].as_f64().unwrap() - bytes / plain_bytes).abs() < 1e-12);
            assert!(l["compress_ms"].as_f64().unwrap() > 0.0);
        }
    }
    for (i, level) in ["1", "19"].iter().enumerate() {
        let written = frame_len(tmp.path(), &input, level);
        let reported = f32_row["levels"][i]["bytes"].as_u64().unwrap();
        assert_eq!(reported, written, "level {level}");
    }
    let md = std::fs::read_to_string(out.join("compression.md")).unwrap();
    assert!(md.contains("| 19 |") && md.contains("(unorm16,"), "{md}");
    let svg = std::fs::read_to_string(out.join("compression.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("size against speed"));
}
