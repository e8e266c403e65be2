//! Times single steps of a build or of `verify` that the whole-command
//! benchmarks (`benches/compare_binaries.py`, `benches/compare_verify.py`)
//! only see summed: the figures benches/ROUNDS.md's ninth round quotes for them.
//! Each step runs several times in one process and the fastest time is
//! printed; build it at two commits and alternate the binaries to compare.
//!
//! ```text
//! cargo run --release --example stage_probe -- read FILE     # read against map, first touch
//! cargo run --release --example stage_probe -- build MODEL   # weld, topology, plan, fills
//! cargo run --release --example stage_probe -- weld MODEL    # the weld and its steps, memory recycled, and std's sort of its words
//! cargo run --release --example stage_probe -- passes MODEL  # the topology's four passes, and fed; its listings per vertex
//! cargo run --release --example stage_probe -- buckets MODEL # weld + topology + bucket counts (the stages bench's `ours_buckets`), then meshoptimizer's adjacency, with their page faults
//! cargo run --release --example stage_probe -- floor MODEL   # `buckets` with fresh and with recycled memory, and the fresh pages of its output alone, alternated: the fresh-memory floor
//! cargo run --release --example stage_probe -- fill-write MODEL  # the writer's fills (caps from the welded mesh, with no position read, from the soup), with and without its writes, and its writes alone
//! cargo run --release --example stage_probe -- verify FILE.svpk  # orientation errors, 12 point lights
//! cargo run --release --example stage_probe -- evaluate MODEL  # the evaluator's caps and caps + sides, each kernel choice, alternated
//! cargo run --release --example stage_probe -- replace DIR   # putting a 120 MiB output in place
//! ```
//!
//! `build` and `verify` run on one thread (`RAYON_NUM_THREADS` overrides).
//! Only APIs older than the ninth round are used, so the same file builds
//! at earlier commits (copy it into a worktree) for the before figures; so
//! the weld timed is `weld::weld`, with the triangle sources the build
//! itself no longer makes. The exceptions, to delete for an earlier
//! commit: `passes` (`topology::build_edges_opposites_only_timed`, eleventh
//! round), `weld` (`weld::weld_without_sources` under an
//! `alloc::KeepFreed` guard, thirteenth round; its steps timed by
//! `weld::weld_without_sources_timed`, twenty-third round), `buckets`
//! (`weld::weld_without_sources` and `Plan::edge_stats`, fourteenth round;
//! its before figures came from this file built with the twenty-sixth
//! round's `src/alloc.rs`)
//! and `fill-write`
//! (`format::split_pieces`, fifteenth round; its before figures came from
//! this file built with the old prefetch distance instead; and
//! `layout::SoupCaps`, twenty-second round). Since the
//! seventeenth round `fill-write` reserves its file's blocks first, as the
//! writer does; its write times from earlier rounds were into a file
//! without them (slower by about 2 ms: `file_write` took 21.2–21.4 ms
//! for 128 MiB without, 18.9–19.5 ms with, twelfth round).
//!
//! Four environment variables, for every step: `RECYCLE=1` holds an
//! `alloc::KeepFreed` guard, so that each run reuses the blocks the one
//! before freed instead of faulting in fresh pages, whose cost on this
//! machine varies more than the code's; `NO_AVX512=1` turns the crate's
//! AVX-512 kernels off (`evaluate_simd::disable_avx512`), which times the
//! topology's AVX2 count and emit (the scalar ones without AVX2) on the
//! same binary; `SCALAR_TOPOLOGY=1` turns every topology kernel off
//! (`topology::scalar_topology`), which times its scalar passes;
//! `NO_THP=1` (Linux) turns transparent huge pages off for the process
//! (`PR_SET_THP_DISABLE`), so that every block is in 4 KiB pages, which
//! tells what the TLB's misses cost a step (fifty-second round, `RECYCLE=1 RAYON_NUM_THREADS=1 cargo
//! run --release --example stage_probe -- weld
//! target/targets/scene_5000000.obj` with and without it, three
//! alternations: the weld 66.7–68.2 ms in huge pages, 68.6–72.0 in small
//! ones).

use std::path::Path;
use std::time::Instant;

#[path = "../benches/common/peers.rs"]
#[allow(dead_code)] // (Only the weld's and the topology's peers are used here.)
mod peers;

#[global_allocator]
static ALLOC: svpack::alloc::HugePageAlloc = svpack::alloc::HugePageAlloc;

