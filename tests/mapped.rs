//! Large uncompressed files are mapped by `format::read_file`: what is read
//! through the mapping must be exactly what reading the file gives, and a
//! damaged large file must still be a clear error.

mod common;

use common::svpack;
use svpack::format::{self, FileBytes, MAP_MIN};
use svpack::verify::decode;

/// A bumpy grid of `2 n²` triangles, as OBJ text; the heights are
/// pseudo-random, so even the compressed output is over a MiB.
fn grid(n: usize) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let mut h = 0x2545_f491_4f6c_dd1du64;
    for j in 0..=n {
        for i in 0..=n {
            h ^= h << 13;
            h ^= h >> 7;
            h ^= h << 17;
            let z = (h >> 40) as f32 / (1u64 << 24) as f32;
            let _ = writeln!(s, "v {} {} {z}", i as f32 * 0.5, j as f32 * 0.25);
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j), id(i + 1, j + 1));
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j + 1), id(i, j + 1));
        }
    }
    s
}

/// Builds a grid of `2 n²` triangles into `dir` with extra build arguments;
/// returns the output.
fn built(dir: &std::path::Path, n: usize, name: &str, args: &[&str]) -> std::path::PathBuf {
    let src = dir.join(format!("grid{n}.obj"));
    if !src.exists() {
        std::fs::write(&src, grid(n)).unwrap();
    }
    let out = dir.join(name);
    svpack()
        .arg("build")
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .args(args)
        .assert()
        .code(0);
    out
}

#[test]
fn mapped_and_read_files_give_the_same_floats_and_decoding() {
    let tmp = tempfile::tempdir().unwrap();
    for (name, args) in [
        ("f32.svpk", &[][..]),
        ("unorm16.svpk", &["--positions", "unorm16"][..]),
    ] {
        let out = built(tmp.path(), 160, name, args);
        assert!(std::fs::metadata(&out).unwrap().len() >= MAP_MIN, "{name}");
        let mapped = format::read_file(&out).unwrap();
        assert!(matches!(mapped.bytes, FileBytes::Mapped(_)), "{name}");
        let read = format::decode(&out, std::fs::read(&out).unwrap()).unwrap();
        assert!(matches!(read.bytes, FileBytes::Read(_)));
        assert_eq!(mapped.header, read.header);
        assert!(*mapped.bytes == *read.bytes);
        let m = &mapped.header.meshes[0];
        let sections = std::iter::once((m.caps.offset, m.caps.length))
            .chain(m.buckets.iter().map(|b| (b.offset, b.length)));
        for (offset, length) in sections {
            let (a, b) = (mapped.floats(offset, length), read.floats(offset, length));
            assert!(!a.is_empty());
            // Bit for bit (NaN-safe), without printing megabytes on failure.
            let bits = |f: &[f32]| f.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert!(bits(&a) == bits(&b), "{name}: section at {offset}");
        }
        let (da, db) = (decode(&mapped, 0), decode(&read, 0));
        assert!(da.positions == db.positions && da.caps == db.caps, "{name}");
        for (x, y) in da.buckets.iter().zip(&db.buckets) {
            assert!(x.ids == y.ids && x.slot_tri == y.slot_tri, "{name}");
            assert!(x.slot_parity == y.slot_parity, "{name}");
        }
        svpack().arg("verify").arg(&out).assert().code(0);
    }
}

#[test]
fn large_compressed_files_are_read_and_damaged_large_files_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let plain = built(tmp.path(), 160, "plain.svpk", &[]);
    let packed = built(tmp.path(), 400, "packed.svpk", &["--compress"]);
    // A compressed file is decompressed into memory, whatever its size.
    let packed_len = std::fs::metadata(&packed).unwrap().len();
    assert!(packed_len >= MAP_MIN, "{packed_len}");
    let z = format::read_file(&packed).unwrap();
    assert!(z.compressed && matches!(z.bytes, FileBytes::Read(_)));

    let len = std::fs::metadata(&plain).unwrap().len();
    let bytes = std::fs::read(&plain).unwrap();
    // Truncated, and one payload byte flipped: clear errors naming the file.
    let cut = tmp.path().join("cut.svpk");
    std::fs::write(&cut, &bytes[..(len as usize) * 2 / 3]).unwrap();
    let flipped = tmp.path().join("flipped.svpk");
    let mut f = bytes.clone();
    let at = f.len() - 100;
    f[at] ^= 0x10;
    std::fs::write(&flipped, &f).unwrap();
    for (path, what) in [
        (&cut, "truncated file"),
        (&flipped, "payload checksum mismatch"),
    ] {
        assert!(std::fs::metadata(path).unwrap().len() >= MAP_MIN);
        let e = format::read_file(path).unwrap_err().to_string();
        assert!(e.contains("cut.svpk") || e.contains("flipped.svpk"), "{e}");
        assert!(e.contains(what), "{e}");
        svpack()
            .arg("verify")
            .arg(path)
            .assert()
            .code(1)
            .stderr(predicates::str::contains(what));
    }
}

