//! Every real model in ../shared/meshes (obj/ and gltf/) builds, and its file
//! passes the read-back property.

mod common;
mod readback;

#[test]
fn every_shared_model_builds_and_reads_back() {
    let Some(shared) = common::shared_meshes() else {
        return;
    };
    let files = common::shared_models(&shared);
    assert!(
        files.len() >= 20,
        "expected the shared corpus, found {}",
        files.len()
    );
    let tmp = tempfile::tempdir().unwrap();
    let mut built = 0;
    for f in &files {
        let out = tmp.path().join("out.svpk");
        let r = common::svpack()
            .arg("build")
            .arg(f)
            .arg("-o")
            .arg(&out)
            .arg("--json")
            .output()
            .unwrap();
        let name = f.strip_prefix(&shared).unwrap().display().to_string();
        let stderr = String::from_utf8_lossy(&r.stderr);
        // Points-only and lines-only primitive-mode samples have no triangles.
        if r.status.code() == Some(1) && stderr.contains("no triangles") {
            eprintln!("{name}: {}", stderr.trim());
            continue;
        }
        assert!(r.status.success(), "{name}: {stderr}");
        let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
        eprintln!(
            "{name}: {} triangles, {} edges, max fan {}, {} bytes",
            j["triangles"], j["edges"], j["max_fan"], j["file_bytes"]
        );
        readback::check_file(&out, f);
        built += 1;
    }
    assert!(built >= 20, "only {built} models built");
}