/// Fastest of `n` runs of `f`, in ms, and the last result.
fn fastest<T>(n: usize, mut f: impl FnMut() -> T) -> (f64, T) {
    let mut best = f64::MAX;
    let mut out = None;
    for _ in 0..n {
        let t = Instant::now();
        let r = f();
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
        out = Some(std::hint::black_box(r));
    }
    (best, out.unwrap())
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [what, file] = &args[..] else {
        eprintln!(
            "usage: stage_probe read|build|weld|passes|buckets|floor|fill-write|verify|evaluate|replace FILE"
        );
        std::process::exit(1);
    };
    let path = Path::new(file);
    let _keep = std::env::var_os("RECYCLE").map(|_| svpack::alloc::KeepFreed::new());
    if std::env::var_os("NO_AVX512").is_some() {
        svpack::evaluate_simd::disable_avx512(true);
    }
    if std::env::var_os("SCALAR_TOPOLOGY").is_some() {
        svpack::topology::scalar_topology(true);
    }
    #[cfg(target_os = "linux")]
    if std::env::var_os("NO_THP").is_some() {
        // SAFETY: a plain prctl on this process; no memory is touched.
        let r = unsafe { libc::prctl(libc::PR_SET_THP_DISABLE, 1, 0, 0, 0) };
        assert_eq!(r, 0, "prctl(PR_SET_THP_DISABLE) failed");
    }
    if std::env::var_os("RAYON_NUM_THREADS").is_none() {
        rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build_global()
            .unwrap();
    }
    match what.as_str() {
        "read" => read(path),
        "build" => build(path),
        "weld" => weld_recycled(path),
        "passes" => passes(path),
        "buckets" => buckets(path),
        "floor" => floor(path),
        "fill-write" => fill_write(path),
        "verify" => verify(path),
        "evaluate" => evaluate(path),
        "replace" => replace(path),
        _ => {
            eprintln!(
                "unknown step {what:?}: read, build, weld, passes, buckets, floor, fill-write, verify, evaluate or replace"
            );
            std::process::exit(1);
        }
    }
}

/// The weld as a build of a batch's later inputs runs it: 60 times under
/// an `alloc::KeepFreed` guard (whatever `RECYCLE` says), so that each run
/// gets the blocks the previous one freed (the thirteenth round's
/// uninitialised buffers skip the zeroing such a block otherwise gets).
fn weld_recycled(path: &Path) {
    let _keep = svpack::alloc::KeepFreed::new();
    let soup = svpack::load::load(path).unwrap();
    // Fastest of 60 for the whole weld and for each step (not all from one
    // run), then of 60 for the peer: the same vertices' sort words sorted
    // by the standard library alone (`sorted_vertex_words`). Not
    // alternated run by run: the peer's buffer then changed which blocks
    // the weld got back, and the weld took 19 ms instead of 16.
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    let mut best = [f64::MAX; 5];
    let mut kept = 0;
    for _ in 0..60 {
        let t = Instant::now();
        let (w, s) = svpack::weld::weld_without_sources_timed(&soup.positions, &soup.indices);
        let all = t.elapsed().as_secs_f64() * 1e3;
        kept = w.triangle_count();
        std::hint::black_box(w);
        for (b, d) in best.iter_mut().zip([
            all,
            ms(s.sort),
            ms(s.numbering),
            ms(s.triangles),
            ms(s.unused),
        ]) {
            *b = b.min(d);
        }
    }
    let (peer, _) = fastest(60, || peers::sorted_vertex_words(&soup.positions));
    println!(
        "{kept} triangles: weld {:.2} ms, memory recycled: sort {:.2}, numbering {:.2}, triangles {:.2}, unused {:.2} ms; the words sorted by sort_unstable alone {peer:.2} ms",
        best[0], best[1], best[2], best[3], best[4]
    );
}

/// Opening and reading a file into fresh memory, then mapping it as
/// `file_bytes::read_or_map` does (populated, read-only); once each, first
/// (the fresh memory is the point), then 5 more times each.
fn read(path: &Path) {
    let time = |f: &dyn Fn() -> usize| {
        let t = Instant::now();
        let n = f();
        (t.elapsed().as_secs_f64() * 1e3, n)
    };
    let by_read = || std::fs::read(path).unwrap().len();
    let by_map = || {
        let f = std::fs::File::open(path).unwrap();
        // SAFETY: the file is not modified while mapped (a probe).
        unsafe { memmap2::MmapOptions::new().populate().map(&f) }
            .unwrap()
            .len()
    };
    let (r, n) = time(&by_read);
    let (m, _) = time(&by_map);
    println!("{n} bytes, first time: read {r:.2} ms, mapped {m:.2} ms");
    let (r, _) = fastest(5, by_read);
    let (m, _) = fastest(5, by_map);
    println!("then fastest of 5: read {r:.2} ms, mapped {m:.2} ms");
}

