//! Uncompressed builds fill the file block by block at precomputed offsets
//! (`format::write_file_streamed`); compressed builds write whole in-memory
//! buffers in order (`format::write_file`). Both must carry the same payload
//! bytes and the same header apart from the compression flag, whatever the
//! thread count, K or position encoding.

mod common;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use svpack::build::{BuildConfig, build_file};
use svpack::format::{self, Encoding};
use svpack::layout::BLOCK;

/// A grid with fins on every 5th cell and fans of 1–17 extra triangles on
/// every 97th edge: several side and caps blocks, every bucket of every K.
fn fan_grid(dir: &Path) -> PathBuf {
    let n = 150;
    let mut s = String::new();
    for j in 0..=n {
        for i in 0..=n {
            let _ = writeln!(s, "v {} {} {}", i, j, ((i * 3 + j * 5) % 7) as f32 * 0.1);
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    let mut apex = (n + 1) * (n + 1);
    let mut cell = 0;
    for j in 0..n {
        for i in 0..n {
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j), id(i + 1, j + 1));
            let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j + 1), id(i, j + 1));
            cell += 1;
            let fins = if cell % 97 == 0 {
                1 + cell / 97 % 17
            } else {
                usize::from(cell % 5 == 0)
            };
            for f in 0..fins {
                apex += 1;
                let _ = writeln!(s, "v {} {} {}", i as f32 + 0.5, j as f32 - 0.25, 1 + f);
                let _ = writeln!(s, "f {} {} {}", id(i, j), id(i + 1, j), apex);
            }
        }
    }
    let faces = s.lines().filter(|l| l.starts_with("f ")).count();
    assert!(
        faces > BLOCK,
        "more than one caps block ({faces} triangles)"
    );
    let p = dir.join("fan_grid.obj");
    std::fs::write(&p, s).unwrap();
    p
}

/// A grid of at least `format::ROOM_MIN_TRIANGLES` triangles (so a file
/// with header room, whose one-thread build writes the caps from the soup,
/// `layout::SoupCaps`) with what the weld changes: coordinates of `-0`
/// and `0` (one welded position, written `+0.0`), a copy of every 7th
/// vertex that some triangles use instead, and degenerate triangles (a
/// corner repeated, or a vertex and its copy) in runs at the start, at
/// the end, just before kept triangle `BLOCK - 2` (caps unit 1 starts
/// two kept triangles after it), just after unit 1's first (before kept
/// triangle `BLOCK + 1`) and just before kept triangle `2 * BLOCK` (the
/// first of unit 2), `layout::BLOCK` triangles to a unit.
fn degenerate_grid(dir: &Path) -> PathBuf {
    let n = 190;
    let mut s = String::new();
    let z = |i: usize, j: usize| match (i + j) % 5 {
        0 => "-0".to_string(),
        1 => "0".to_string(),
        r => format!("{}", r as f32 * 0.25),
    };
    for j in 0..=n {
        for i in 0..=n {
            let x = if i == n / 2 {
                "-0".to_string()
            } else {
                format!("{}", i as i64 - (n / 2) as i64)
            };
            let _ = writeln!(s, "v {x} {j} {}", z(i, j));
        }
    }
    let id = |i: usize, j: usize| j * (n + 1) + i + 1;
    // Copies of every 7th vertex, with the other zero's sign.
    let mut copy = std::collections::HashMap::new();
    let mut next = (n + 1) * (n + 1);
    for j in 0..=n {
        for i in 0..=n {
            if id(i, j) % 7 == 0 {
                next += 1;
                let x = if i == n / 2 {
                    "0".to_string()
                } else {
                    format!("{}", i as i64 - (n / 2) as i64)
                };
                let z = match z(i, j).as_str() {
                    "-0" => "0".to_string(),
                    "0" => "-0".to_string(),
                    v => v.to_string(),
                };
                let _ = writeln!(s, "v {x} {j} {z}");
                copy.insert(id(i, j), next);
            }
        }
    }
    let alt = |v: usize, t: usize| {
        if t.is_multiple_of(2) {
            *copy.get(&v).unwrap_or(&v)
        } else {
            v
        }
    };
    let mut kept = 0;
    let degenerate = |s: &mut String, count: usize| {
        for d in 0..count {
            let v = id(d % n, 3);
            let w = *copy.get(&v).unwrap_or(&v);
            let _ = writeln!(s, "f {v} {w} {}", id(d % n + 1, 4));
            let _ = writeln!(s, "f {v} {} {v}", id(d % n, 5));
        }
    };
    degenerate(&mut s, 3);
    for j in 0..n {
        for i in 0..n {
            for t in [
                [id(i, j), id(i + 1, j), id(i + 1, j + 1)],
                [id(i, j), id(i + 1, j + 1), id(i, j + 1)],
            ] {
                if kept == BLOCK - 2 || kept == BLOCK + 1 || kept == 2 * BLOCK {
                    degenerate(&mut s, 10);
                }
                let _ = writeln!(s, "f {} {} {}", alt(t[0], kept), t[1], alt(t[2], kept / 3));
                kept += 1;
            }
        }
    }
    degenerate(&mut s, 2);
    assert!(kept >= format::ROOM_MIN_TRIANGLES as usize);
    assert!(kept > 2 * BLOCK, "the grid reaches caps unit 2");
    let p = dir.join("degenerate_grid.obj");
    std::fs::write(&p, s).unwrap();
    p
}

