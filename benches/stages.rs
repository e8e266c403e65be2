//! Per-stage throughput of the build pipeline, one criterion group per stage,
//! on real meshes (../shared/meshes when present) and a generated scene, all
//! reported per input triangle:
//!
//! - `load/ours/*`: file read + OBJ/glTF decode through `svpack::load::load`,
//!   and for OBJ the peer `load/tobj/*`: file read + `tobj::load_obj_buf` with
//!   the options our loader uses (our overhead = ours / tobj − 1), and for
//!   glTF the peer `load/gltf_crate/*`: the gltf crate's parse and its
//!   accessor readers for every primitive's positions and indices;
//! - `check/ours/*`: `build::check_soup` (indices in range, finite positions);
//! - `weld/ours/*`: `weld::weld`, and the peer `weld/peer_sort_unstable/*`:
//!   the same vertices' 128-bit sort words sorted by the standard library's
//!   `sort_unstable`, alone (`common/peers.rs`);
//! - `topology/ours/*`: `topology::build_edges` (edges and all opposite
//!   vertices), `topology/opposites_only/*` (the same without the opposite
//!   vertices' triangles, as `svpack build` runs it), `topology/previous_sort/*` (the method it replaced,
//!   `common/topology_sort.rs`, as the baseline of that speed-up),
//!   `topology/edge_stats/*`, and the peer in the same group,
//!   `topology/meshopt_adjacency/*`: meshoptimizer's adjacency index buffer
//!   (`meshopt::generate_adjacency_indices`) on the same welded positions
//!   and indices;
//! - `layout/ours/*`: `layout::layout` (side buckets and caps, K = 5);
//! - `layout/floor_fill/*`: allocating and filling as many fresh bytes as the
//!   layout produces (the memory-bandwidth floor of the layout stage);
//! - `write/memory/*` and `write/file/*`: container serialisation
//!   (`format::encode_to` into a Vec, `format::write_file` to a temp file),
//!   and `write/floor_file/*`: writing the same number of ready bytes to a
//!   temp file and renaming it (the page-cache floor of the write stage);
//!   the file benchmarks remove their previous output outside the timing;
//! - `layout+write/whole/*`: `layout::layout` then `format::write_file` (the
//!   compressed build's path, here uncompressed), against
//!   `layout+write/streamed/*`: `layout::Plan` and
//!   `format::write_file_streamed`, which fills the file block by block (the
//!   uncompressed build's path); both write the same file;
//! - `evaluate/reference_1t/*`: the CPU evaluator (reference strategy, one
//!   light, every side bucket and the caps) inside a 1-thread rayon pool;
//! - `weld+topology+layout/ours/*`: `build::build_soup` from the loaded soup,
//!   against `weld+topology+layout/meshopt_adjacency/*`: meshoptimizer's
//!   adjacency from the same unwelded soup (it does its own position
//!   matching), i.e. "soup in, adjacency out" for both; and
//!   `weld+topology+layout/ours_buckets/*`: weld, topology and the bucket
//!   counts (`layout::Plan`) without filling any buffer, which is all an
//!   uncompressed build does before writing; `ours_buckets_kept/*` the same
//!   with freed blocks kept between iterations (`alloc::KeepFreed`), as a
//!   batch's later inputs see them.
//!
//! Inputs: dragon_res4, armadillo and 2CylinderEngine from ../shared/meshes,
//! the full Stanford dragon when `benches/fetch_dragon.sh` has fetched it,
//! and a generated scene of `SVPACK_BENCH_SCENE` triangles (default 1M).
//! `SVPACK_BENCH_ONLY=dragon_full,scene_1000k` keeps only the named inputs.
//!
//! `cargo bench --bench stages -- --warm-up-time 1 --measurement-time 3`;
//! a filter such as `topology/` runs one group.