/// The topology's four passes on the welded model (one thread unless
/// `RAYON_NUM_THREADS` says otherwise): the fastest time of each over 15
/// runs (not necessarily from the same run); then, alternated with the
/// plain topology in another 15 runs, the topology fed as a build with two
/// threads feeds it (`build_edges_opposites_only_fed`, with a consumer
/// that only reads how many records there are), whose count pass also
/// xors its edges' keys; then the listings per vertex (`listing_counts`).
fn passes(path: &Path) {
    let soup = svpack::load::load(path).unwrap();
    let w = svpack::weld::weld_without_sources(&soup.positions, &soup.indices);
    let mut best = [f64::MAX; 5];
    for _ in 0..15 {
        let t = Instant::now();
        let (e, p) =
            svpack::topology::build_edges_opposites_only_timed(&w.triangles, w.positions.len());
        let all = t.elapsed();
        std::hint::black_box(e);
        for (b, d) in best
            .iter_mut()
            .zip([all, p.count, p.list, p.emit, p.compact])
        {
            *b = b.min(d.as_secs_f64() * 1e3);
        }
    }
    println!(
        "{} triangles: topology {:.2} ms: count {:.2}, list {:.2}, emit {:.2}, compact {:.2} ms",
        w.triangle_count(),
        best[0],
        best[1],
        best[2],
        best[3],
        best[4]
    );
    let (mut fed, mut plain) = (f64::MAX, f64::MAX);
    for _ in 0..15 {
        let t = Instant::now();
        let e = svpack::topology::build_edges_opposites_only_fed(
            &w.triangles,
            w.positions.len(),
            &mut |feed: &svpack::topology::EmitFeed| {
                std::hint::black_box(feed.records());
            },
        );
        fed = fed.min(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(e);
        let t = Instant::now();
        let e = svpack::topology::build_edges_opposites_only(&w.triangles, w.positions.len());
        plain = plain.min(t.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(e);
    }
    println!("fed, as a build with two threads: topology {fed:.2} ms, against {plain:.2} ms plain");
    listing_counts(&w.triangles, w.positions.len());
}

/// What pass 3 of the topology meets per vertex: the histogram of its
/// listings (each triangle is listed under its smallest and middle
/// corner), how many vertices have more than the 8 slots
/// (`topology::SLOTS`), and how often the AVX-512 kernel's branch on at
/// most 4 listings changes between consecutive vertices.
fn listing_counts(triangles: &[u32], vertices: usize) {
    let mut listings = vec![0u32; vertices];
    for t in triangles.chunks_exact(3) {
        let mut c = [t[0], t[1], t[2]];
        c.sort_unstable();
        listings[c[0] as usize] += 1;
        listings[c[1] as usize] += 1;
    }
    let mut hist = [0usize; 10];
    for &l in &listings {
        hist[(l as usize).min(9)] += 1;
    }
    let flips = listings
        .windows(2)
        .filter(|p| (p[0] <= 4) != (p[1] <= 4))
        .count();
    let shown: Vec<String> = hist[..9]
        .iter()
        .enumerate()
        .map(|(l, n)| format!("{l}: {n}"))
        .collect();
    println!(
        "listings per vertex: {}, more than 8: {} vertices; the kernel's branch on at most 4 changes {flips} times in {vertices} vertices",
        shown.join(", "),
        hist[9]
    );
}

/// The evaluator on MODEL's build, one light, as the evaluate bench's
/// `caps/reference_indexed` and `caps+sides/reference_shared` run it, with
/// each choice of kernel: the crate's own (`auto`), the caps' AVX-512
/// kernel with gathers forced on and off, and every AVX-512 kernel off;
/// and the crate's kernels with the triangles in input order (`input
/// order`: the evaluator before `evaluate_ordered`, the bench's
/// `caps+sides/reference_shared_input_order`). The choices take turns, 40
/// rounds of 5 runs each, so that all see the same phases of this machine
/// (criterion runs one after the other); prints the fastest and the median
/// round per run, in ms, and each choice's caps + sides as a multiple of
/// `auto`'s. Then, in the same rounds, four lights at once
/// (`evaluate_many_into`, and its caps alone, `cap_signs_many`) against the
/// same four one at a time, per light. Last, `auto`'s one light by step
/// (`evaluate_ordered`'s three): the caps kernel (its `caps` figure), the
/// same with the signs paired and read back into input order
/// (`OrderedEvaluation::cap_signs`; those two steps as the difference of
/// the fastest, and of the medians), and the sides' sums
/// (`OrderedEvaluation::sides`).
fn evaluate(path: &Path) {
    use svpack::evaluate_simd::{disable_avx512, prefer_gather_caps};
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("e.svpk");
    svpack::build::build_file(path, &out, &svpack::build::BuildConfig::default()).unwrap();
    let file = svpack::format::read_file(&out).unwrap();
    let d = svpack::verify::decode(&file, 0);
    let Some(ix) = d.ordered.as_ref().map(|o| o.caps()) else {
        eprintln!(
            "{}: its file has no caps from corner ids (`verify::decode`)",
            path.display()
        );
        std::process::exit(1);
    };
    let light = [3.0, 2.5, 4.0, 1.0];
    let records: usize = d.buckets.iter().map(|b| b.records()).sum();
    // (name, AVX-512 off, caps' gathers, triangles in input order)
    let choices: [(&str, bool, Option<bool>, bool); 5] = [
        ("auto", false, None, false),
        ("gathers", false, Some(true), false),
        ("no gathers", false, Some(false), false),
        ("no AVX-512", true, None, false),
        ("input order", false, None, true),
    ];
    let in_input_order = svpack::evaluate_indexed::IndexedCaps::new(&d.positions, &d.caps)
        .expect("the table that `decode` accepted");
    let mut times = vec![(Vec::new(), Vec::new()); choices.len()];
    // The crate's kernels on four lights at once (`evaluate_many_into`),
    // against the same four one at a time into one reused evaluation (as
    // `verify` runs its lights); per light.
    let four = [
        light,
        [-3.0, 1.5, 2.0, 1.0],
        [0.3, -1.0, 0.2, 0.0],
        [1.0, 9.0, -4.0, 1.0],
    ];
    let mut evs = vec![svpack::verify::Evaluation::default(); four.len()];
    let mut one_by_one = svpack::verify::Evaluation::default();
    let (mut grouped, mut alone) = (Vec::new(), Vec::new());
    let (mut caps_grouped, mut caps_alone) = (Vec::new(), Vec::new());
    let mut caps4 = vec![vec![0i8; ix.len()]; four.len()];
    let mut signs = vec![0i8; ix.len()];
    let mut ev = svpack::verify::Evaluation::default();
    let mut sides: Vec<Vec<i8>> = d.buckets.iter().map(|b| vec![0; b.records()]).collect();
    let ordered = d.ordered.as_ref().expect("checked above");
    let (mut paired, mut summed) = (Vec::new(), Vec::new());
    let mut scratch = Vec::new();
    let mut in_input_order_signs = vec![0i8; ix.len()];
    let mut sides_of_steps = sides.clone();
    let per_run = |t: Instant| t.elapsed().as_secs_f64() * 1e3 / 5.0;
    let strategy = svpack::evaluate::Strategy::Reference;
    for _ in 0..40 {
        for (&(_, off, gathers, input), (caps, both)) in choices.iter().zip(&mut times) {
            disable_avx512(off);
            prefer_gather_caps(gathers);
            let ix = if input { &in_input_order } else { ix };
            let t = Instant::now();
            for _ in 0..5 {
                ix.cap_signs(light, &mut signs);
            }
            caps.push(per_run(t));
            let t = Instant::now();
            for _ in 0..5 {
                if !input {
                    svpack::verify::evaluate_into(&d, light, strategy, &mut ev);
                    continue;
                }
                ix.cap_signs(light, &mut signs);
                for (b, m) in d.buckets.iter().zip(&mut sides) {
                    svpack::evaluate::side_multiplicities_shared(
                        strategy,
                        b.k,
                        &b.data,
                        &b.slot_tri,
                        &b.slot_parity,
                        &signs,
                        light,
                        m,
                    );
                }
            }
            both.push(per_run(t));
        }
        let t = Instant::now();
        for _ in 0..5 {
            let mut out: Vec<&mut [i8]> = caps4.iter_mut().map(|c| &mut c[..]).collect();
            ix.cap_signs_many(&four, &mut out);
        }
        caps_grouped.push(per_run(t) / four.len() as f64);
        let t = Instant::now();
        for _ in 0..5 {
            for (&l, c) in four.iter().zip(&mut caps4) {
                ix.cap_signs(l, c);
            }
        }
        caps_alone.push(per_run(t) / four.len() as f64);
        let t = Instant::now();
        for _ in 0..5 {
            svpack::verify::evaluate_many_into(&d, &four, strategy, &mut evs);
        }
        grouped.push(per_run(t) / four.len() as f64);
        let t = Instant::now();
        for _ in 0..5 {
            for &l in &four {
                svpack::verify::evaluate_into(&d, l, strategy, &mut one_by_one);
            }
        }
        alone.push(per_run(t) / four.len() as f64);
        // `auto`'s one light, step by step.
        disable_avx512(false);
        prefer_gather_caps(None);
        let t = Instant::now();
        for _ in 0..5 {
            ordered.cap_signs(light, &mut scratch, &mut in_input_order_signs);
        }
        paired.push(per_run(t));
        let t = Instant::now();
        for _ in 0..5 {
            for (b, m) in sides_of_steps.iter_mut().enumerate() {
                ordered.sides(b, &scratch, m);
            }
        }
        summed.push(per_run(t));
    }
    for (&l, ev) in four.iter().zip(&evs) {
        svpack::verify::evaluate_into(&d, l, strategy, &mut one_by_one);
        assert!(
            ev.caps == one_by_one.caps && ev.sides == one_by_one.sides,
            "four lights at once differ from one at a time"
        );
    }
    assert!(
        signs == ev.caps && sides == ev.sides,
        "the input-order path differs"
    );
    // (The sides' step leaves the records of `leftovers` to its caller.)
    assert!(
        in_input_order_signs == ev.caps,
        "the steps' caps differ from the whole's"
    );
    prefer_gather_caps(None);
    disable_avx512(false);
    let fastest_median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[0], v[v.len() / 2])
    };
    println!("{} triangles, {records} side records", ix.len());
    let auto = fastest_median(&mut times[0].1.clone());
    for ((name, ..), (caps, both)) in choices.iter().zip(&mut times) {
        let (cf, cm) = fastest_median(caps);
        let (bf, bm) = fastest_median(both);
        println!(
            "{name}: caps {cf:.3} / {cm:.3} ms, caps + sides {bf:.3} / {bm:.3} ms ({:.2} / {:.2} ns per side record; {:.2} / {:.2} × auto's)",
            bf * 1e6 / records as f64,
            bm * 1e6 / records as f64,
            bf / auto.0,
            bm / auto.1
        );
    }
    let (cgf, cgm) = fastest_median(&mut caps_grouped);
    let (caf, cam) = fastest_median(&mut caps_alone);
    println!(
        "four lights, caps alone: at once {cgf:.3} / {cgm:.3} ms per light, one at a time {caf:.3} / {cam:.3} ms"
    );
    let (kf, km) = fastest_median(&mut times[0].0);
    let (pf, pm) = fastest_median(&mut paired);
    let (sf, sm) = fastest_median(&mut summed);
    println!(
        "auto, one light by step: the caps kernel {kf:.3} / {km:.3} ms; with the signs paired and read back into input order {pf:.3} / {pm:.3} ms (those two steps {:.3} / {:.3}); the sides' sums {sf:.3} / {sm:.3} ms",
        pf - kf,
        pm - km
    );
    let (gf, gm) = fastest_median(&mut grouped);
    let (af, am) = fastest_median(&mut alone);
    let ns = |ms: f64| ms * 1e6 / records as f64;
    println!(
        "four lights: at once {gf:.3} / {gm:.3} ms per light ({:.2} / {:.2} ns per side record), one at a time {af:.3} / {am:.3} ms ({:.2} / {:.2} ns; {:.2} / {:.2} × at once)",
        ns(gf),
        ns(gm),
        ns(af),
        ns(am),
        af / gf,
        am / gm
    );
}

