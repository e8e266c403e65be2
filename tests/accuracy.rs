//! `svpack bench --accuracy` on the hard-case suite: the report's files, and
//! the papers' claims as assertions — Kim 2008 cracks on hard cases, the
//! reference edge (and every consistent strategy) never does, exact
//! predicates never miss a sample, and quantisation never cracks.

mod common;

use common::svpack;
use serde_json::Value;

fn run(out: &std::path::Path, threads: &str) -> Value {
    svpack()
        .env("RAYON_NUM_THREADS", threads)
        .args([
            "bench",
            "--accuracy",
            "--lights",
            "8",
            "--samples",
            "32",
            "--out",
        ])
        .arg(out)
        .assert()
        .code(0);
    serde_json::from_slice(&std::fs::read(out.join("accuracy.json")).unwrap()).unwrap()
}

fn strategy<'a>(r: &'a Value, name: &str) -> &'a Value {
    r["strategies"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["strategy"] == name)
        .unwrap_or_else(|| panic!("no strategy {name}"))
}

#[test]
fn accuracy_report_shows_what_the_papers_claim() {
    let tmp = tempfile::tempdir().unwrap();
    let r = run(tmp.path(), "2");

    // Three outputs.
    let md = std::fs::read_to_string(tmp.path().join("accuracy.md")).unwrap();
    assert!(md.contains("| strategy | ns / edge instance |"));
    assert!(md.contains("| plane_tilted |"));
    let svg = std::fs::read_to_string(tmp.path().join("accuracy.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("ns per edge instance"));

    let names: Vec<&str> = r["strategies"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["strategy"].as_str().unwrap())
        .collect();
    assert_eq!(
        names,
        ["kim", "peciva", "reference", "reference-f64", "exact"]
    );
    assert_eq!(r["inputs"].as_array().unwrap().len(), 8, "the whole suite");

    // (a) cracks on hard cases: open volumes, sides and caps disagreeing.
    let kim = &strategy(&r, "kim")["errors"];
    assert!(kim["closedness_violations"].as_u64().unwrap() > 0);
    assert!(kim["disagreeing_triangles"].as_u64().unwrap() > 0);
    assert!(
        strategy(&r, "kim")["hard_cases_with_errors"]
            .as_array()
            .unwrap()
            .len()
            >= 2
    );
    // (b)–(e) are consistent: closed, sides and caps always agree.
    for s in ["peciva", "reference", "reference-f64", "exact"] {
        let e = &strategy(&r, s)["errors"];
        assert_eq!(e["closedness_violations"], 0, "{s}");
        assert_eq!(e["disagreeing_triangles"], 0, "{s}");
    }
    // (c), the format, is also right at every sample on the suite, and so is (e).
    for s in ["reference", "exact"] {
        let e = &strategy(&r, s)["errors"];
        assert_eq!(e["sample_mismatches"], 0, "{s}");
        assert_eq!(e["lights_with_errors"], 0, "{s}");
        assert!(e["samples"].as_u64().unwrap() > 1000, "{s}");
    }

    // Quantisation halves the bytes, moves vertices by at most half a step of
    // 1/65535 of the bounds, and never cracks.
    for i in r["inputs"].as_array().unwrap() {
        let q = &i["encodings"][1];
        assert_eq!(q["encoding"], "unorm16");
        assert_eq!(q["closedness_violations"], 0, "{}", i["name"]);
        assert!(q["max_displacement"].as_f64().unwrap() <= 0.5 / 65535.0 * 1.0001);
        let f = &i["encodings"][0];
        assert!(q["file_bytes"].as_u64() < f["file_bytes"].as_u64());
    }
}

#[test]
fn accuracy_counts_do_not_depend_on_threads() {
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    let (ra, rb) = (run(a.path(), "1"), run(b.path(), "2"));
    // Everything but the times.
    assert_eq!(ra["inputs"], rb["inputs"]);
    for (x, y) in ra["strategies"]
        .as_array()
        .unwrap()
        .iter()
        .zip(rb["strategies"].as_array().unwrap())
    {
        assert_eq!(x["errors"], y["errors"]);
    }
}

#[test]
fn accuracy_rejects_a_missing_input_after_reporting_the_rest() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("missing.obj");
    svpack()
        .args([
            "bench",
            "--accuracy",
            "--lights",
            "2",
            "--samples",
            "8",
            "--out",
        ])
        .arg(tmp.path().join("out"))
        .arg(&missing)
        .assert()
        .code(1)
        .stderr(predicates::str::contains("missing.obj"));
    // The report of what could be built is still written.
    let md = std::fs::read_to_string(tmp.path().join("out/accuracy.md")).unwrap();
    assert!(md.contains("missing.obj"));
}
