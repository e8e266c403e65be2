//! Batch builds: one output per input, failures reported at the end,
//! outputs identical whatever --jobs is.

mod common;
mod readback;

use common::{svpack, write_fixtures};
use predicates::prelude::*;

#[test]
fn batch_outputs_are_identical_for_any_job_count() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let inputs: Vec<_> = fx.iter().map(|f| f.1.clone()).collect();
    let mut dirs = Vec::new();
    for jobs in ["1", "2", "0"] {
        let out = tmp.path().join(format!("out{jobs}"));
        svpack()
            .arg("build")
            .args(&inputs)
            .arg("-o")
            .arg(&out)
            .arg(format!("--jobs={jobs}"))
            .assert()
            .code(0);
        dirs.push(out);
    }
    for (name, _) in &fx {
        let stem = std::path::Path::new(name)
            .file_stem()
            .unwrap()
            .to_str()
            .unwrap();
        let a = std::fs::read(dirs[0].join(format!("{stem}.svpk"))).unwrap();
        for d in &dirs[1..] {
            assert_eq!(
                a,
                std::fs::read(d.join(format!("{stem}.svpk"))).unwrap(),
                "{name}"
            );
        }
        // Same bytes as a single build.
        let single = tmp.path().join("single.svpk");
        let src = &fx.iter().find(|f| &f.0 == name).unwrap().1;
        svpack()
            .arg("build")
            .arg(src)
            .arg("-o")
            .arg(&single)
            .assert()
            .code(0);
        assert_eq!(a, std::fs::read(&single).unwrap(), "{name}");
    }
}

/// A batch starts its inputs largest first (`build::batch_order`, by
/// `load::work_estimate`) and answers in input order. With one job the
/// builds run one after another, so the order in which their loads start
/// is the schedule. Caught: the order reversed (smallest first); the loop
/// taking the inputs in the order given; a result stored at its place in
/// the schedule instead of its input's.
#[test]
fn a_batch_starts_its_largest_inputs_first_and_answers_in_input_order() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let fixture = |name: &str| fx.iter().find(|f| f.0 == name).unwrap().1.clone();
    let inputs = vec![
        fixture("quad.obj"),
        common::torus(tmp.path(), 40, 0, 0.5),
        fixture("mirrored.gltf"),
        fixture("fan12.obj"),
    ];
    let work: Vec<u64> = inputs
        .iter()
        .map(|i| svpack::load::work_estimate(i))
        .collect();
    let order = svpack::build::batch_order(&inputs);
    let mut sorted = order.clone();
    sorted.sort();
    assert_eq!(sorted, [0, 1, 2, 3]);
    assert_eq!(order[0], 1, "the torus first: {work:?}");
    assert!(
        order.windows(2).all(|w| work[w[0]] >= work[w[1]]),
        "{order:?} by {work:?}"
    );
    let outputs: Vec<_> = (0..inputs.len())
        .map(|n| tmp.path().join(format!("out{n}.svpk")))
        .collect();
    let started = std::sync::Mutex::new(Vec::new());
    let results = svpack::build::build_batch_with(
        &inputs,
        &outputs,
        &svpack::build::BuildConfig::default(),
        &svpack::build::BatchConfig::jobs(1),
        &|n, stage| {
            if stage == "load" {
                started.lock().unwrap().push(n);
            }
        },
        &|_| {},
    );
    assert_eq!(*started.lock().unwrap(), order);
    for (input, result) in inputs.iter().zip(results) {
        let name = input.file_name().unwrap().to_str().unwrap();
        assert_eq!(result.unwrap().header.input.file_name, name);
    }
}

#[test]
fn failing_inputs_are_reported_and_the_rest_built() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let bad = tmp.path().join("broken.obj");
    std::fs::write(&bad, "v 0 0 0\nf 1 2 3\n").unwrap();
    let missing = tmp.path().join("missing.glb");
    let out = tmp.path().join("out");
    let r = svpack()
        .arg("build")
        .arg(&fx[0].1)
        .arg(&bad)
        .arg(&fx[1].1)
        .arg(&missing)
        .arg("-o")
        .arg(&out)
        .arg("--json")
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&r.stderr);
    assert!(stderr.contains("2 of 4 inputs failed"), "{stderr}");
    assert!(
        stderr.contains("broken.obj") && stderr.contains("missing.glb"),
        "{stderr}"
    );
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let oks: Vec<bool> = j
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["ok"].as_bool().unwrap())
        .collect();
    assert_eq!(oks, vec![true, false, true, false]);
    assert!(j[0]["summary"]["triangles"].as_u64().unwrap() > 0);
    assert!(out.join("cube.svpk").exists() && out.join("seamed_cube.svpk").exists());
    assert!(!out.join("broken.svpk").exists() && !out.join("missing.svpk").exists());
}