/// Where `fill-write`'s caps come from.
#[derive(Clone, Copy, PartialEq)]
enum Caps {
    /// The welded mesh (`layout::Records`, what the probe timed first).
    Welded,
    /// No positions: each corner id stored where its position goes.
    Stores,
    /// The soup (`layout::SoupCaps`).
    Soup,
}

/// The streamed writer's fills (`format::write_file_streamed`), unit by
/// unit in file order into one reused buffer as one thread runs them:
/// alone, then with each unit written at its place in a new file in the
/// current directory (`pwrite`, as the writer does), 6 rounds of each,
/// fastest. The caps are also filled with their position gathers replaced
/// by stores of the corner ids (the same bytes written, nothing gathered),
/// which tells what the gathers cost each way.
///
/// Why: before the fifteenth round's longer prefetch, the dragon's fills
/// took about 10 ms alone and 12.5–16.7 ms between the writes, the caps
/// most (3.7–4.0 → 4.6–6.8 ms; 1.7–2.4 ms either way without the
/// gathers). The copy into the page cache carries the whole output through
/// the caches, so the caps' scattered reads of the position table (5.2 MB)
/// go to memory instead of L2 and L3 (benches/ROUNDS.md, fifteenth round).
fn fill_write(path: &Path) {
    use std::os::unix::fs::FileExt;
    use svpack::format::PayloadSource;
    use svpack::layout::{DEFAULT_MAX_MULT, Plan};
    let soup = svpack::load::load(path).unwrap();
    let w = svpack::weld::weld_without_sources(&soup.positions, &soup.indices);
    let e = svpack::topology::build_edges_opposites_only(&w.triangles, w.positions.len());
    let plan = Plan::new(&e, w.triangle_count(), DEFAULT_MAX_MULT);
    let records = plan.records(&w, &e);
    let sections = 1 + plan.buckets().count();
    let units = records.units();
    let lens = |u: usize| {
        (0..sections)
            .map(|s| records.floats(u, s))
            .collect::<Vec<_>>()
    };
    let widest = (0..units).map(|u| lens(u).iter().sum()).max().unwrap_or(0);
    let mut buf = vec![0f32; widest];
    // Caps records with the corner ids where the positions go: the stores
    // without the gathers. Every caps unit but the last is full, so unit
    // u's first corner is u times a full unit's.
    let corners_per_unit = lens(0)[0] / 4;
    let caps_without_gathers = |u: usize, out: &mut [f32]| {
        let out: &mut [[f32; 4]] = bytemuck::cast_slice_mut(out);
        let tris = &w.triangles[u * corners_per_unit..];
        for (slot, &v) in out.iter_mut().zip(tris) {
            *slot = [v as f32, 0.0, 0.0, 1.0];
        }
    };
    // The caps as a one-thread build makes them (`layout::SoupCaps`).
    let soup_caps = svpack::layout::SoupCaps::new(&soup.positions, &soup.indices, &w);
    let file_path = Path::new(".svpack-fill-write.tmp");
    let total: usize = (0..units).map(|u| lens(u).iter().sum::<usize>()).sum();
    // (fill, caps fill, write) in ms for one round; with `gathers` None,
    // no fills at all: the same writes of a buffer no fill has just
    // passed through the caches.
    let mut round = |write: bool, gathers: Option<Caps>| {
        let file = write.then(|| {
            let f = std::fs::File::create(file_path).unwrap();
            // Its blocks reserved first, as `format::write_file_streamed`
            // does on ext4 and XFS.
            use std::os::unix::io::AsRawFd;
            // SAFETY: an open descriptor; the call only reserves blocks.
            unsafe { libc::fallocate(f.as_raw_fd(), 0, 0, (4 * total) as libc::off_t) };
            f
        });
        let (mut fill, mut caps, mut written) = (0.0, 0.0, 0.0);
        let mut at = 0u64;
        for u in 0..units {
            let lens = lens(u);
            let t = Instant::now();
            let mut outs = svpack::format::split_pieces(&mut buf, &lens);
            let is_caps = lens[0] > 0;
            match gathers {
                None => {} // No fill.
                Some(Caps::Stores) if is_caps => caps_without_gathers(u, outs[0]),
                Some(Caps::Soup) if is_caps => soup_caps.fill(u, &mut outs),
                Some(_) => records.fill(u, &mut outs),
            }
            let d = t.elapsed().as_secs_f64() * 1e3;
            fill += d;
            if is_caps {
                caps += d;
            }
            let total: usize = lens.iter().sum();
            let bytes: &[u8] = bytemuck::cast_slice(&buf[..total]);
            if let Some(f) = &file {
                let t = Instant::now();
                f.write_all_at(bytes, at).unwrap();
                written += t.elapsed().as_secs_f64() * 1e3;
            }
            at += bytes.len() as u64;
        }
        if file.is_some() {
            std::fs::remove_file(file_path).unwrap();
        }
        [fill, caps, written]
    };
    for (write, gathers) in [
        (false, Some(Caps::Welded)),
        (true, Some(Caps::Welded)),
        (false, Some(Caps::Stores)),
        (true, Some(Caps::Stores)),
        (false, Some(Caps::Soup)),
        (true, Some(Caps::Soup)),
        (true, None),
    ] {
        let mut best = [f64::MAX; 3];
        for _ in 0..6 {
            for (b, v) in best.iter_mut().zip(round(write, gathers)) {
                *b = b.min(v);
            }
        }
        println!(
            "{}{}: fills {:.2} ms (caps {:.2}){}",
            if write {
                "each unit written"
            } else {
                "fills alone"
            },
            match gathers {
                Some(Caps::Welded) => "",
                Some(Caps::Stores) => ", caps without gathers",
                Some(Caps::Soup) => ", caps from the soup",
                None => ", no fills (the writes alone)",
            },
            best[0],
            best[1],
            if write {
                format!(", writes {:.2} ms", best[2])
            } else {
                String::new()
            }
        );
    }
}