use criterion::measurement::WallTime;
use criterion::{
    BatchSize, BenchmarkGroup, Criterion, Throughput, criterion_group, criterion_main,
};
use std::hint::black_box;
use std::path::{Path, PathBuf};
use svpack::build::{BuildConfig, build_file, build_soup, check_soup};
use svpack::evaluate::{Strategy, cap_signs_with, side_multiplicities_with};
use svpack::format::{self, MeshPayload};
use svpack::layout::{self, DEFAULT_MAX_MULT, Layout};
use svpack::load::{self, Soup};
use svpack::topology::{self, Edges};
use svpack::weld::{self, Welded};

/// The allocator `svpack` itself runs with, so stage times match the CLI's.
#[global_allocator]
static ALLOC: svpack::alloc::HugePageAlloc = svpack::alloc::HugePageAlloc;

#[path = "../examples/scene.rs"]
mod scene;

#[path = "common/peers.rs"]
mod peers;

#[path = "common/topology_sort.rs"]
mod topology_sort;

/// Triangles of the generated scene.
const SCENE_TRIANGLES: u64 = 1_000_000;

/// One input, loaded and run through every stage once, so each benchmark
/// gets the previous stage's output.
struct Mesh {
    name: String,
    path: PathBuf,
    soup: Soup,
    welded: Welded,
    edges: Edges,
    layout: Layout,
    header: format::Header,
    /// Triangles in the loaded soup (the throughput unit everywhere).
    triangles: u64,
}

fn prepare(name: &str, path: &Path, scratch: &Path) -> Mesh {
    let soup = load::load(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    check_soup(path, &soup).unwrap();
    let welded = weld::weld(&soup.positions, &soup.indices);
    let edges = topology::build_edges(&welded.triangles, welded.positions.len());
    assert!(
        topology_sort::build_edges(&welded.triangles, welded.positions.len()) == edges,
        "{name}: the previous topology method gives different edges"
    );
    assert!(
        peers::welded_in_sorted_words(
            &peers::sorted_vertex_words(&soup.positions),
            &welded.positions
        ),
        "{name}: the weld's peer sorts its words into another order"
    );
    let layout = layout::layout(&welded, &edges, DEFAULT_MAX_MULT);
    // The header exactly as a default build writes it, so the write stage
    // serialises the same container as `svpack build`.
    let out = build_file(
        path,
        &scratch.join(format!("{name}.svpk")),
        &BuildConfig::default(),
    )
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let triangles = soup.triangle_count() as u64;
    eprintln!(
        "{name}: {triangles} triangles, {} soup vertices -> {} welded vertices, {} kept triangles, {} edges, {} side instances, {} bytes",
        soup.positions.len(),
        welded.positions.len(),
        welded.triangle_count(),
        edges.len(),
        layout.edge_instances(),
        out.file_bytes
    );
    Mesh {
        name: name.to_string(),
        path: path.to_path_buf(),
        soup,
        welded,
        edges,
        layout,
        header: out.header,
        triangles,
    }
}

fn group<'a>(c: &'a mut Criterion, stage: &str, m: &Mesh) -> BenchmarkGroup<'a, WallTime> {
    let mut g = c.benchmark_group(stage);
    g.throughput(Throughput::Elements(m.triangles));
    // Criterion's default 100 samples take minutes on the large inputs.
    g.sample_size(if m.triangles > 50_000 { 10 } else { 30 });
    g
}

fn payload(m: &Mesh) -> MeshPayload<'_> {
    MeshPayload {
        header: m.header.meshes[0].clone(),
        caps: &m.layout.caps,
        buckets: m.layout.buckets.iter().map(|b| b.data.as_slice()).collect(),
    }
}

