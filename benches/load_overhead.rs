//! Our loaders' overhead on top of the parsers they call, measured so that
//! this machine's drift cannot decide the answer.
//!
//! Each round runs, back to back and in a rotating order, the peer (the
//! parser alone: `tobj::load_obj_buf` for OBJ, the gltf crate's parse and
//! accessor readers for glTF, both including the file read; see
//! `common/peers.rs`) and `svpack::load::load` in a 1-thread and a 2-thread
//! rayon pool. A slow patch of the machine then hits all three in the same
//! round, so the per-round ratio ours / peer is steadier than two criterion
//! groups run a minute apart (where this VM's noise was larger than the
//! overhead being measured). Reported per input: fastest and median time of
//! each, the overhead of the fastest against the fastest, the median of
//! the per-round overheads, and the time of the input's SHA-256 alone over
//! as many bytes as the loader reads (MB: file plus external buffers).
//!
//! What "ours" adds on top of the peer: the input's SHA-256 (beside the
//! parse when there are 2 threads, inline with 1), the OBJ pre-scan and
//! triangulation, or the glTF node walk, accessor checks and decoding.
//!
//! Inputs: OBJ and glTF models from ../shared/meshes, the full Stanford
//! dragon when `benches/fetch_dragon.sh` has fetched it, a generated scene
//! of `SVPACK_BENCH_SCENE` triangles (default 1M) as OBJ, and the largest of
//! those soups written as one binary glTF (f32 positions, u32 indices), so
//! the glTF loader is also measured on a large file. `SVPACK_BENCH_ROUNDS`
//! (default 11) sets the rounds; `SVPACK_BENCH_ONLY=a,b` keeps named inputs.
//!
//! `cargo bench --bench load_overhead`

use std::path::{Path, PathBuf};
use std::time::Instant;
use svpack::load::{self, Soup};

/// The allocator `svpack` itself runs with, so times match the CLI's.
#[global_allocator]
static ALLOC: svpack::alloc::HugePageAlloc = svpack::alloc::HugePageAlloc;

#[path = "../examples/scene.rs"]
mod scene;

#[path = "common/peers.rs"]
#[allow(dead_code)] // (The weld's peer is the stages bench's.)
mod peers;

/// Writes `soup` as a binary glTF: one buffer (positions as f32 VEC3, then
/// indices as u32), one mesh with one triangle primitive, one node.
fn write_glb(soup: &Soup, path: &Path) {
    let pos_bytes: &[u8] = bytemuck::cast_slice(&soup.positions);
    let idx_bytes: &[u8] = bytemuck::cast_slice(&soup.indices);
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for p in &soup.positions {
        for a in 0..3 {
            min[a] = min[a].min(p[a]);
            max[a] = max[a].max(p[a]);
        }
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0", "generator": "svpack load_overhead bench"},
        "buffers": [{"byteLength": pos_bytes.len() + idx_bytes.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_bytes.len(), "target": 34962},
            {"buffer": 0, "byteOffset": pos_bytes.len(), "byteLength": idx_bytes.len(), "target": 34963}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": soup.positions.len(),
             "type": "VEC3", "min": min, "max": max},
            {"bufferView": 1, "componentType": 5125, "count": soup.indices.len(), "type": "SCALAR"}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0
    });
    let mut json = serde_json::to_vec(&json).unwrap();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    // Both sections are multiples of 4 bytes (f32 and u32 elements).
    let bin_len = pos_bytes.len() + idx_bytes.len();
    let total = 12 + 8 + json.len() + 8 + bin_len;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin_len as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(pos_bytes);
    out.extend_from_slice(idx_bytes);
    std::fs::write(path, out).unwrap();
}