#[test]
fn colliding_output_names_are_refused_before_building() {
    let tmp = tempfile::tempdir().unwrap();
    let a = tmp.path().join("a");
    let b = tmp.path().join("b");
    std::fs::create_dir_all(&a).unwrap();
    std::fs::create_dir_all(&b).unwrap();
    write_fixtures(&a);
    write_fixtures(&b);
    let out = tmp.path().join("out");
    svpack()
        .arg("build")
        .arg(a.join("cube.obj"))
        .arg(b.join("cube.obj"))
        .arg("-o")
        .arg(&out)
        .assert()
        .code(1)
        .stderr(predicate::str::contains("would both write"));
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0);
}

#[test]
fn report_lists_files_largest_first_with_size_comparisons() {
    let tmp = tempfile::tempdir().unwrap();
    let fx = write_fixtures(tmp.path());
    let out = tmp.path().join("out");
    let inputs: Vec<_> = fx.iter().map(|f| f.1.clone()).collect();
    svpack()
        .arg("build")
        .args(&inputs)
        .arg("-o")
        .arg(&out)
        .assert()
        .code(0);
    let r = svpack()
        .arg("report")
        .arg(&out)
        .arg("--json")
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(0));
    let j: serde_json::Value = serde_json::from_slice(&r.stdout).unwrap();
    let rows = j.as_array().unwrap();
    assert_eq!(rows.len(), fx.len());
    let sizes: Vec<u64> = rows
        .iter()
        .map(|x| x["summary"]["file_bytes"].as_u64().unwrap())
        .collect();
    assert!(
        sizes.windows(2).all(|w| w[0] >= w[1]),
        "not largest first: {sizes:?}"
    );
    for x in rows {
        let s = &x["summary"];
        let t = s["triangles"].as_u64().unwrap();
        assert_eq!(s["psv_bytes"].as_u64().unwrap(), 128 * (t + 1));
        let per_mesh: u64 = s["meshes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|m| m["sides_bytes"].as_u64().unwrap())
            .sum();
        assert_eq!(per_mesh, s["sides_bytes"].as_u64().unwrap());
    }
    // inspect adds the zstd size; for an already compressed file it is the file size.
    let cube = out.join("cube.svpk");
    let j: serde_json::Value = serde_json::from_slice(
        &svpack()
            .arg("inspect")
            .arg(&cube)
            .arg("--json")
            .output()
            .unwrap()
            .stdout,
    )
    .unwrap();
    assert!(j["zstd_bytes"].as_u64().unwrap() < j["file_bytes"].as_u64().unwrap());
    let z = tmp.path().join("z.svpk");
    svpack()
        .arg("build")
        .arg(&fx[0].1)
        .arg("-o")
        .arg(&z)
        .arg("--compress")
        .assert()
        .code(0);
    let j: serde_json::Value = serde_json::from_slice(
        &svpack()
            .arg("inspect")
            .arg(&z)
            .arg("--json")
            .output()
            .unwrap()
            .stdout,
    )
    .unwrap();
    assert_eq!(j["zstd_bytes"], j["file_bytes"]);
    // A damaged file is listed with its error and makes the exit code 1.
    std::fs::write(out.join("junk.svpk"), b"not a file").unwrap();
    svpack()
        .arg("report")
        .arg(&out)
        .assert()
        .code(1)
        .stdout(predicate::str::contains("junk.svpk"))
        .stdout(predicate::str::contains("total of 8 files"));
}

/// The parallel stages (weld sort, topology blocks, layout blocks) on a
/// mesh large enough to span many blocks: the same bytes for 1, 2 and 3
/// threads, and a file that passes the independent read-back.
#[test]
fn large_build_is_thread_independent_and_reads_back() {
    let tmp = tempfile::tempdir().unwrap();
    // A 160 × 160 grid (51,200 triangles, 25,921 vertices, ~77k edges) plus
    // fins on every 7th grid edge: non-manifold edges scattered over blocks.
    let input = tmp.path().join("grid.obj");
    std::fs::write(&input, grid_with_fins(160)).unwrap();
    let mut files = Vec::new();
    for threads in ["1", "2", "3"] {
        let out = tmp.path().join(format!("g{threads}.svpk"));
        common::svpack()
            .args(["build", "--threads", threads, "-o"])
            .arg(&out)
            .arg(&input)
            .assert()
            .code(0);
        files.push(std::fs::read(&out).unwrap());
    }
    assert!(files.iter().all(|f| *f == files[0]));
    readback::check_file(&tmp.path().join("g2.svpk"), &input);
}