fn bench_mesh(c: &mut Criterion, m: &Mesh, scratch: &Path) {
    let n = &m.name;

    let mut g = group(c, "load", m);
    g.bench_function(format!("ours/{n}"), |b| {
        b.iter(|| load::load(black_box(&m.path)).unwrap())
    });
    // The parser alone, as our OBJ loader calls it (same options), so
    // ours/tobj is our overhead on top of the parser.
    if m.path.extension().is_some_and(|e| e == "obj") {
        g.bench_function(format!("tobj/{n}"), |b| {
            b.iter(|| peers::tobj_load(black_box(&m.path)))
        });
    }
    // For glTF: the gltf crate's own parse (JSON, validation, GLB container)
    // and its accessor readers for every primitive's positions and indices,
    // i.e. the data a loader needs, without node transforms or diagnostics.
    if m.path
        .extension()
        .is_some_and(|e| e == "glb" || e == "gltf")
    {
        g.bench_function(format!("gltf_crate/{n}"), |b| {
            b.iter(|| peers::gltf_crate_load(black_box(&m.path)))
        });
    }
    g.finish();

    let mut g = group(c, "check", m);
    g.bench_function(format!("ours/{n}"), |b| {
        b.iter(|| check_soup(&m.path, black_box(&m.soup)).unwrap())
    });
    g.finish();

    let mut g = group(c, "weld", m);
    g.bench_function(format!("ours/{n}"), |b| {
        b.iter(|| weld::weld(black_box(&m.soup.positions), black_box(&m.soup.indices)))
    });
    g.bench_function(format!("peer_sort_unstable/{n}"), |b| {
        b.iter(|| peers::sorted_vertex_words(black_box(&m.soup.positions)))
    });
    g.finish();

    let mut g = group(c, "topology", m);
    g.bench_function(format!("ours/{n}"), |b| {
        b.iter(|| topology::build_edges(black_box(&m.welded.triangles), m.welded.positions.len()))
    });
    g.bench_function(format!("opposites_only/{n}"), |b| {
        b.iter(|| {
            topology::build_edges_opposites_only(
                black_box(&m.welded.triangles),
                m.welded.positions.len(),
            )
        })
    });
    // The same without the AVX-512 kernels: passes 1 and 3's AVX2
    // kernels (since the sixty-first round), which run where the CPU has
    // AVX2 but not AVX-512.
    g.bench_function(format!("opposites_only_avx2/{n}"), |b| {
        svpack::evaluate_simd::disable_avx512(true);
        b.iter(|| {
            topology::build_edges_opposites_only(
                black_box(&m.welded.triangles),
                m.welded.positions.len(),
            )
        });
        svpack::evaluate_simd::disable_avx512(false);
    });
    // The same without any kernel: the scalar passes (the emit every build
    // ran before the thirteenth round, and runs where the CPU lacks AVX2).
    g.bench_function(format!("opposites_only_scalar/{n}"), |b| {
        topology::scalar_topology(true);
        b.iter(|| {
            topology::build_edges_opposites_only(
                black_box(&m.welded.triangles),
                m.welded.positions.len(),
            )
        });
        topology::scalar_topology(false);
    });
    g.bench_function(format!("previous_sort/{n}"), |b| {
        b.iter(|| {
            topology_sort::build_edges(black_box(&m.welded.triangles), m.welded.positions.len())
        })
    });
    g.bench_function(format!("edge_stats/{n}"), |b| {
        b.iter(|| topology::edge_stats(black_box(&m.edges)))
    });
    g.bench_function(format!("meshopt_adjacency/{n}"), |b| {
        b.iter(|| {
            peers::meshopt_adjacency(
                black_box(&m.welded.positions),
                black_box(&m.welded.triangles),
            )
        })
    });
    g.finish();

    let mut g = group(c, "layout", m);
    g.bench_function(format!("ours/{n}"), |b| {
        b.iter(|| layout::layout(black_box(&m.welded), black_box(&m.edges), DEFAULT_MAX_MULT))
    });
    // Floor: allocating and filling as many fresh bytes as the layout
    // produces, with nothing to compute.
    let layout_bytes = (m.layout.caps_bytes() + m.layout.sides_bytes()) as usize;
    g.bench_function(format!("floor_fill/{n}"), |b| {
        b.iter(|| vec![1u8; black_box(layout_bytes)])
    });
    g.finish();

    let mut g = group(c, "write", m);
    let mut buf = Vec::new();
    g.bench_function(format!("memory/{n}"), |b| {
        b.iter(|| {
            buf.clear();
            format::encode_to(&mut buf, m.header.clone(), &[payload(m)]).unwrap();
            buf.len()
        })
    });
    // Every file benchmark removes its previous output outside the timing
    // (as before a fresh `svpack build`): unlinking 100+ MB of page cache is
    // not the writer's cost.
    let fresh = |p: &Path| {
        let _ = std::fs::remove_file(p);
    };
    let out = scratch.join(format!("{n}.write.svpk"));
    g.bench_function(format!("file/{n}"), |b| {
        b.iter_batched(
            || fresh(&out),
            |()| format::write_file(&out, m.header.clone(), &[payload(m)], None).unwrap(),
            BatchSize::PerIteration,
        )
    });
    // Floor: the same number of bytes, already encoded, written the same way
    // (temp file in the same directory, renamed over the previous output).
    // (Sized from the header, not from `write/memory`'s buffer, which is
    // empty when a filter skips that benchmark.)
    let bytes = vec![1u8; format::container_len(&m.header) as usize];
    let floor_out = scratch.join(format!("{n}.floor.bin"));
    g.bench_function(format!("floor_file/{n}"), |b| {
        b.iter_batched(
            || fresh(&floor_out),
            |()| {
                let tmp = tempfile::NamedTempFile::new_in(scratch).unwrap();
                std::io::Write::write_all(&mut tmp.as_file(), black_box(&bytes)).unwrap();
                tmp.persist(&floor_out).unwrap();
            },
            BatchSize::PerIteration,
        )
    });
    g.finish();

    // The CLI's uncompressed path against filling whole buffers and then
    // writing them: both from the same welded mesh and edges to a temp file
    // renamed over the previous output, the same bytes.
    let mut g = group(c, "layout+write", m);
    let whole_out = scratch.join(format!("{n}.whole.svpk"));
    g.bench_function(format!("whole/{n}"), |b| {
        b.iter_batched(
            || fresh(&whole_out),
            |()| {
                let l = layout::layout(black_box(&m.welded), black_box(&m.edges), DEFAULT_MAX_MULT);
                let mesh = MeshPayload {
                    header: m.header.meshes[0].clone(),
                    caps: &l.caps,
                    buckets: l.buckets.iter().map(|b| b.data.as_slice()).collect(),
                };
                format::write_file(&whole_out, m.header.clone(), &[mesh], None).unwrap()
            },
            BatchSize::PerIteration,
        )
    });
    let streamed_out = scratch.join(format!("{n}.streamed.svpk"));
    g.bench_function(format!("streamed/{n}"), |b| {
        b.iter_batched(
            || fresh(&streamed_out),
            |()| {
                let plan = layout::Plan::new(
                    black_box(&m.edges),
                    m.welded.triangle_count(),
                    DEFAULT_MAX_MULT,
                );
                let records = plan.records(&m.welded, &m.edges);
                format::write_file_streamed(
                    &streamed_out,
                    m.header.clone(),
                    m.header.meshes[0].clone(),
                    &records,
                )
                .unwrap()
            },
            BatchSize::PerIteration,
        )
    });
    g.finish();
    // (Both files exist only when a filter ran both benchmarks.)
    if let (Ok(whole), Ok(streamed)) = (std::fs::read(&whole_out), std::fs::read(&streamed_out)) {
        assert!(
            whole == streamed,
            "{n}: streamed and whole-buffer files differ"
        );
    }

    let light = [3.0, 2.5, 4.0, 1.0];
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut g = group(c, "evaluate", m);
    g.bench_function(format!("reference_1t/{n}"), |b| {
        let mut sides: Vec<Vec<i8>> = m
            .layout
            .buckets
            .iter()
            .map(|x| vec![0; x.instances as usize])
            .collect();
        let mut caps = vec![0i8; m.layout.caps.len() / 12];
        b.iter(|| {
            pool.install(|| {
                for (bk, o) in m.layout.buckets.iter().zip(sides.iter_mut()) {
                    side_multiplicities_with(
                        Strategy::Reference,
                        bk.k as usize,
                        &bk.data,
                        light,
                        o,
                    );
                }
                cap_signs_with(Strategy::Reference, &m.layout.caps, light, &mut caps);
            })
        })
    });
    g.finish();

    let mut g = group(c, "weld+topology+layout", m);
    g.bench_function(format!("ours/{n}"), |b| {
        b.iter(|| build_soup(black_box(&m.soup), DEFAULT_MAX_MULT))
    });
    g.bench_function(format!("ours_buckets/{n}"), |b| {
        b.iter(|| peers::ours_buckets(black_box(&m.soup)))
    });
    // The same under an `alloc::KeepFreed` guard held across the
    // iterations, so that each run gets the blocks the run before freed,
    // as a batch's later inputs do: without it every run faults in fresh
    // pages, while meshoptimizer's own buffers (C++, glibc's malloc) are
    // served from memory the runs before freed, but for the ones above
    // glibc's mmap threshold (on the dragon 8,193–8,203 small-page faults
    // a run, against ours 11,311–11,707 with the huge-page hint paused:
    // `stage_probe -- buckets`, twenty-seventh round).
    g.bench_function(format!("ours_buckets_kept/{n}"), |b| {
        let _keep = svpack::alloc::KeepFreed::new();
        b.iter(|| peers::ours_buckets(black_box(&m.soup)))
    });
    g.bench_function(format!("meshopt_adjacency/{n}"), |b| {
        b.iter(|| {
            peers::meshopt_adjacency(black_box(&m.soup.positions), black_box(&m.soup.indices))
        })
    });
    g.finish();
}