/// Builds `input` both ways in a pool of `threads` threads and compares.
fn check(input: &Path, dir: &Path, cfg: BuildConfig, threads: usize) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    let streamed = dir.join("streamed.svpk");
    let whole = dir.join("whole.svpk");
    pool.install(|| {
        build_file(input, &streamed, &cfg).unwrap();
        build_file(
            input,
            &whole,
            &BuildConfig {
                compress: Some(svpack::format::ZSTD_LEVEL),
                ..cfg
            },
        )
        .unwrap();
    });
    // read_file checks both CRCs and every section's placement.
    let s = format::read_file(&streamed).unwrap();
    let w = format::read_file(&whole).unwrap();
    assert!(!s.compressed && w.compressed);
    let what = format!("{} with {cfg:?}, {threads} threads", input.display());
    let mut wh = w.header.clone();
    wh.options.compress = false;
    assert_eq!(s.header, wh, "{what}: headers differ");
    let from = s.header.payload_offset as usize;
    assert_eq!(s.bytes.len(), w.bytes.len(), "{what}: lengths differ");
    assert!(
        s.bytes[from..] == w.bytes[from..],
        "{what}: payloads differ"
    );
}

#[test]
fn streamed_files_equal_whole_buffer_files() {
    let tmp = tempfile::tempdir().unwrap();
    let mut inputs: Vec<PathBuf> = common::write_fixtures(tmp.path())
        .into_iter()
        .map(|(_, p)| p)
        .collect();
    inputs.push(fan_grid(tmp.path()));
    for input in &inputs {
        for positions in [Encoding::F32, Encoding::Unorm16] {
            for max_mult in [1, 2, 5, 13] {
                for threads in [1, 3] {
                    let cfg = BuildConfig {
                        max_mult,
                        compress: None,
                        positions,
                    };
                    check(input, tmp.path(), cfg, threads);
                }
            }
        }
    }
}

/// The one-thread build of a file with header room takes its caps from
/// the soup (`layout::SoupCaps`), the compressed one from the welded mesh.
/// Caught: the soup's `-0.0` written as it is (no `+ 0.0`), the dropped
/// triangles not skipped, and a unit counting the dropped triangles after
/// its first kept one as before it (the caps' bytes differed each time).
#[test]
fn caps_from_the_soup_are_the_welded_caps() {
    let tmp = tempfile::tempdir().unwrap();
    let input = degenerate_grid(tmp.path());
    for positions in [Encoding::F32, Encoding::Unorm16] {
        let cfg = BuildConfig {
            positions,
            ..BuildConfig::default()
        };
        check(&input, tmp.path(), cfg, 1);
    }
    let f = format::read_file(&tmp.path().join("streamed.svpk")).unwrap();
    assert!(
        f.header.reserved > 0,
        "no header room: the soup's caps not used"
    );
    assert_eq!(
        f.header.meshes[0].stats.degenerate_triangles,
        2 * (3 + 10 + 10 + 10 + 2)
    );
}

#[test]
fn streamed_files_equal_whole_buffer_files_on_shared_models() {
    let Some(shared) = common::shared_meshes() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    for input in common::shared_models(&shared).iter().take(6) {
        for positions in [Encoding::F32, Encoding::Unorm16] {
            let cfg = BuildConfig {
                positions,
                ..BuildConfig::default()
            };
            check(input, tmp.path(), cfg, 2);
        }
    }
}
