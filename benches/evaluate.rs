//! CPU evaluator throughput: ns per side record and per cap triangle, single
//! thread, reference edge (the format's contract) against Kim 2008's per-edge
//! light plane as the peer, on real models (stanford-bunny from
//! ../shared/meshes when present, the full Stanford dragon when
//! benches/fetch_dragon.sh has fetched it) and a generated sphere.
//!
//! Also the shared evaluator `verify` uses (triangles once, sides as sums of
//! their signs), per side record, and the same for four lights at once
//! (`caps+sides/reference_shared_4_lights`, per light and side record).
//!
//! `reference` is the vectorised kernel (`svpack::evaluate_simd`, what
//! `Strategy::Reference` runs); `reference_scalar` is the scalar, branching
//! loop it replaced, kept in the same run so the two read against each other
//! on the same machine state (the results are bit for bit equal; the
//! library's tests check that).
//!
//! Every timed loop runs inside the one-thread pool (`pool.install` around
//! `b.iter`): starting the pool's thread from outside for each iteration
//! costs a sleep and a wake-up, tens of microseconds in this VM, which was
//! 15% of an iteration on the bunny.
//!
//! `cargo bench --bench evaluate -- --warm-up-time 1 --measurement-time 3`;
//! criterion reports time per element: per side record for `sides/*` and
//! `caps+sides/*`, per triangle for `caps/*`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::path::Path;
use svpack::build::{BuildConfig, build_file};
use svpack::evaluate::{
    Strategy, cap_signs_scalar, cap_signs_with, side_multiplicities_scalar,
    side_multiplicities_shared, side_multiplicities_shared_scalar, side_multiplicities_with,
};

#[path = "../examples/sphere.rs"]
mod sphere;
use sphere::sphere_obj;

/// Signature of `side_multiplicities_shared` and its scalar peer.
type SharedFn = fn(Strategy, usize, &[f32], &[u32], &[i8], &[i8], [f32; 4], &mut [i8]);

/// The group of lights of the four-light benchmarks: `light` and three
/// others around the model (one directional), as `stage_probe -- evaluate`
/// has them.
fn four_lights(light: [f32; 4]) -> [[f32; 4]; 4] {
    [
        light,
        [-3.0, 1.5, 2.0, 1.0],
        [0.3, -1.0, 0.2, 0.0],
        [1.0, 9.0, -4.0, 1.0],
    ]
}

/// `shared` (the reference strategy) over one decoded bucket.
fn shared_bucket(
    shared: SharedFn,
    bk: &svpack::verify::DecodedBucket,
    caps: &[i8],
    light: [f32; 4],
    out: &mut [i8],
) {
    let (tri, parity) = (&bk.slot_tri, &bk.slot_parity);
    shared(
        Strategy::Reference,
        bk.k,
        &bk.data,
        tri,
        parity,
        caps,
        light,
        out,
    )
}

/// The kernel choices the evaluator's dispatching benches run with: label
/// suffix, AVX-512 off (`evaluate_simd::disable_avx512`), and the caps'
/// gathers forced (`evaluate_simd::prefer_gather_caps`; None leaves them
/// to the measurement of `evaluate_indexed::gathers_pay`).
const KERNEL_CHOICES: [(&str, bool, Option<bool>); 3] = [
    ("", false, None),
    ("_no_avx512", true, None),
    ("_gathers", false, Some(true)),
];