/// The build's steps after loading, each on the previous one's output.
fn build(path: &Path) {
    use svpack::layout::{DEFAULT_MAX_MULT, Plan};
    let soup = svpack::load::load(path).unwrap();
    let (weld_ms, w) = fastest(15, || svpack::weld::weld(&soup.positions, &soup.indices));
    let (topo_ms, e) = fastest(15, || {
        svpack::topology::build_edges_opposites_only(&w.triangles, w.positions.len())
    });
    let (plan_ms, plan) = fastest(30, || Plan::new(&e, w.triangle_count(), DEFAULT_MAX_MULT));
    // The fills into buffers reused from block to block, as the writer
    // reuses its own: the largest block's size for every bucket.
    let mut caps = vec![
        0f32;
        (0..plan.cap_blocks())
            .map(|b| plan.cap_block_floats(b))
            .max()
            .unwrap_or(0)
    ];
    let (caps_ms, _) = fastest(15, || {
        for b in 0..plan.cap_blocks() {
            let n = plan.cap_block_floats(b);
            plan.fill_caps(&w, b, &mut caps[..n]);
        }
    });
    let widest = |k: u32| {
        (0..plan.side_blocks())
            .map(|b| plan.side_block_floats(b, k))
            .max()
            .unwrap_or(0)
    };
    let mut sides: Vec<Vec<f32>> = (0..=DEFAULT_MAX_MULT)
        .map(|k| vec![0f32; widest(k)])
        .collect();
    let (sides_ms, _) = fastest(15, || {
        for b in 0..plan.side_blocks() {
            let mut outs: Vec<&mut [f32]> = (sides.iter_mut().enumerate())
                .map(|(k, v)| &mut v[..plan.side_block_floats(b, k as u32)])
                .collect();
            plan.fill_sides(&w, &e, b, &mut outs);
        }
    });
    println!(
        "{} triangles: weld {weld_ms:.2} ms, topology {topo_ms:.2} ms, plan {plan_ms:.3} ms, \
         caps fill {caps_ms:.2} ms, sides fill {sides_ms:.2} ms",
        w.triangle_count()
    );
}

