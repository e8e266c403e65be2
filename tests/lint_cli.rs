//! `svpack lint` on the command line: exit codes and --deny.

mod common;

use common::{svpack, write_fixtures};
use predicates::prelude::*;

#[test]
fn deny_controls_the_exit_code() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let path = |n: &str| fx.iter().find(|f| f.0 == n).unwrap().1.clone();
    // Clean closed model: nothing at all, even with warnings denied.
    svpack()
        .arg("lint")
        .arg(path("cube.obj"))
        .arg("--deny=warnings")
        .assert()
        .code(0);
    // Non-manifold edge: a warning, allowed by default, denied on request.
    svpack()
        .arg("lint")
        .arg(path("two_tets.obj"))
        .assert()
        .code(0)
        .stdout(predicate::str::contains("non-manifold-edge"));
    svpack()
        .arg("lint")
        .arg(path("two_tets.obj"))
        .arg("--deny=warnings")
        .assert()
        .code(3);
    svpack()
        .arg("lint")
        .arg(path("two_tets.obj"))
        .arg("--deny=non-manifold-edge")
        .assert()
        .code(3)
        .stdout(predicate::str::contains("[denied]"));
    svpack()
        .arg("lint")
        .arg(path("two_tets.obj"))
        .arg("--deny=open-edge")
        .assert()
        .code(0);
    // Open edges are info: only an explicit code denies them.
    svpack()
        .arg("lint")
        .arg(path("quad.obj"))
        .arg("--deny=warnings")
        .assert()
        .code(0);
    svpack()
        .arg("lint")
        .arg(path("quad.obj"))
        .arg("--deny=open-edge")
        .assert()
        .code(3);
    // Unknown codes are usage errors.
    svpack()
        .arg("lint")
        .arg(path("quad.obj"))
        .arg("--deny=no-such-code")
        .assert()
        .code(1)
        .stderr(predicate::str::contains("unknown code"));
    // Error severity (NaN) is always denied; unreadable inputs are exit 1.
    let nan = tmp.path().join("nan.obj");
    std::fs::write(&nan, "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n").unwrap();
    svpack()
        .arg("lint")
        .arg(&nan)
        .assert()
        .code(3)
        .stdout(predicate::str::contains("non-finite"));
    svpack()
        .arg("lint")
        .arg(tmp.path().join("missing.obj"))
        .assert()
        .code(1)
        .stderr(predicate::str::contains("missing.obj"));
}

#[test]
fn json_lists_findings_per_file() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let r = svpack()
        .arg("lint")
        .arg(&fx.iter().find(|f| f.0 == "fan12.obj").unwrap().1)
        .arg("--json")
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(0));
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let findings = j[0]["findings"].as_array().unwrap();
    let codes: Vec<&str> = findings
        .iter()
        .map(|f| f["code"].as_str().unwrap())
        .collect();
    assert_eq!(codes, vec!["non-manifold-edge", "open-edge", "split-edge"]);
    assert_eq!(findings[1]["count"], 24);
    assert_eq!(findings[0]["severity"], "warning");
    assert!(findings[0]["examples"][0]["positions"].is_array());
}

#[test]
fn readme_documents_every_code() {
    let readme = std::fs::read_to_string(common::root().join("README.md")).unwrap();
    for (code, severity, _) in svpack::lint::CODES {
        let sev = format!("{severity:?}").to_lowercase();
        assert!(
            readme.contains(&format!("| `{code}` | {sev} |")),
            "README lint table lacks `{code}` ({sev})"
        );
    }
}
