//! Side records written ahead (`layout::write_sides_ahead`): with two
//! threads or more, a build of a mesh whose every edge is on an even number
//! of triangles copies each finished block of side records into the file
//! while the rest of the edges are made, at the offset it has if the first
//! bucket is bucket 2. The finishing writer keeps the blocks that went
//! where the file puts them and writes the others again. Whatever the
//! guess, the bytes must be those of a one-thread build, which writes no
//! side block ahead (only the caps, from the soup).

use std::path::Path;
use svpack::build::{BuildConfig, build_file};
use svpack::format;
use svpack::format::Encoding;

mod common;
use common::torus;

/// Builds `input` to `out` in a pool of `threads` threads; the summary.
fn build(
    input: &Path,
    out: &Path,
    threads: usize,
    cfg: &BuildConfig,
) -> svpack::build::BuildOutput {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(|| build_file(input, out, cfg).unwrap())
}

/// Builds `input` in `dir` with one thread, then with two and three,
/// asserting the same bytes each time; the one-thread build's summary.
fn same_bytes_with_more_threads(
    dir: &Path,
    input: &Path,
    cfg: &BuildConfig,
    what: &str,
) -> svpack::build::BuildOutput {
    let one = dir.join("one.svpk");
    let summary = build(input, &one, 1, cfg);
    let want = std::fs::read(&one).unwrap();
    for threads in [2, 3] {
        let out = dir.join(format!("t{threads}.svpk"));
        build(input, &out, threads, cfg);
        let got = std::fs::read(&out).unwrap();
        assert!(
            got == want,
            "{what}, {threads} threads: the bytes differ from one thread's"
        );
    }
    summary
}

/// Caught: every piece written ahead kept, whether or not it went where
/// the file puts it (the fan-6 torus's two-thread file differed from the
/// one-thread one: its first bucket is bucket 1, so every side block
/// written ahead was at the wrong offset); and those pieces left in the
/// file instead of cut off (its unorm16 file differed: stale bytes stayed
/// in the zero gaps between sections).
#[test]
fn side_blocks_written_ahead_give_the_one_thread_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let n = 185;
    assert!(2 * n * n >= format::ROOM_MIN_TRIANGLES as usize);
    // (pages, where, buckets expected): the plain torus, whose blocks all
    // go ahead; an edge of 4 opposite vertices in the middle (bucket 4: the
    // blocks before it stay, the ones after it are written again); and one
    // of 6 near the end and near the start (K = 5: a record in bucket 5 and
    // one in bucket 1, so bucket 2 is not the first and nothing written
    // ahead stays).
    for (pages, at, buckets) in [
        (0, 0.5, vec![2]),
        (1, 0.5, vec![2, 4]),
        (2, 0.97, vec![1, 2, 5]),
        (2, 0.02, vec![1, 2, 5]),
    ] {
        let input = torus(tmp.path(), n, pages, at);
        for positions in [Encoding::F32, Encoding::Unorm16] {
            let cfg = BuildConfig {
                positions,
                ..BuildConfig::default()
            };
            let what = format!("{pages} pages at {at}, {positions:?}");
            let summary = same_bytes_with_more_threads(tmp.path(), &input, &cfg, &what);
            let ks: Vec<u32> = summary.header.meshes[0]
                .buckets
                .iter()
                .map(|b| b.k)
                .collect();
            assert_eq!(ks, buckets, "{what}: buckets");
        }
    }
}

/// A mesh with open edges is not fed (its emit runs as one group per
/// thread), and with two threads or more its caps are copied by both
/// threads at once (`format::AheadFile::write_shared`) before the edges
/// are made: the bytes must still be a one-thread build's. Caught: the
/// units the topology's thread took written as if they were the first
/// ones (over the other thread's), and the further emit groups' edges
/// appended in the wrong order.
#[test]
fn an_open_mesh_built_by_several_threads_gives_the_one_thread_bytes() {
    let tmp = tempfile::tempdir().unwrap();
    let n = 185;
    let closed = std::fs::read_to_string(torus(tmp.path(), n, 0, 0.5)).unwrap();
    // Every 997th face left out: holes all over the mesh.
    let mut faces = 0;
    let open: String = closed
        .lines()
        .filter(|l| {
            let face = l.starts_with("f ");
            faces += face as usize;
            !face || faces % 997 != 0
        })
        .map(|l| format!("{l}\n"))
        .collect();
    let input = tmp.path().join("open.obj");
    std::fs::write(&input, open).unwrap();
    for positions in [Encoding::F32, Encoding::Unorm16] {
        let cfg = BuildConfig {
            positions,
            ..BuildConfig::default()
        };
        let what = format!("{positions:?}");
        let summary = same_bytes_with_more_threads(tmp.path(), &input, &cfg, &what);
        assert_eq!(
            summary.header.meshes[0].buckets[0].k, 1,
            "{what}: open edges (bucket 1)"
        );
    }
}
