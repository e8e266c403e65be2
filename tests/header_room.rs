//! Header room (format 2.1, `format::header_room`): a one-mesh file of at
//! least `ROOM_MIN_TRIANGLES` triangles pads its header to a length its
//! edges do not change, so that a build writes the caps before the edges
//! are made (`format::AheadFile`; with two threads beside the edges, with
//! one from the soup). A mesh with more
//! distinct opposite counts than the room holds is written without room,
//! and the caps written early are written again. Either way the bytes must
//! not depend on the thread count, and readers must check the room.

mod common;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use svpack::build::{BuildConfig, build_file};
use svpack::format;

/// An `n` × `n` grid (2 n² triangles) with `books` books on row 1: book b
/// has b + 1 pages on the bottom edge of cell b, so that edge has b + 3
/// opposite vertices. Distinct opposite counts: 1 (border and page edges),
/// 2 (the grid) and 3 ..= books + 2.
fn book_grid(dir: &Path, n: usize, books: usize) -> PathBuf {
    assert!(books < n);
    let mut s = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let _ = writeln!(s, "v {i} {j} {}", ((i * 7 + j * 3) % 5) as f32 * 0.1);
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    for j in 0..n {
        for i in 0..n {
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j), id(i + 1, j + 1));
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j + 1), id(i, j + 1));
        }
    }
    let mut apex = (n + 1) * (n + 1);
    for b in 0..books {
        for p in 0..=b {
            apex += 1;
            let _ = writeln!(s, "v {} 1.25 {}", b as f32 + 0.5, 1 + p);
            let _ = writeln!(s, "f {} {} {apex}", id(b, 1), id(b + 1, 1));
        }
    }
    let path = dir.join(format!("books{books}.obj"));
    std::fs::write(&path, s).unwrap();
    path
}

/// Builds `input` to `out` in a pool of `threads` threads.
fn build(input: &Path, out: &Path, threads: usize, cfg: &BuildConfig) {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| build_file(input, out, cfg).unwrap());
}

fn header_len(bytes: &[u8]) -> usize {
    u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize
}

/// Rewrites the header CRC after a test changed header bytes.
fn fix_header_crc(bytes: &mut [u8]) {
    let end = format::PREAMBLE_LEN + header_len(bytes);
    let crc = crc32fast::hash(&bytes[format::PREAMBLE_LEN..end]);
    bytes[16..20].copy_from_slice(&crc.to_le_bytes());
}

/// Caught: the writer without `reserve_room` (no room on the 22-count
/// mesh), and the early caps kept although the header outgrew its room (the
/// 72-count mesh's two-thread file then differs from the one-thread file).
#[test]
fn large_files_keep_room_and_are_the_same_bytes_on_any_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    let n = 185;
    assert!(2 * n * n >= format::ROOM_MIN_TRIANGLES as usize);
    for (books, room) in [(20, true), (format::ROOM_HISTOGRAM_ENTRIES + 6, false)] {
        let input = book_grid(tmp.path(), n, books);
        for cfg in [
            BuildConfig::default(),
            BuildConfig {
                positions: format::Encoding::Unorm16,
                ..BuildConfig::default()
            },
        ] {
            let what = format!("{books} books, {:?}", cfg.positions);
            let files: Vec<Vec<u8>> = [1, 2, 3]
                .iter()
                .map(|&t| {
                    let out = tmp.path().join(format!("t{t}.svpk"));
                    build(&input, &out, t, &cfg);
                    std::fs::read(&out).unwrap()
                })
                .collect();
            assert!(files[0] == files[1], "{what}: 1 and 2 threads differ");
            assert!(files[0] == files[2], "{what}: 1 and 3 threads differ");
            // A compressed file is written in one go, nothing ahead: its
            // container's payload is the reference for the pieces the other
            // files wrote ahead and kept, or moved where the header outgrew
            // its room.
            let zout = tmp.path().join("z.svpk");
            build(
                &input,
                &zout,
                1,
                &BuildConfig {
                    compress: Some(format::ZSTD_LEVEL),
                    ..cfg
                },
            );
            let z = format::read_file(&zout).unwrap();
            let plain = format::read_file(&tmp.path().join("t1.svpk")).unwrap();
            assert!(z.compressed && !plain.compressed);
            assert_eq!(
                z.header.payload_offset, plain.header.payload_offset,
                "{what}"
            );
            let at = plain.header.payload_offset as usize;
            assert!(
                z.bytes[at..] == plain.bytes[at..],
                "{what}: the payload differs from the compressed file's"
            );
            let f = format::read_file(&tmp.path().join("t2.svpk")).unwrap();
            assert_eq!(f.version_minor, 1);
            let stats = &f.header.meshes[0].stats;
            assert_eq!(stats.histogram.len(), books + 2, "{what}");
            let want = format::header_room(&f.header)
                .unwrap()
                .expect("large enough");
            if room {
                assert!(f.header.reserved > 0, "{what}: no room");
                assert_eq!(header_len(&files[0]), want, "{what}");
            } else {
                assert_eq!(f.header.reserved, 0, "{what}: room kept");
                assert!(header_len(&files[0]) > want, "{what}");
            }
        }
    }
    // Below the threshold: no room.
    let small = book_grid(tmp.path(), 20, 3);
    let out = tmp.path().join("small.svpk");
    build(&small, &out, 2, &BuildConfig::default());
    assert_eq!(format::read_file(&out).unwrap().header.reserved, 0);
}

