//! CPU evaluator throughput: ns per side record and per cap triangle, single
//! thread, reference edge (the format's contract) against Kim 2008's per-edge
//! light plane as the peer, on a real model (stanford-bunny from
//! ../shared/meshes when present) and a generated sphere.
//!
//! Also the shared evaluator `verify` uses (triangles once, sides as sums of
//! their signs), per side record.
//!
//! `cargo bench --bench evaluate`; criterion reports time per element.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use std::path::Path;
use svpack::build::{BuildConfig, build_file};
use svpack::evaluate::{Strategy, cap_signs_with, side_multiplicities_with};

#[path = "../examples/sphere.rs"]
mod sphere;
use sphere::sphere_obj;

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
    for (label, strategy) in [("reference", Strategy::Reference), ("kim", Strategy::Kim)] {
        g.throughput(Throughput::Elements(records as u64));
        g.bench_function(format!("sides/{label}"), |b| {
            let mut outs: Vec<Vec<i8>> = d.buckets.iter().map(|x| vec![0; x.records()]).collect();
            b.iter(|| {
                pool.install(|| {
                    for (bk, o) in d.buckets.iter().zip(outs.iter_mut()) {
                        side_multiplicities_with(strategy, bk.k, &bk.data, light, o);
                    }
                })
            })
        });
        g.throughput(Throughput::Elements(d.caps.len() as u64));
        g.bench_function(format!("caps/{label}"), |b| {
            let mut o = vec![0i8; d.caps.len()];
            b.iter(|| pool.install(|| cap_signs_with(strategy, &d.caps_data, light, &mut o)))
        });
    }
    // The evaluator `verify` uses: each triangle's sign once (caps), then
    // every side record as a signed sum of its triangles' signs; per light,
    // caps + sides. Reported per side record (edge instance), so it reads
    // against sides/reference + caps/reference above.
    g.throughput(Throughput::Elements(records as u64));
    g.bench_function("caps+sides/reference_shared", |b| {
        b.iter(|| pool.install(|| svpack::verify::evaluate(&d, light, Strategy::Reference)))
    });
    g.bench_function("sides_given_caps/reference_shared", |b| {
        let caps = svpack::verify::evaluate(&d, light, Strategy::Reference).caps;
        let mut outs: Vec<Vec<i8>> = d.buckets.iter().map(|x| vec![0; x.records()]).collect();
        b.iter(|| {
            pool.install(|| {
                for (bk, o) in d.buckets.iter().zip(outs.iter_mut()) {
                    svpack::evaluate::side_multiplicities_shared(
                        Strategy::Reference,
                        bk.k,
                        &bk.data,
                        &bk.slot_tri,
                        &bk.slot_parity,
                        &caps,
                        light,
                        o,
                    );
                }
            })
        })
    });
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
}

criterion_group!(benches, evaluator);
criterion_main!(benches);