fn stages(c: &mut Criterion) {
    let scratch = tempfile::tempdir().unwrap();
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes");
    let mut inputs: Vec<(String, PathBuf)> = Vec::new();
    for (name, rel) in [
        ("dragon_res4", "obj/dragon_vrip_res4.obj"),
        ("armadillo", "obj/armadillo.obj"),
        ("2CylinderEngine", "gltf/2CylinderEngine.glb"),
    ] {
        let p = shared.join(rel);
        if p.exists() {
            inputs.push((name.into(), p));
        } else {
            eprintln!("skipping {name}: {} is absent", p.display());
        }
    }
    // The full Stanford dragon (871k triangles) when benches/fetch_dragon.sh
    // has fetched it.
    let dragon = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/dragon/dragon.obj");
    if dragon.exists() {
        inputs.push(("dragon_full".into(), dragon));
    } else {
        eprintln!(
            "skipping dragon_full: run benches/fetch_dragon.sh to fetch {}",
            dragon.display()
        );
    }
    // SVPACK_BENCH_SCENE=N sets the generated scene's size (default 1M).
    let scene_triangles = std::env::var("SVPACK_BENCH_SCENE")
        .ok()
        .map(|v| v.parse().expect("SVPACK_BENCH_SCENE: a triangle count"))
        .unwrap_or(SCENE_TRIANGLES);
    let scene_name = format!("scene_{}k", scene_triangles / 1000);
    let scene = scratch.path().join(format!("{scene_name}.obj"));
    let file = std::fs::File::create(&scene).unwrap();
    scene::write_scene(std::io::BufWriter::new(file), scene_triangles).unwrap();
    inputs.push((scene_name, scene));
    // SVPACK_BENCH_ONLY=name,name keeps only those inputs.
    if let Ok(only) = std::env::var("SVPACK_BENCH_ONLY") {
        let keep: Vec<&str> = only.split(',').collect();
        inputs.retain(|(name, _)| keep.contains(&name.as_str()));
    }
    for (name, path) in &inputs {
        let m = prepare(name, path, scratch.path());
        bench_mesh(c, &m, scratch.path());
    }
}

criterion_group!(benches, stages);
criterion_main!(benches);