/// A 2.1 reader checks the room (zeros, a count that fits) and still reads
/// 2.0 files, which have no room field.
#[test]
fn readers_check_the_room_and_read_2_0_files() {
    let tmp = tempfile::tempdir().unwrap();
    let input = book_grid(tmp.path(), 185, 4);
    let out = tmp.path().join("room.svpk");
    build(&input, &out, 2, &BuildConfig::default());
    let good = std::fs::read(&out).unwrap();
    let h = header_len(&good);
    let reserved = format::read_file(&out).unwrap().header.reserved as usize;
    assert!(reserved > 0);
    // `inspect` reports the room.
    let run = common::svpack()
        .args(["inspect", "--json"])
        .arg(&out)
        .output()
        .unwrap();
    let j: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(j["header_room_bytes"], reserved as u64);
    assert_eq!(
        j["header_bytes"],
        format::align_up((format::PREAMBLE_LEN + h) as u64)
    );
    let bad = tmp.path().join("bad.svpk");
    let read = |bytes: &[u8]| {
        std::fs::write(&bad, bytes).unwrap();
        format::read_file(&bad).map(|_| ())
    };
    assert!(read(&good).is_ok());

    // A nonzero byte in the room.
    let mut b = good.clone();
    b[format::PREAMBLE_LEN + h - 1] = 1;
    fix_header_crc(&mut b);
    let err = read(&b).unwrap_err().to_string();
    assert!(err.contains("reserved room is not zero"), "{err}");

    // A count past the header's end.
    let mut b = good.clone();
    let count_at = format::PREAMBLE_LEN + h - reserved - 8;
    b[count_at..count_at + 8].copy_from_slice(&(reserved as u64 + 1).to_le_bytes());
    fix_header_crc(&mut b);
    let err = read(&b).unwrap_err().to_string();
    assert!(err.contains("reserved bytes, only"), "{err}");
    b[count_at..count_at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
    fix_header_crc(&mut b);
    let err = read(&b).unwrap_err().to_string();
    assert!(err.contains("reserved bytes, only"), "{err}");

    // A file as 2.0 wrote it: no count, no room. Dropping the count moves
    // the payload unless the header's end stays in the same 16-byte row:
    // a small mesh whose header ends in such a row (the histogram's length
    // moves the end by 12 bytes per book) keeps every offset as it is.
    let (v21, h) = (1..=8)
        .find_map(|books| {
            let small = book_grid(tmp.path(), 12, books);
            let out = tmp.path().join("small.svpk");
            build(&small, &out, 1, &BuildConfig::default());
            let v21 = std::fs::read(&out).unwrap();
            let h = header_len(&v21);
            let end = (format::PREAMBLE_LEN + h) as u64;
            (format::align_up(end - 8) == format::align_up(end)).then_some((v21, h))
        })
        .expect("a header ending in the second half of a row");
    let f = format::read_file(&tmp.path().join("small.svpk")).unwrap();
    assert_eq!(f.header.reserved, 0);
    // The count (0) becomes part of the zero padding before the payload.
    let mut v20 = v21.clone();
    v20[10..12].copy_from_slice(&0u16.to_le_bytes());
    v20[12..16].copy_from_slice(&((h - 8) as u32).to_le_bytes());
    fix_header_crc(&mut v20);
    std::fs::write(&bad, &v20).unwrap();
    let old = format::read_file(&bad).unwrap();
    assert_eq!(old.version_minor, 0);
    assert_eq!(old.header.reserved, 0);
    assert_eq!(old.header.meshes[0].stats, f.header.meshes[0].stats);
    // Its zstd frame (`inspect`'s size) is the same 2.0 file with the
    // header's `--compress` record set, not a re-encoding as 2.1.
    let frame = format::compressed_frame(&old, 3).unwrap();
    assert_eq!(format::zstd_size(&old, 3), frame.len() as u64);
    let inner = zstd::decode_all(&frame[..]).unwrap();
    assert_eq!(inner.len(), v20.len());
    let back = format::decode(&bad, inner.clone()).unwrap();
    assert_eq!(back.version_minor, 0);
    assert!(back.header.options.compress);
    let differ = (0..v20.len()).filter(|&i| inner[i] != v20[i]).count();
    assert!((1..=5).contains(&differ), "{differ} bytes differ");
    // And a 2.0 file with a room field is one with trailing bytes.
    let mut b = v21.clone();
    b[10..12].copy_from_slice(&0u16.to_le_bytes());
    let err = read(&b).unwrap_err().to_string();
    assert!(err.contains("trailing bytes"), "{err}");
}