/// Weld, topology, the bucket counts and the edge statistics from them, as
/// the stages bench's `weld+topology+layout/ours_buckets` runs them (and a
/// build: `Plan::edge_stats`), then its peer,
/// meshoptimizer's adjacency from the same soup: 30 runs of ours and 10 of
/// the peer, the fastest and median times and the median number of page
/// faults per run (`getrusage`'s minor faults: one per huge page or small
/// page faulted in). With `RECYCLE=1` our runs after the first should
/// fault in nothing, the blocks the run before freed being kept: that they
/// did (14–16 huge pages a run on the dragon until freed blocks that touch
/// were joined, `alloc`, twenty-seventh round) is what this step showed.
/// The peer's C++ buffers come from glibc's malloc, which serves them
/// from memory earlier runs freed, but for those above its mmap threshold.
fn buckets(path: &Path) {
    let soup = svpack::load::load(path).unwrap();
    let faults = || {
        // SAFETY: `getrusage` writes the struct it is given.
        let mut u: libc::rusage = unsafe { std::mem::zeroed() };
        unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) };
        u.ru_minflt
    };
    let runs = |name: &str, n: usize, f: &dyn Fn()| {
        let mut times = Vec::new();
        let mut counts = Vec::new();
        for _ in 0..n {
            let before = faults();
            let t = Instant::now();
            f();
            times.push(t.elapsed().as_secs_f64() * 1e3);
            counts.push(faults() - before);
        }
        let first = counts[0];
        times.sort_by(f64::total_cmp);
        counts.sort_unstable();
        println!(
            "{name}: fastest {:.2} ms, median {:.2} ms; page faults: {first} in the first run, median {} a run",
            times[0],
            times[n / 2],
            counts[n / 2]
        );
    };
    runs("weld + topology + buckets", 30, &|| {
        std::hint::black_box(peers::ours_buckets(&soup));
    });
    runs("meshoptimizer's adjacency", 10, &|| {
        std::hint::black_box(peers::meshopt_adjacency(&soup.positions, &soup.indices));
    });
}

