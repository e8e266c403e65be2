//! Every file in ../shared/meshes/malformed either builds or is rejected with
//! exit 1 and a message naming the file — never a panic, never partial output.

mod common;

#[test]
fn malformed_inputs_load_sensibly_or_fail_cleanly() {
    let Some(shared) = common::shared_meshes() else {
        return;
    };
    let files = common::files_with_ext(&shared.join("malformed"), &["gltf", "glb", "obj"]);
    assert!(
        files.len() >= 20,
        "expected the malformed corpus, found {}",
        files.len()
    );
    let tmp = tempfile::tempdir().unwrap();
    let mut report = Vec::new();
    for f in &files {
        let out = tmp.path().join("out.svpk");
        let _ = std::fs::remove_file(&out);
        let r = common::svpack()
            .arg("build")
            .arg(f)
            .arg("-o")
            .arg(&out)
            .output()
            .unwrap();
        let code = r.status.code();
        let stderr = String::from_utf8_lossy(&r.stderr);
        let name = f.file_name().unwrap().to_string_lossy();
        match code {
            Some(0) => assert!(out.exists(), "{name}: exit 0 but no output"),
            Some(1) => {
                assert!(
                    stderr.contains(&*name),
                    "{name}: error does not name the file: {stderr}"
                );
                assert!(!out.exists(), "{name}: failed build left an output file");
            }
            _ => panic!("{name}: exit {code:?} (panic or crash?): {stderr}"),
        }
        report.push(format!("{name}: exit {} {}", code.unwrap(), stderr.trim()));
        let left: Vec<_> = std::fs::read_dir(tmp.path())
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name())
            .filter(|n| n != "out.svpk")
            .collect();
        assert!(left.is_empty(), "{name}: stray files {left:?}");
    }
    eprintln!("{}", report.join("\n"));
    // Files that are broken in ways a loader must catch.
    for (file, needle) in [
        ("IndexOutOfRange.gltf", "range"),
        ("AllIndicesOutOfRange.gltf", "range"),
        ("BoxTextured.gltf", ".bin"),
        ("RecursiveNodes.gltf", "ancestor"),
        ("BoxWithInfinites.glb", "non-finite"),
    ] {
        let line = report
            .iter()
            .find(|l| l.starts_with(file))
            .unwrap_or_else(|| panic!("{file} not in corpus"));
        assert!(line.contains("exit 1") && line.contains(needle), "{line}");
    }
}