/// A binary glTF of `soup` (f32 positions, u32 indices, one primitive), or
/// with `external` a `.gltf` whose buffer is the file `external` beside it.
fn gltf_of(soup: &svpack::load::Soup, external: Option<&str>) -> (Vec<u8>, Vec<u8>) {
    let pos: &[u8] = bytemuck::cast_slice(&soup.positions);
    let idx: &[u8] = bytemuck::cast_slice(&soup.indices);
    let bin = [pos, idx].concat();
    let mut buffer = serde_json::json!({ "byteLength": bin.len() });
    if let Some(uri) = external {
        buffer["uri"] = serde_json::json!(uri);
    }
    let doc = serde_json::json!({
        "asset": { "version": "2.0" },
        "buffers": [buffer],
        "bufferViews": [
            { "buffer": 0, "byteLength": pos.len() },
            { "buffer": 0, "byteOffset": pos.len(), "byteLength": idx.len() }
        ],
        "accessors": [
            { "bufferView": 0, "componentType": 5126, "count": soup.positions.len(),
              "type": "VEC3" },
            { "bufferView": 1, "componentType": 5125, "count": soup.indices.len(),
              "type": "SCALAR" }
        ],
        "meshes": [{ "primitives": [{ "attributes": { "POSITION": 0 }, "indices": 1 }] }],
        "nodes": [{ "mesh": 0 }],
        "scenes": [{ "nodes": [0] }],
        "scene": 0
    });
    let mut json = serde_json::to_vec(&doc).unwrap();
    if external.is_some() {
        return (json, bin);
    }
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut glb = Vec::new();
    let total = 12 + 8 + json.len() + 8 + bin.len();
    for w in [
        0x4654_6c67u32,
        2,
        total as u32,
        json.len() as u32,
        0x4e4f_534a,
    ] {
        glb.extend_from_slice(&w.to_le_bytes());
    }
    glb.extend_from_slice(&json);
    glb.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    glb.extend_from_slice(&0x004e_4942u32.to_le_bytes());
    glb.extend_from_slice(&bin);
    (glb, Vec::new())
}

/// Everything a loader returns, positions by their bits.
fn soup_summary(s: &svpack::load::Soup) -> impl PartialEq + std::fmt::Debug {
    (
        s.positions
            .iter()
            .flatten()
            .map(|v| v.to_bits())
            .collect::<Vec<_>>(),
        s.indices.clone(),
        s.parts.iter().map(|p| p.name.clone()).collect::<Vec<_>>(),
        (s.input_bytes, s.input_sha256, s.input_vertices),
        s.stats.warnings.clone(),
    )
}

#[test]
fn large_inputs_are_mapped_and_load_as_their_bytes_do() {
    use svpack::load::{self, gltf::load_gltf, obj::load_obj};
    let tmp = tempfile::tempdir().unwrap();
    let text = grid(200);
    // Plain text takes the streaming path; a Latin-1 comment sends the
    // parse to the path that rewrites a copy of the text.
    let plain = tmp.path().join("plain.obj");
    std::fs::write(&plain, &text).unwrap();
    let latin = tmp.path().join("latin.obj");
    std::fs::write(&latin, [&b"# caf\xe9\n"[..], text.as_bytes()].concat()).unwrap();
    let reference = load_obj(&plain, text.clone().into_bytes()).unwrap();
    let (glb, _) = gltf_of(&reference, None);
    let glb_path = tmp.path().join("grid.glb");
    std::fs::write(&glb_path, &glb).unwrap();
    let (json, bin) = gltf_of(&reference, Some("grid.bin"));
    let gltf_path = tmp.path().join("grid.gltf");
    std::fs::write(&gltf_path, &json).unwrap();
    std::fs::write(tmp.path().join("grid.bin"), &bin).unwrap();
    assert!(bin.len() as u64 >= MAP_MIN);

    for path in [&plain, &latin, &glb_path] {
        let bytes = load::read_file(path).unwrap();
        assert!(bytes.len() as u64 >= MAP_MIN);
        assert!(matches!(bytes, FileBytes::Mapped(_)), "{}", path.display());
        let read = std::fs::read(path).unwrap();
        let (mapped, from_read) = if path == &glb_path {
            (load::load(path).unwrap(), load_gltf(path, read).unwrap())
        } else {
            (load::load(path).unwrap(), load_obj(path, read).unwrap())
        };
        assert!(
            soup_summary(&mapped) == soup_summary(&from_read),
            "{}: mapped and read loads differ",
            path.display()
        );
        assert_eq!(mapped.triangle_count(), 2 * 200 * 200);
    }
    let latin_soup = load::load(&latin).unwrap();
    assert!(
        latin_soup
            .stats
            .warnings
            .iter()
            .any(|w| w.contains("UTF-8"))
    );
    // The same triangles from every container, and the glTF files' digests
    // cover the file and then its buffer.
    let from_glb = load::load(&glb_path).unwrap();
    let from_gltf = load::load(&gltf_path).unwrap();
    assert!(from_glb.positions == reference.positions && from_glb.indices == reference.indices);
    assert!(from_gltf.positions == reference.positions && from_gltf.indices == reference.indices);
    assert_eq!(from_gltf.input_bytes, (json.len() + bin.len()) as u64);
    assert_eq!(from_glb.input_bytes, glb.len() as u64);

    // A small file is read, not mapped.
    let small = tmp.path().join("small.obj");
    std::fs::write(&small, grid(2)).unwrap();
    assert!(matches!(
        load::read_file(&small).unwrap(),
        FileBytes::Read(_)
    ));
    // A missing external buffer is still an error naming it.
    std::fs::remove_file(tmp.path().join("grid.bin")).unwrap();
    let msg = load::load(&gltf_path).unwrap_err().to_string();
    assert!(
        msg.contains("grid.bin") && msg.contains("grid.gltf"),
        "{msg}"
    );
}