/// The floor that fresh memory puts under `buckets`' runs (the stages
/// bench's `ours_buckets`, whose every iteration maps its blocks afresh):
/// per round, one run with fresh memory, one with memory recycled (a
/// `KeepFreed` guard held over a run before it, which fills the cache),
/// meshoptimizer's adjacency, and the fresh pages of our run's output
/// alone: buffers of the returned arrays' sizes allocated the same way,
/// one byte written per 4 KiB page, then freed. 20 rounds alternated (the
/// host drifts). Recycled plus the output's pages is what a run with
/// fresh memory takes at least, whatever the code does short of returning
/// less: the kernel maps and zeroes every page of it. Ignores `RECYCLE`.
fn floor(path: &Path) {
    let soup = svpack::load::load(path).unwrap();
    let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3;
    // The returned arrays' sizes in bytes (capacities: what was mapped).
    let sizes: Vec<usize> = {
        let (w, e, _, _) = peers::ours_buckets(&soup);
        vec![
            w.positions.capacity() * 12,
            w.triangles.capacity() * 4,
            e.a.capacity() * 4,
            e.b.capacity() * 4,
            e.opp_start.capacity() * 4,
            e.opp.capacity() * 4,
        ]
    };
    let output: usize = sizes.iter().sum();
    let (mut fresh, mut recycled, mut peer, mut pages) = (vec![], vec![], vec![], vec![]);
    for _ in 0..20 {
        let t = Instant::now();
        std::hint::black_box(peers::ours_buckets(&soup));
        fresh.push(ms(t));
        {
            let _keep = svpack::alloc::KeepFreed::new();
            std::hint::black_box(peers::ours_buckets(&soup));
            let t = Instant::now();
            std::hint::black_box(peers::ours_buckets(&soup));
            recycled.push(ms(t));
        }
        let t = Instant::now();
        std::hint::black_box(peers::meshopt_adjacency(&soup.positions, &soup.indices));
        peer.push(ms(t));
        let t = Instant::now();
        for &n in &sizes {
            let mut v: Vec<u8> = Vec::with_capacity(n);
            // SAFETY: within the capacity; one byte per page, as a first
            // write does.
            for at in (0..n).step_by(4096) {
                unsafe { v.as_mut_ptr().add(at).write_volatile(1) };
            }
            std::hint::black_box(&v);
        }
        pages.push(ms(t));
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[0], v[v.len() / 2])
    };
    let (f, r, p, g) = (
        stats(&mut fresh),
        stats(&mut recycled),
        stats(&mut peer),
        stats(&mut pages),
    );
    println!("fastest / median of 20 alternated rounds, ms:");
    println!(
        "  weld + topology + buckets, fresh memory: {:.2} / {:.2}",
        f.0, f.1
    );
    println!("  the same, memory recycled: {:.2} / {:.2}", r.0, r.1);
    println!(
        "  the fresh pages of its output alone ({:.1} MiB): {:.2} / {:.2}",
        output as f64 / (1 << 20) as f64,
        g.0,
        g.1
    );
    println!("  meshoptimizer's adjacency: {:.2} / {:.2}", p.0, p.1);
    println!(
        "floor with fresh memory (recycled + the output's pages): {:.2} / {:.2} ms = {:.3} / {:.3} of meshoptimizer; fresh memory measured {:.3} / {:.3}",
        r.0 + g.0,
        r.1 + g.1,
        (r.0 + g.0) / p.0,
        (r.1 + g.1) / p.1,
        f.0 / p.0,
        f.1 / p.1
    );
}

