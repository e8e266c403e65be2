//! `svpack build --trace FILE`: a timeline of the build's threads as
//! Chrome trace event JSON (`svpack::trace`).

use std::collections::HashSet;
use std::path::Path;

mod common;
use common::{svpack, torus};

/// One complete (`X`) event: name, thread, start and end in µs.
type Interval = (String, u64, f64, f64);

/// The complete events of the trace at `path`, and the threads named by
/// metadata events.
fn events(path: &Path) -> (Vec<Interval>, HashSet<u64>) {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let mut out = Vec::new();
    let mut named = HashSet::new();
    for e in v["traceEvents"].as_array().expect("traceEvents") {
        let tid = e["tid"].as_u64().unwrap();
        match e["ph"].as_str().unwrap() {
            "M" => {
                assert_eq!(e["name"], "thread_name");
                assert!(e["args"]["name"].as_str().is_some_and(|n| !n.is_empty()));
                named.insert(tid);
            }
            "X" => {
                let (ts, dur) = (e["ts"].as_f64().unwrap(), e["dur"].as_f64().unwrap());
                assert!(ts >= 0.0 && dur >= 0.0, "{e}");
                out.push((e["name"].as_str().unwrap().to_string(), tid, ts, ts + dur));
            }
            other => panic!("unexpected phase {other}"),
        }
    }
    (out, named)
}

/// A two-thread build of a mesh large enough to be written ahead records
/// its stages once each, in order, on one thread; the caps' and sides'
/// fills and file writes inside them, the writes on more than one thread
/// (the copier's beside the emitting one's); a name for every thread. The
/// output is the same bytes as without `--trace`. Caught: every thread
/// given the same number (the writes then all on one thread).
#[test]
fn a_two_thread_build_records_its_stages_fills_and_writes() {
    let dir = tempfile::tempdir().unwrap();
    // 2 × 200² = 80,000 triangles: above `format::ROOM_MIN_TRIANGLES`, so
    // the caps and side blocks are written ahead, beside the edges.
    let input = torus(dir.path(), 200, 0, 0.5);
    let (traced, plain, json) = (
        dir.path().join("traced.svpk"),
        dir.path().join("plain.svpk"),
        dir.path().join("build.json"),
    );
    for (out, trace) in [(&traced, Some(&json)), (&plain, None)] {
        let mut cmd = svpack();
        cmd.args(["--threads", "2", "build", "-q"])
            .arg(&input)
            .arg("-o")
            .arg(out);
        if let Some(t) = trace {
            cmd.arg("--trace").arg(t);
        }
        cmd.assert().success();
    }
    assert!(
        std::fs::read(&traced).unwrap() == std::fs::read(&plain).unwrap(),
        "the trace changed the output"
    );
    let (ev, named) = events(&json);
    let stage = |name: &str| {
        let found: Vec<_> = ev.iter().filter(|e| e.0 == name).collect();
        assert_eq!(found.len(), 1, "one {name} stage: {found:?}");
        found[0].clone()
    };
    let stages: Vec<_> = ["load", "weld", "topology", "layout", "write"]
        .map(stage)
        .into();
    for w in stages.windows(2) {
        assert_eq!(w[0].1, w[1].1, "stages on one thread: {w:?}");
        assert!(w[0].3 <= w[1].2 + 1.0, "stages in order: {w:?}");
    }
    let (topology, write) = (&stages[2], &stages[4]);
    // Units of caps and blocks of sides: several fills, each written,
    // all within the stages that copy (the topology's with the file
    // written ahead, the write stage's for what is left).
    let of = |name: &'static str| ev.iter().filter(move |e| e.0 == name);
    assert!(of("fill").count() >= 3, "fills: {}", of("fill").count());
    assert_eq!(of("fill").count(), of("file write").count());
    for e in of("fill").chain(of("file write")) {
        assert!(
            e.2 >= topology.2 - 1.0 && e.3 <= write.3 + 1.0,
            "{e:?} outside the topology and write stages"
        );
    }
    let writers: HashSet<u64> = of("file write").map(|e| e.1).collect();
    assert!(writers.len() >= 2, "file writes on one thread only");
    let emit: Vec<_> = of("topology: emit").collect();
    assert_eq!(emit.len(), 1, "one fed emit pass: {emit:?}");
    assert!(
        of("file write").any(|e| e.1 != emit[0].1),
        "no write beside the emit"
    );
    let used: HashSet<u64> = ev.iter().map(|e| e.1).collect();
    assert!(
        used.is_subset(&named),
        "unnamed threads: {used:?} {named:?}"
    );
}

/// A trace path whose directory does not exist fails before the build:
/// non-zero exit, the path in the message, and neither the trace nor the
/// output written. Caught: the trace's file made only after the build
/// (the output was then written and left).
#[test]
fn an_unwritable_trace_path_fails_before_building() {
    let dir = tempfile::tempdir().unwrap();
    let input = common::root().join("fixtures/cube.obj");
    let out = dir.path().join("cube.svpk");
    let trace = dir.path().join("missing").join("t.json");
    let assert = svpack()
        .args(["build", "-q"])
        .arg(&input)
        .arg("-o")
        .arg(&out)
        .arg("--trace")
        .arg(&trace)
        .assert()
        .failure();
    let stderr = String::from_utf8_lossy(&assert.get_output().stderr).into_owned();
    assert!(stderr.contains("t.json"), "{stderr}");
    assert!(!out.exists() && !trace.exists());
}