fn bench_file(c: &mut Criterion, name: &str, input: &Path) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("b.svpk");
    build_file(input, &out, &BuildConfig::default()).unwrap();
    let file = svpack::format::read_file(&out).unwrap();
    let d = svpack::verify::decode(&file, 0);
    let light = [3.0, 2.5, 4.0, 1.0];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let records: usize = d.buckets.iter().map(|b| b.records()).sum();
    let mut g = c.benchmark_group(format!("evaluate/{name}"));
    type SidesFn = fn(Strategy, usize, &[f32], [f32; 4], &mut [i8]);
    type CapsFn = fn(Strategy, &[f32], [f32; 4], &mut [i8]);
    let runs: [(&str, Strategy, SidesFn, CapsFn); 3] = [
        (
            "reference",
            Strategy::Reference,
            side_multiplicities_with,
            cap_signs_with,
        ),
        (
            "reference_scalar",
            Strategy::Reference,
            side_multiplicities_scalar,
            cap_signs_scalar,
        ),
        (
            "kim",
            Strategy::Kim,
            side_multiplicities_with,
            cap_signs_with,
        ),
    ];
    for (label, strategy, sides, caps) in runs {
        g.throughput(Throughput::Elements(records as u64));
        g.bench_function(format!("sides/{label}"), |b| {
            let mut outs: Vec<Vec<i8>> = d.buckets.iter().map(|x| vec![0; x.records()]).collect();
            pool.install(|| {
                b.iter(|| {
                    for (bk, o) in d.buckets.iter().zip(outs.iter_mut()) {
                        sides(strategy, bk.k, &bk.data, light, o);
                    }
                })
            })
        });
        g.throughput(Throughput::Elements(d.caps.len() as u64));
        g.bench_function(format!("caps/{label}"), |b| {
            let mut o = vec![0i8; d.caps.len()];
            pool.install(|| b.iter(|| caps(strategy, &d.caps_data, light, &mut o)))
        });
    }
    // The caps from sorted corner ids (what `verify` uses for the reference
    // when the file's position table allows it), per triangle: reads against
    // caps/reference above.
    // `_no_avx512`: the same with the AVX-512 kernels turned off (AVX2 for
    // the caps, the plain loop for the sides): the previous kernels as
    // peers in the same run. `_gathers`: the AVX-512 caps kernel, whose
    // gathers a measurement decides on (`evaluate_simd::gather_caps`),
    // forced on where the CPU has AVX-512, so that the choice is measured
    // on each machine.
    if let Some(ix) = d.ordered.as_ref().map(|o| o.caps()) {
        g.throughput(Throughput::Elements(ix.len() as u64));
        for (label, off, gathers) in KERNEL_CHOICES {
            g.bench_function(format!("caps/reference_indexed{label}"), |b| {
                let mut o = vec![0i8; ix.len()];
                svpack::evaluate_simd::disable_avx512(off);
                svpack::evaluate_simd::prefer_gather_caps(gathers);
                pool.install(|| b.iter(|| ix.cap_signs(light, &mut o)));
                svpack::evaluate_simd::prefer_gather_caps(None);
                svpack::evaluate_simd::disable_avx512(false);
            });
        }
    }
    // The evaluator `verify` uses: each triangle's sign once (caps), then
    // every side record as a signed sum of its triangles' signs; per light,
    // caps + sides. Reported per side record (edge instance), so it reads
    // against sides/reference + caps/reference above.
    g.throughput(Throughput::Elements(records as u64));
    // Floor of the shared evaluation: reading the bytes it must read (every
    // cap record once, the side slots' triangle ids and parities) with
    // nothing computed, per side record. On a mesh larger than the caches
    // this is memory bandwidth, which no kernel can beat.
    // Every side slot's triangle id and parity, summed (read, nothing else).
    let read_slots = || {
        let mut acc = 0u32;
        for bk in &d.buckets {
            acc = acc.wrapping_add(bk.slot_tri.iter().fold(0u32, |a, &t| a.wrapping_add(t)));
            acc = acc.wrapping_add(
                bk.slot_parity
                    .iter()
                    .fold(0u32, |a, &p| a.wrapping_add(p as u32)),
            );
        }
        acc
    };
    g.bench_function("floor_read/shared_inputs", |b| {
        b.iter(|| {
            let mut acc = 0u32;
            for chunk in d.caps_data.chunks_exact(4) {
                acc = acc.wrapping_add(chunk[0].to_bits());
            }
            std::hint::black_box(acc.wrapping_add(read_slots()))
        })
    });
    // Floor of the shared evaluation with caps from ids: reading the caps'
    // corner ids, the position table (12 bytes a point) and the side slots'
    // triangle ids and parities, nothing computed: a little less than the
    // evaluation reads (its table has 16-byte points, and a parity byte per
    // triangle), so a lower bound.
    g.bench_function("floor_read/indexed_inputs", |b| {
        b.iter(|| {
            let mut acc = 0u32;
            for c in &d.caps {
                acc = acc.wrapping_add(c[0] ^ c[1] ^ c[2]);
            }
            for p in &d.positions {
                acc = acc.wrapping_add(p[0].to_bits());
            }
            std::hint::black_box(acc.wrapping_add(read_slots()))
        })
    });
    // What `verify` does per light: one set of output buffers reused
    // across lights (`evaluate_into`); `_fresh` allocates them per light
    // (`evaluate`), which on this machine means first-touch page faults.
    for (label, off, gathers) in KERNEL_CHOICES {
        g.bench_function(format!("caps+sides/reference_shared{label}"), |b| {
            let mut ev = svpack::verify::Evaluation::default();
            svpack::evaluate_simd::disable_avx512(off);
            svpack::evaluate_simd::prefer_gather_caps(gathers);
            pool.install(|| {
                b.iter(|| svpack::verify::evaluate_into(&d, light, Strategy::Reference, &mut ev))
            });
            svpack::evaluate_simd::prefer_gather_caps(None);
            svpack::evaluate_simd::disable_avx512(false);
        });
    }
    // Four lights at once (`evaluate_many_into`: the caps of the group in
    // one pass, the sides from the group's table), per light and side
    // record: the element count is four lights' records.
    g.throughput(Throughput::Elements(4 * records as u64));
    g.bench_function("caps+sides/reference_shared_4_lights", |b| {
        let lights = four_lights(light);
        let mut evs = vec![svpack::verify::Evaluation::default(); lights.len()];
        pool.install(|| {
            b.iter(|| {
                svpack::verify::evaluate_many_into(&d, &lights, Strategy::Reference, &mut evs)
            })
        });
    });
    g.throughput(Throughput::Elements(records as u64));
    // The peer of the lines above: the same kernels with the triangles in
    // input order (the evaluator before `evaluate_ordered`), buffers reused
    // as above: the caps from ids, then each slot's sign read from the
    // input-order table through the gathers of `try_sides_from_caps`.
    if let Some(ix) = svpack::evaluate_indexed::IndexedCaps::new(&d.positions, &d.caps) {
        g.bench_function("caps+sides/reference_shared_input_order", |b| {
            let mut caps = vec![0i8; ix.len()];
            let mut sides: Vec<Vec<i8>> =
                d.buckets.iter().map(|bk| vec![0; bk.records()]).collect();
            pool.install(|| {
                b.iter(|| {
                    ix.cap_signs(light, &mut caps);
                    for (bk, m) in d.buckets.iter().zip(&mut sides) {
                        shared_bucket(side_multiplicities_shared, bk, &caps, light, m);
                    }
                })
            })
        });
    }
    g.bench_function("caps+sides/reference_shared_fresh", |b| {
        pool.install(|| b.iter(|| svpack::verify::evaluate(&d, light, Strategy::Reference)))
    });
    // The same computation with the caps from the records (the shared
    // evaluator before the ids), the peer of the line above, and through the
    // loops it had before the vectorised kernels and gather (scalar caps, one
    // checked `caps.get` per slot).
    for (label, caps_fn, shared) in [
        (
            "reference_shared_record_caps",
            cap_signs_with as CapsFn,
            side_multiplicities_shared as SharedFn,
        ),
        (
            "reference_shared_scalar",
            cap_signs_scalar,
            side_multiplicities_shared_scalar,
        ),
    ] {
        g.bench_function(format!("caps+sides/{label}"), |b| {
            pool.install(|| {
                b.iter(|| {
                    let mut caps = vec![0i8; d.caps.len()];
                    caps_fn(Strategy::Reference, &d.caps_data, light, &mut caps);
                    let sides: Vec<Vec<i8>> = d
                        .buckets
                        .iter()
                        .map(|bk| {
                            let mut m = vec![0i8; bk.records()];
                            shared_bucket(shared, bk, &caps, light, &mut m);
                            m
                        })
                        .collect();
                    (caps, sides)
                })
            })
        });
    }
    let caps = svpack::verify::evaluate(&d, light, Strategy::Reference).caps;
    for (label, shared, off) in [
        (
            "reference_shared",
            side_multiplicities_shared as SharedFn,
            false,
        ),
        (
            "reference_shared_no_avx512",
            side_multiplicities_shared,
            true,
        ),
        (
            "reference_shared_scalar",
            side_multiplicities_shared_scalar,
            false,
        ),
    ] {
        g.bench_function(format!("sides_given_caps/{label}"), |b| {
            let mut outs: Vec<Vec<i8>> = d.buckets.iter().map(|x| vec![0; x.records()]).collect();
            svpack::evaluate_simd::disable_avx512(off);
            pool.install(|| {
                b.iter(|| {
                    for (bk, o) in d.buckets.iter().zip(outs.iter_mut()) {
                        shared_bucket(shared, bk, &caps, light, o);
                    }
                })
            });
            svpack::evaluate_simd::disable_avx512(false);
        });
    }
    g.finish();
}

fn evaluator(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let sphere = dir.path().join("sphere.obj");
    std::fs::write(&sphere, sphere_obj(256)).unwrap();
    bench_file(c, "sphere_131k", &sphere);
    let bunny =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes/obj/stanford-bunny.obj");
    if bunny.exists() {
        bench_file(c, "bunny", &bunny);
    } else {
        eprintln!("skipping bunny: {} is absent", bunny.display());
    }
    // The full Stanford dragon (871k triangles), when benches/fetch_dragon.sh
    // has fetched it.
    let dragon = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/dragon/dragon.obj");
    if dragon.exists() {
        bench_file(c, "dragon_full", &dragon);
    } else {
        eprintln!("skipping dragon_full: run benches/fetch_dragon.sh");
    }
}

criterion_group!(benches, evaluator);
criterion_main!(benches);