/// What putting a finished 120 MiB output in place costs in directory
/// `dir` (the tenth round's `format::persist`), 3 times each, the previous
/// output on disk (synced) and the new file just written, as a rebuild
/// finds them: a rename onto a fresh name; a rename over the previous output
/// (on ext4 the call starts writeback of the new file); the swap
/// (`renameat2` with `RENAME_EXCHANGE`) and the removal of the previous
/// output it leaves under the temp name. Plain `std` and `libc`, so it
/// builds at older commits too.
fn replace(dir: &Path) {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let bytes: Vec<u8> = (0..120u32 << 20)
        .map(|i| i.wrapping_mul(2654435761) as u8)
        .collect();
    let (tmp, out) = (dir.join("probe.tmp"), dir.join("probe.out"));
    let c = |p: &Path| CString::new(p.as_os_str().as_bytes()).unwrap();
    let ms = |t: Instant| t.elapsed().as_secs_f64() * 1e3;
    let sync = || std::process::Command::new("sync").status().unwrap();
    // The previous output on disk (synced), the new one just written.
    let prepare = |previous: bool| {
        let _ = std::fs::remove_file(&out);
        if previous {
            std::fs::write(&out, &bytes).unwrap();
        }
        sync();
        std::fs::write(&tmp, &bytes).unwrap();
    };
    for _ in 0..3 {
        prepare(false);
        let t = Instant::now();
        std::fs::rename(&tmp, &out).unwrap();
        let fresh = ms(t);
        prepare(true);
        let t = Instant::now();
        std::fs::rename(&tmp, &out).unwrap();
        let over = ms(t);
        prepare(true);
        let t = Instant::now();
        // SAFETY: two NUL-terminated paths that outlive the call.
        let rc = unsafe {
            libc::syscall(
                libc::SYS_renameat2,
                libc::AT_FDCWD,
                c(&tmp).as_ptr(),
                libc::AT_FDCWD,
                c(&out).as_ptr(),
                libc::RENAME_EXCHANGE,
            )
        };
        assert_eq!(rc, 0, "{}", std::io::Error::last_os_error());
        let swap = ms(t);
        let t = Instant::now();
        std::fs::remove_file(&tmp).unwrap();
        let remove = ms(t);
        println!(
            "rename to a fresh name {fresh:.1} ms; rename over the previous output {over:.1} ms; \
             swap {swap:.2} ms + removing the previous output {remove:.1} ms"
        );
    }
    let _ = std::fs::remove_file(&out);
}

/// `verify`'s orientation check for 12 point lights around the mesh, after
/// decoding and evaluating once.
fn verify(path: &Path) {
    let file = svpack::format::read_file(path).unwrap();
    let d = svpack::verify::decode(&file, 0);
    let lights: Vec<[f32; 4]> = (0..12)
        .map(|i| {
            let a = i as f32 * 0.5;
            [0.3 * a.cos(), 0.2, 0.3 * a.sin(), 1.0]
        })
        .collect();
    let strategy = svpack::evaluate::Strategy::Reference;
    let evs: Vec<_> = (lights.iter())
        .map(|&l| svpack::verify::evaluate(&d, l, strategy))
        .collect();
    let (ms, errors) = fastest(5, || {
        (lights.iter().zip(&evs))
            .map(|(&l, ev)| svpack::verify::orientation_errors(&d, l, ev))
            .sum::<u64>()
    });
    println!("orientation errors, 12 point lights: {ms:.1} ms ({errors} errors)");
}