/// `--compress` runs zstd with as many workers as threads: the frame is the
/// same bytes for 1, 2 and 3 threads, on a file of several zstd jobs, and
/// holds exactly the uncompressed build.
#[test]
fn compressed_build_is_thread_independent() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("grid.obj");
    std::fs::write(&input, grid_with_fins(220)).unwrap();
    let plain = tmp.path().join("plain.svpk");
    common::svpack()
        .args(["build", "-o"])
        .arg(&plain)
        .arg(&input)
        .assert()
        .code(0);
    let plain = std::fs::read(&plain).unwrap();
    // Several 4 MiB jobs.
    assert!(plain.len() > 12 << 20, "{}", plain.len());
    let mut files = Vec::new();
    for threads in ["1", "2", "3"] {
        let out = tmp.path().join(format!("z{threads}.svpk"));
        common::svpack()
            .args(["build", "--compress", "--threads", threads, "-o"])
            .arg(&out)
            .arg(&input)
            .assert()
            .code(0);
        files.push(std::fs::read(&out).unwrap());
    }
    assert!(files.iter().all(|f| *f == files[0]), "frames differ");
    assert!(files[0].len() * 3 < plain.len());
    // The same container but for the header's record of `--compress` (and
    // its checksum): a few bytes near the start.
    let inner = zstd::decode_all(&files[0][..]).unwrap();
    assert_eq!(inner.len(), plain.len());
    let differ: Vec<usize> = (0..plain.len()).filter(|&i| inner[i] != plain[i]).collect();
    assert!(
        differ.len() <= 8 && differ.iter().all(|&i| i < 4096),
        "{:?}",
        &differ[..differ.len().min(20)]
    );
}

/// An OBJ grid of `n` × `n` squares, two triangles each, with a fin on
/// every 7th square's first edge (non-manifold edges scattered over the
/// parallel blocks).
fn grid_with_fins(n: usize) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let _ = writeln!(s, "v {} {} {}", i, j, ((i * 7 + j * 3) % 5) as f32 * 0.1);
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    let mut apex = (n + 1) * (n + 1);
    for j in 0..n {
        for i in 0..n {
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j), id(i + 1, j + 1));
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 7 == 0 {
                apex += 1;
                let _ = writeln!(s, "v {} {} 3", i as f32 + 0.5, j as f32 - 0.25);
                let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j), apex);
            }
        }
    }
    s
}

/// Rebuilding a batch over its own outputs: every build swaps its new
/// output in and hands the old file to the batch's removing thread
/// (`removals::Remover`), which the command waits for. Every output must
/// hold the new bytes (those of a fresh single build), a hard link to an
/// old output its old bytes, and no temp file may be left, with one job
/// or several.
#[cfg(unix)]
#[test]
fn rebuilding_a_batch_in_place_replaces_every_output_and_leaves_no_temp_file() {
    let tmp = tempfile::tempdir().unwrap();
    let objs: Vec<(&str, Vec<u8>)> = common::fixtures()
        .into_iter()
        .filter(|(name, _)| name.ends_with(".obj"))
        .collect();
    assert!(objs.len() >= 3);
    // The second inputs have the first ones' names and the next one's bytes.
    let (first, second) = (tmp.path().join("first"), tmp.path().join("second"));
    std::fs::create_dir_all(&first).unwrap();
    std::fs::create_dir_all(&second).unwrap();
    for (i, (name, data)) in objs.iter().enumerate() {
        std::fs::write(first.join(name), data).unwrap();
        std::fs::write(second.join(name), &objs[(i + 1) % objs.len()].1).unwrap();
    }
    let inputs = |dir: &std::path::Path| -> Vec<std::path::PathBuf> {
        objs.iter().map(|(n, _)| dir.join(n)).collect()
    };
    let stem = |name: &str| name.trim_end_matches(".obj").to_string();
    for jobs in ["1", "2"] {
        let out = tmp.path().join(format!("out{jobs}"));
        let links = tmp.path().join(format!("links{jobs}"));
        std::fs::create_dir_all(&links).unwrap();
        let batch = |dir: &std::path::Path| {
            svpack()
                .arg("build")
                .args(inputs(dir))
                .arg("-o")
                .arg(&out)
                .arg(format!("--jobs={jobs}"))
                .arg("-q")
                .assert()
                .code(0);
        };
        batch(&first);
        let mut old = Vec::new();
        for (name, _) in &objs {
            let o = out.join(format!("{}.svpk", stem(name)));
            old.push(std::fs::read(&o).unwrap());
            std::fs::hard_link(&o, links.join(stem(name))).unwrap();
        }
        batch(&second);
        for ((name, _), old) in objs.iter().zip(&old) {
            let fresh = tmp.path().join("fresh.svpk");
            let _ = std::fs::remove_file(&fresh);
            svpack()
                .arg("build")
                .arg(second.join(name))
                .arg("-o")
                .arg(&fresh)
                .arg("-q")
                .assert()
                .code(0);
            let now = std::fs::read(out.join(format!("{}.svpk", stem(name)))).unwrap();
            assert!(now == std::fs::read(&fresh).unwrap(), "{name}: new bytes");
            assert!(now != *old, "{name}: the inputs differ");
            assert!(
                std::fs::read(links.join(stem(name))).unwrap() == *old,
                "{name}: old file kept by its link"
            );
        }
        let mut names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        let mut want: Vec<String> = objs
            .iter()
            .map(|(n, _)| format!("{}.svpk", stem(n)))
            .collect();
        want.sort();
        assert_eq!(names, want, "--jobs={jobs}: no temp file left");
    }
}
