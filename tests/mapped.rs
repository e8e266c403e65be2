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