/// Wall seconds of `f`.
fn timed(f: impl FnOnce()) -> f64 {
    let t = Instant::now();
    f();
    t.elapsed().as_secs_f64()
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn ms(d: f64) -> String {
    format!("{:.2}", d * 1e3)
}

fn main() {
    // `cargo bench` passes `--bench` (and filters); this harness takes none.
    let rounds: usize = std::env::var("SVPACK_BENCH_ROUNDS")
        .ok()
        .map(|v| v.parse().expect("SVPACK_BENCH_ROUNDS: a number"))
        .unwrap_or(11);
    let scratch = tempfile::tempdir().unwrap();
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/meshes");
    let mut inputs: Vec<(String, PathBuf)> = Vec::new();
    for (name, rel) in [
        ("dragon_res4", "obj/dragon_vrip_res4.obj"),
        ("bunny", "obj/stanford-bunny.obj"),
        ("armadillo", "obj/armadillo.obj"),
        ("2CylinderEngine", "gltf/2CylinderEngine.glb"),
        ("FlightHelmet", "gltf/FlightHelmet/FlightHelmet.gltf"),
    ] {
        let p = shared.join(rel);
        if p.exists() {
            inputs.push((name.into(), p));
        } else {
            eprintln!("skipping {name}: {} is absent", p.display());
        }
    }
    let dragon = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/dragon/dragon.obj");
    if dragon.exists() {
        inputs.push(("dragon_full".into(), dragon));
    } else {
        eprintln!("skipping dragon_full: run benches/fetch_dragon.sh");
    }
    let scene_triangles: u64 = std::env::var("SVPACK_BENCH_SCENE")
        .ok()
        .map(|v| v.parse().expect("SVPACK_BENCH_SCENE: a triangle count"))
        .unwrap_or(1_000_000);
    let scene_name = format!("scene_{}k", scene_triangles / 1000);
    let scene_path = scratch.path().join(format!("{scene_name}.obj"));
    let file = std::fs::File::create(&scene_path).unwrap();
    scene::write_scene(std::io::BufWriter::new(file), scene_triangles).unwrap();
    inputs.push((scene_name, scene_path));
    // The largest OBJ soup again, as a binary glTF.
    let (big_name, big_path) = inputs.last().cloned().unwrap();
    let big = inputs
        .iter()
        .filter(|(_, p)| p.extension().is_some_and(|e| e == "obj"))
        .map(|(n, p)| (n, p, std::fs::metadata(p).unwrap().len()))
        .max_by_key(|x| x.2)
        .map(|(n, p, _)| (n.clone(), p.clone()))
        .unwrap_or((big_name, big_path));
    let soup = load::load(&big.1).unwrap();
    let glb = scratch.path().join(format!("{}.glb", big.0));
    write_glb(&soup, &glb);
    drop(soup);
    inputs.push((format!("{}_glb", big.0), glb));
    if let Ok(only) = std::env::var("SVPACK_BENCH_ONLY") {
        let keep: Vec<&str> = only.split(',').collect();
        inputs.retain(|(name, _)| keep.contains(&name.as_str()));
    }

    let pool = |n| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
    };
    let (pool1, pool2) = (pool(1), pool(2));
    println!(
        "| input | MB | triangles | peer fastest / median (ms) | ours 1 thread | ours 2 threads | overhead 1 thread: fastest, median of rounds | overhead 2 threads: fastest, median of rounds | SHA-256 of the input alone, fastest (ms) | SHA-256 / peer fastest |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (name, path) in &inputs {
        let is_obj = path.extension().is_some_and(|e| e == "obj");
        let peer = || {
            timed(|| {
                if is_obj {
                    std::hint::black_box(peers::tobj_load(path));
                } else {
                    std::hint::black_box(peers::gltf_crate_load(path));
                }
            })
        };
        let ours = |p: &rayon::ThreadPool| {
            p.install(|| timed(|| drop(std::hint::black_box(load::load(path).unwrap()))))
        };
        // One warm-up of each (page cache, allocator, pools).
        peer();
        ours(&pool1);
        ours(&pool2);
        let triangles = load::load(path).unwrap().triangle_count();
        // The input digest alone, over as many bytes as the loader reads
        // (SHA-256 time does not depend on the content): what one thread
        // must add to the parse, and what a second thread hides.
        let read_bytes = load::load(path).unwrap().input_bytes as usize;
        let filler = vec![0x5au8; read_bytes];
        let digest = || {
            timed(|| {
                std::hint::black_box(load::InputDigest::of(&filler));
            })
        };
        let mut times: [Vec<f64>; 4] = Default::default();
        for r in 0..rounds {
            for k in 0..4 {
                let which = (r + k) % 4;
                let wall = match which {
                    0 => peer(),
                    1 => ours(&pool1),
                    2 => ours(&pool2),
                    _ => digest(),
                };
                times[which].push(wall);
            }
        }
        let fastest: Vec<f64> = times
            .iter()
            .map(|t| t.iter().copied().fold(f64::INFINITY, f64::min))
            .collect();
        let med: Vec<f64> = times.iter().map(|t| median(&mut t.clone())).collect();
        let overhead = |k: usize| {
            let mut per_round: Vec<f64> = (0..rounds)
                .map(|r| times[k][r] / times[0][r] - 1.0)
                .collect();
            format!(
                "{:+.1}%, {:+.1}%",
                (fastest[k] / fastest[0] - 1.0) * 100.0,
                median(&mut per_round) * 100.0
            )
        };
        println!(
            "| {name} | {:.1} | {triangles} | {} / {} | {} / {} | {} / {} | {} | {} | {} | {:+.1}% |",
            read_bytes as f64 / 1e6,
            ms(fastest[0]),
            ms(med[0]),
            ms(fastest[1]),
            ms(med[1]),
            ms(fastest[2]),
            ms(med[2]),
            overhead(1),
            overhead(2),
            ms(fastest[3]),
            (fastest[3] / fastest[0]) * 100.0,
        );
    }
}
