//! The build pipeline: load → check → weld → topology → layout → write.

use crate::error::{Error, Result};
use crate::format::{
    self, BucketHeader, BuildOptions, Encoding, Header, HistogramEntry, InputInfo, MeshHeader,
    MeshPayload, MeshStats, Section,
};
use crate::layout::{self, Layout, MAX_MAX_MULT, Plan};
use crate::load::{self, Soup};
use crate::quantize::{self, RecordSpace};
use crate::topology::{self, Edges};
use crate::weld::{self, Welded};
use std::path::Path;
use std::time::{Duration, Instant};

/// Options of one build.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BuildConfig {
    /// K: largest opposite-vertex count per side instance (1..=13).
    pub max_mult: u32,
    /// Wrap the output in a zstd frame at this level (one of
    /// [`format::ZSTD_LEVELS`]; [`format::ZSTD_LEVEL`] is `--compress`'s),
    /// or write it plain.
    pub compress: Option<i32>,
    /// How positions are stored (f32, or 16-bit quantised over the mesh bounds).
    pub positions: Encoding,
}

impl Default for BuildConfig {
    fn default() -> Self {
        BuildConfig {
            max_mult: layout::DEFAULT_MAX_MULT,
            compress: None,
            positions: Encoding::F32,
        }
    }
}

/// Everything the pipeline computed for one mesh, before writing.
#[derive(Debug, Clone)]
pub struct Built {
    /// Welded triangles and positions.
    pub welded: Welded,
    /// Edge structure.
    pub edges: Edges,
    /// Sides and caps buffers.
    pub layout: Layout,
    /// Statistics for the header.
    pub stats: MeshStats,
    /// Loader warnings.
    pub warnings: Vec<String>,
}

/// Wall time of each build stage, in milliseconds (`build --timings`).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct Timings {
    /// Reading and parsing the input (OBJ or glTF), and checking it.
    pub load: f64,
    /// Quantising (unorm16 only) and welding.
    pub weld: f64,
    /// Edges and opposite vertices, and their statistics; on an
    /// uncompressed file with header room (`format::header_room`), also
    /// the caps (with one thread written from the soup before the edges
    /// are made, `layout::SoupCaps`; with more, beside the edges), and with
    /// two threads or more on a mesh whose every fan is even the side
    /// blocks written as the edges are finished
    /// (`layout::write_sides_ahead`).
    pub topology: f64,
    /// Buckets and splitting (the counting pass, [`Plan`]); with
    /// `--compress` also filling the sides and caps buffers.
    pub layout: f64,
    /// Encoding and writing the file. Without `--compress` this includes
    /// filling the sides and caps records (those not written under
    /// `topology`), which go straight into the file
    /// (`format::write_file_streamed`); with it, compressing whole buffers.
    /// Rebuilding in place, removing the old output is in this stage when
    /// the build removes it itself ([`build_file`]), and in none when a
    /// batch's removing thread does ([`build_batch`], the command line;
    /// `crate::removals`).
    pub write: f64,
    /// The whole build.
    pub total: f64,
    /// Of `topology`, `layout` and `write`: the time inside the calls
    /// that copied the output into the file (`format::Written::write_calls`),
    /// summed over the threads that made them, so with two threads or
    /// more it can exceed the stages' wall time. Nothing svpack computes
    /// is in it: it is the floor the page cache sets under those stages.
    pub write_calls: f64,
}

/// Peak resident memory of this process so far, in bytes (Linux:
/// `VmHWM` of /proc/self/status; `None` elsewhere).
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Sets the process's peak memory (`VmHWM`) back to its resident size now,
/// so that [`peak_memory_bytes`] then gives the peak from this moment on
/// (Linux 4.0 and later: `/proc/self/clear_refs`). False where that cannot
/// be done; the peak then keeps covering the process's whole life.
///
/// Why: `svpack bench --parallel` runs many builds in one process, and the
/// process's peak only grows; reset before each build, it is that build's.
pub fn reset_peak_memory() -> bool {
    std::fs::write("/proc/self/clear_refs", b"5").is_ok()
}

/// A stage reported to a progress callback: its name, as it starts.
pub type StageCallback<'a> = &'a (dyn Fn(&'static str) + Sync);

/// Result of [`build_file`].
#[derive(Debug, Clone)]
pub struct BuildOutput {
    /// The header as written.
    pub header: Header,
    /// Bytes on disk.
    pub file_bytes: u64,
    /// Wall time of the whole build.
    pub elapsed: Duration,
    /// Wall time per stage.
    pub timings: Timings,
    /// Loader warnings.
    pub warnings: Vec<String>,
    /// Bytes the build's write calls put into the file
    /// (`format::Written::write_bytes`): `file_bytes` (less the zero gaps
    /// between sections, in an uncompressed file), plus whatever was
    /// moved within the file or written again.
    pub write_bytes: u64,
}

/// Rejects non-finite positions used by any triangle and out-of-range
/// indices, naming the part they come from.
///
/// Method: two linear passes settle the usual case, every index in range
/// and every position finite (`max` and a finiteness fold vectorise).
/// Only when either fails are the corners walked in triangle order, one
/// gathered position each, to find and name the first problem; a
/// non-finite position no triangle uses is then no error. The walk alone
/// took 6 ms of a 1-thread build of the 871k-triangle dragon (`perf`).
pub fn check_soup(path: &Path, soup: &Soup) -> Result<()> {
    check_soup_in(path, soup, true)
}

/// [`check_soup`], its fast path on this thread alone unless `parallel`
/// (for a check that runs beside another thread's work, see
/// `load::gltf::load_gltf_deferred`).
fn check_soup_in(path: &Path, soup: &Soup, parallel: bool) -> Result<()> {
    if !soup.indices.len().is_multiple_of(3) {
        return Err(Error::input(path, "index count is not a multiple of 3"));
    }
    use rayon::prelude::*;
    let n = soup.positions.len();
    // The fast path: every index in range and every position finite, in
    // blocks on all threads (one pass over the dragon's 15 MB: 0.77 ms
    // serial, 0.51 ms with two threads when hot; `perf` put about 2 ms of
    // a one-thread build in it, cold). A fold, not `iter().max()`: that
    // tracks a reference and does not vectorise.
    let largest_of = |c: &[u32]| c.iter().fold(0, |m, &i| m.max(i));
    let largest = if parallel {
        soup.indices
            .par_chunks(CHECK_BLOCK)
            .map(largest_of)
            .reduce(|| 0, u32::max)
    } else {
        largest_of(&soup.indices)
    };
    let in_range = soup.indices.is_empty() || (largest as usize) < n;
    let finite = |c: &[[f32; 3]]| {
        c.iter().fold(true, |ok, p| {
            ok & p[0].is_finite() & p[1].is_finite() & p[2].is_finite()
        })
    };
    let all_finite = || {
        if parallel {
            soup.positions.par_chunks(CHECK_BLOCK).all(finite)
        } else {
            finite(&soup.positions)
        }
    };
    if in_range && all_finite() {
        return Ok(());
    }
    for (t, c) in soup.indices.chunks_exact(3).enumerate() {
        for &i in c {
            let where_ = || {
                soup.parts
                    .iter()
                    .find(|p| {
                        (t as u32) >= p.first_triangle
                            && (t as u32) < p.first_triangle + p.triangle_count
                    })
                    .map(|p| format!(" in {}", p.name))
                    .unwrap_or_default()
            };
            if i as usize >= n {
                return Err(Error::input(
                    path,
                    format!(
                        "triangle {t}{}: vertex index {i} out of range ({n} vertices)",
                        where_()
                    ),
                ));
            }
            let p = soup.positions[i as usize];
            if !p.iter().all(|v| v.is_finite()) {
                return Err(Error::input(
                    path,
                    format!(
                        "triangle {t}{}: vertex {i} has a non-finite position ({}, {}, {})",
                        where_(),
                        p[0],
                        p[1],
                        p[2]
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Runs weld, topology and layout on a checked soup.
pub fn build_soup(soup: &Soup, max_mult: u32) -> Built {
    build_soup_timed(soup, max_mult, &mut Timings::default(), &|_| {})
}

/// [`build_soup`], adding each stage's wall time to `t` and announcing each
/// stage to `stage` as it starts.
///
/// The stages run as one job on rayon's pool (see `crate::pool`).
pub fn build_soup_timed(
    soup: &Soup,
    max_mult: u32,
    t: &mut Timings,
    stage: StageCallback<'_>,
) -> Built {
    crate::pool::one_job(|| build_soup_stages(soup, max_mult, t, stage))
}

/// The stages of [`build_soup_timed`].
fn build_soup_stages(
    soup: &Soup,
    max_mult: u32,
    t: &mut Timings,
    stage: StageCallback<'_>,
) -> Built {
    let (welded, edges) = weld_and_topology(soup, t, stage);
    stage("layout");
    let i = Instant::now();
    let plan = Plan::new(&edges, welded.triangle_count(), max_mult);
    let layout = layout::layout_planned(&welded, &edges, &plan);
    t.layout += ms(i);
    let stats = mesh_stats(soup, soup.triangle_count(), &welded, &plan);
    Built {
        welded,
        edges,
        layout,
        stats,
        warnings: soup.stats.warnings.clone(),
    }
}

/// Milliseconds since `i`.
fn ms(i: Instant) -> f64 {
    i.elapsed().as_secs_f64() * 1e3
}

/// Weld and topology of a checked soup, timed into `t`.
fn weld_and_topology(soup: &Soup, t: &mut Timings, stage: StageCallback<'_>) -> (Welded, Edges) {
    let welded = timed_weld(soup, true, t, stage);
    stage("topology");
    let i = Instant::now();
    let edges = topology::build_edges(&welded.triangles, welded.positions.len());
    t.topology += ms(i);
    (welded, edges)
}

/// Welds a checked soup, timed into `t`; with [`Welded::source_triangle`]
/// only when `sources`.
fn timed_weld(soup: &Soup, sources: bool, t: &mut Timings, stage: StageCallback<'_>) -> Welded {
    stage("weld");
    let i = Instant::now();
    let welded = if sources {
        weld::weld(&soup.positions, &soup.indices)
    } else {
        weld::weld_without_sources(&soup.positions, &soup.indices)
    };
    t.weld += ms(i);
    crate::trace::since("weld", i);
    welded
}

/// The header's statistics of one mesh (`input_triangles`: the soup's
/// triangle count, passed because a build frees the soup's indices early).
fn mesh_stats(soup: &Soup, input_triangles: usize, welded: &Welded, plan: &Plan) -> MeshStats {
    let es = plan.edge_stats();
    MeshStats {
        primitives: soup.stats.primitives,
        input_triangles: input_triangles as u64,
        input_vertices: soup.input_vertices,
        welded_vertices: welded.positions.len() as u64,
        degenerate_triangles: welded.degenerate(),
        skipped_points: soup.stats.skipped_points,
        skipped_lines: soup.stats.skipped_lines,
        // (Not the welded mesh's: a one-thread build gives its triangles
        // to the topology.)
        triangles: plan.triangles() as u64,
        edges: es.edges,
        edge_instances: plan.edge_instances(),
        open_edges: es.open_edges,
        non_manifold_edges: es.non_manifold_edges,
        max_fan: es.max_fan,
        histogram: es
            .histogram
            .iter()
            .map(|&(opposites, edges)| HistogramEntry { opposites, edges })
            .collect(),
    }
}

/// Axis-aligned bounds of `positions` (zeros when empty). NaN coordinates
/// are passed over (all NaN: infinite bounds); between a `-0.0` and a
/// `+0.0` the comparisons keep the one they met first, in a fixed order,
/// so the result depends on the input only. (A build's welded positions
/// have no `-0.0`.)
///
/// Why 48 lanes: the positions are read as one flat array, 16 at a time,
/// each float into its own lane (lane `i` holds component `i % 3`), so the
/// compare-and-select compiles to vector min and max instructions; the
/// lanes are combined at the end. A loop of `f32::min` over the positions
/// one by one was 2.3–3.0 ms of a one-thread build of the dragon (435k
/// positions), serial with any number of threads.
pub fn bounds(positions: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    const LANES: usize = 48;
    if positions.is_empty() {
        return ([0.0; 3], [0.0; 3]);
    }
    // `x < lo` is false for NaN, which therefore never replaces a bound.
    let take = |lo: &mut f32, hi: &mut f32, x: f32| {
        *lo = if x < *lo { x } else { *lo };
        *hi = if x > *hi { x } else { *hi };
    };
    let flat: &[f32] = bytemuck::cast_slice(positions);
    let mut lo = [f32::INFINITY; LANES];
    let mut hi = [f32::NEG_INFINITY; LANES];
    let mut steps = flat.chunks_exact(LANES);
    for step in &mut steps {
        for i in 0..LANES {
            take(&mut lo[i], &mut hi[i], step[i]);
        }
    }
    // The last positions (fewer than 16) start again at lane 0, which keeps
    // lane i on component i % 3 (48 is a multiple of 3).
    for (i, &x) in steps.remainder().iter().enumerate() {
        take(&mut lo[i], &mut hi[i], x);
    }
    let (mut out_lo, mut out_hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for i in 0..LANES {
        // Lanes no position reached still hold ±infinity, which the other
        // side's comparison never takes.
        let (l, h) = (&mut out_lo[i % 3], &mut out_hi[i % 3]);
        *l = if lo[i] < *l { lo[i] } else { *l };
        *h = if hi[i] > *h { hi[i] } else { *h };
    }
    (out_lo, out_hi)
}

/// Elements per parallel block of [`check_soup`]'s checks (exact, so the
/// result does not depend on how the blocks are combined).
const CHECK_BLOCK: usize = 1 << 16;

/// The last component of `path` as text (empty when it has none): the
/// name a header, a summary or a bench report gives an input.
pub(crate) fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Builds `input` into the file `output`.
pub fn build_file(input: &Path, output: &Path, cfg: &BuildConfig) -> Result<BuildOutput> {
    build_file_with(input, output, cfg, &|_| {})
}

/// [`build_file`], announcing each stage ("load", "weld", "topology",
/// "layout", "write") to `stage` as it starts (for progress display).
///
/// The build runs as one job on rayon's pool (see `crate::pool`), as the
/// command line's builds do (`build_batch_with` runs them on its pool).
pub fn build_file_with(
    input: &Path,
    output: &Path,
    cfg: &BuildConfig,
    stage: StageCallback<'_>,
) -> Result<BuildOutput> {
    crate::pool::one_job(|| build_file_stages(input, output, cfg, stage))
}

/// The stages of [`build_file_with`].
fn build_file_stages(
    input: &Path,
    output: &Path,
    cfg: &BuildConfig,
    stage: StageCallback<'_>,
) -> Result<BuildOutput> {
    if cfg.max_mult == 0 || cfg.max_mult > MAX_MAX_MULT {
        return Err(Error::Other(format!(
            "--max-mult must be between 1 and {MAX_MAX_MULT} (got {})",
            cfg.max_mult
        )));
    }
    // Freed stage buffers (the soup after welding, the listings after the
    // topology) are handed to the next stage's allocations instead of going
    // back to the system (`crate::alloc`); given back when the build ends.
    let _keep = crate::alloc::KeepFreed::new();
    let start = Instant::now();
    let mut timings = Timings::default();
    stage("load");
    let data = load::read_file(input)?;
    let fmt = load::detect_format(input, &data)?;
    // The output's page cache, about 8 bytes per input byte (the dragon:
    // 125 MB from a 16 MB GLB, a third of that from its OBJ), competes
    // with small pages for warm memory (`alloc::reserve_page_cache`);
    // set to the output the triangles are expected to give once they are
    // loaded.
    let mut page_cache = crate::alloc::reserve_page_cache(8 * data.len() as u64);
    // A glTF's soup is checked by its loader while the input's digest runs
    // on, and the digest's last bytes are hashed while the payload is
    // written (`load_gltf_deferred`, `load::DigestSlices`); an OBJ's
    // digest ends long before the parse, so its check comes after, on all
    // threads.
    let (mut soup, digest) = match fmt {
        load::Format::Gltf => {
            load::gltf::load_gltf_deferred(input, data, |s| check_soup_in(input, s, false))?
        }
        load::Format::Obj => {
            let soup = load::obj::load_obj(input, data)?;
            check_soup(input, &soup)?;
            let digest = load::PendingDigest::Done(soup.input_bytes, soup.input_sha256);
            (soup, digest)
        }
    };
    timings.load = ms(start);
    crate::trace::since("load", start);
    // What the output is expected to take (`layout::expected_payload_bytes`,
    // with room for the largest header), against 8 bytes per input byte
    // before parsing: the 5M scene (OBJ text, 41 bytes a triangle) 1.6 GB
    // then, 0.74 GB now, for a 721 MB output.
    page_cache.resize(
        format::PREAMBLE_LEN as u64
            + format::HEADER_LIMIT as u64
            + layout::expected_payload_bytes(
                soup.triangle_count() as u64,
                soup.positions.len() as u64,
                cfg.positions.vec4_bytes(),
            ),
    );
    let quantise_start = Instant::now();
    // Quantising comes before welding (see `quantize`): positions that share a
    // code weld together and collapsed triangles count as degenerate.
    let (space, world_bounds) = match cfg.positions {
        Encoding::F32 => (RecordSpace::IDENTITY, None),
        Encoding::Unorm16 => {
            let (lo, hi) = quantize::used_bounds(&soup.positions, &soup.indices);
            (RecordSpace::unorm16_box(lo, hi), Some((lo, hi)))
        }
    };
    if cfg.positions != Encoding::F32 {
        soup.positions = quantize::to_record_space(&soup.positions, &space, cfg.positions);
    }
    timings.weld = ms(quantise_start);
    // Without the welded triangles' sources (for `lint` only).
    let mut welded = timed_weld(&soup, false, &mut timings, stage);
    // (The one count of the soup the header needs that freeing it loses.)
    let input_triangles = soup.triangle_count();
    // The headers, with what the edges decide (statistics, buckets) and
    // the bounds still to come; their length is all `format::AheadFile` needs.
    let name = input
        .file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut mesh_header = MeshHeader {
        name,
        bounds_min: [0.0; 3],
        bounds_max: [0.0; 3],
        position_offset: space.offset,
        position_scale: space.scale,
        stats: MeshStats::default(),
        caps: Section {
            offset: 0,
            length: 0,
            count: 0,
        },
        buckets: Vec::new(),
    };
    let mut header = Header {
        payload_offset: 0,
        payload_len: 0,
        payload_crc32: 0,
        generator: generator(),
        input: InputInfo {
            file_name: file_name(input),
            format: match fmt {
                load::Format::Gltf => "gltf".into(),
                load::Format::Obj => "obj".into(),
            },
            // Set from `digest` as the file is written.
            bytes: 0,
            sha256: [0; 32],
        },
        options: BuildOptions {
            max_mult: cfg.max_mult,
            compress: cfg.compress.is_some(),
            positions: cfg.positions.code(),
        },
        bounds_min: [0.0; 3],
        bounds_max: [0.0; 3],
        meshes: Vec::new(),
        reserved: 0,
    };
    // The edges (only their opposite vertices: nothing reads the opposite
    // vertices' triangles), and an uncompressed file's caps written early
    // (`format::AheadFile`): a file with header room
    // (`format::header_room`) starts its payload at an offset the edges do
    // not change (unless its mesh has more distinct opposite counts than
    // the room holds: then the writer moves the caps up within the file,
    // `format::write_file_streamed_finishing`). With two
    // threads or more the caps are written beside the edges, and the side
    // blocks as the edges are finished, where the first bucket is bucket
    // 2 (benches/ROUNDS.md, "Eighteenth round" and "Nineteenth round");
    // with one, the caps are written from the soup before it is freed
    // ("Twenty-second round").
    stage("topology");
    let i = Instant::now();
    let triangles = welded.triangle_count() as u64;
    let early = MeshHeader {
        stats: MeshStats {
            triangles,
            ..MeshStats::default()
        },
        ..mesh_header.clone()
    };
    let ahead_wanted = cfg.compress.is_none()
        && format::header_room(&Header {
            meshes: vec![early.clone()],
            ..header.clone()
        })?
        .is_some();
    let two_threads = rayon::current_num_threads() >= 2;
    // What is left of the input's digest, hashed a slice at a time by
    // threads waiting to write (here, or while the file is written ahead).
    let digest = load::DigestSlices::new(digest);
    let ahead_file = ahead_wanted
        .then(|| format::AheadFile::new(output, header.clone(), early))
        .transpose()?;
    // With one thread, the caps go into the file first, from the soup
    // (`layout::SoupCaps`: its corners are near each other, the welded
    // mesh's are not).
    if let (Some(file), false) = (&ahead_file, two_threads) {
        let caps = layout::SoupCaps::new(&soup.positions, &soup.indices, &welded);
        write_caps_ahead(file, &caps, &digest, &Default::default())?;
    }
    // What the rest of the build does not read is freed before topology
    // allocates, which then reuses those pages: the soup (the welded mesh
    // replaces it). Faulting in pages the process has never touched is the
    // slow part of a fresh buffer, especially in a VM (benches/ROUNDS.md,
    // "Fifth round").
    (soup.positions, soup.indices) = (Vec::new(), Vec::new());
    // With a file to write ahead into, the welded triangles go to the
    // topology, which frees them once it has listed them
    // (`topology::build_edges_opposites_only_owned`): with one thread the
    // caps are written by then. With two, the caps are copied from the
    // welded triangles beside the topology, which shares them
    // (`_shared_fed`), and they are freed once both are done with them.
    // If the header then outgrows its room, the caps are moved within the
    // file, not filled again (`format::write_file_streamed_finishing`).
    let kept_triangles = welded.triangle_count();
    let give_triangles = ahead_file.is_some();
    let mut own_triangles = if give_triangles {
        std::mem::take(&mut welded.triangles)
    } else {
        Vec::new()
    };
    let shared = match &ahead_file {
        Some(_) if two_threads => Some(std::sync::Arc::new(std::mem::take(&mut own_triangles))),
        _ => None,
    };
    // The caps' copy, by units any thread may take
    // (`format::AheadFile::write_shared`): the thread that took it from
    // the join below, and the topology's thread after its pass 1 when the
    // emit is not fed (a mesh with open edges: its emit then runs on both
    // threads, so the caps had better be written by then). The copy's
    // share of the triangles goes once no unit is left to take.
    let caps_next = std::sync::atomic::AtomicUsize::new(0);
    let caps_triangles = std::sync::Mutex::new(shared.clone());
    let copy_caps = |file: &format::AheadFile| -> Result<()> {
        let lock = || caps_triangles.lock().unwrap_or_else(|e| e.into_inner());
        let Some(triangles) = lock().clone() else {
            return Ok(());
        };
        let caps = layout::CapsRecords::from_parts(&welded.positions, &triangles);
        let copied = write_caps_ahead(file, &caps, &digest, &caps_next);
        *lock() = None;
        copied
    };
    let mut helped = Ok(());
    let mut counted = |fed: bool| {
        if let (Some(file), false) = (&ahead_file, fed) {
            helped = copy_caps(file);
        }
    };
    // With a file to write ahead into, the side blocks are copied while the
    // edges are made (`layout::write_sides_ahead`) on the thread that
    // copied the caps.
    let mut sides_ahead = Ok(());
    let (edges, caps_ahead) = rayon::join(
        || match (ahead_file.as_ref().filter(|_| two_threads), shared) {
            (Some(file), Some(triangles)) => {
                let mut consumer = |feed: &topology::EmitFeed| {
                    sides_ahead = layout::write_sides_ahead(
                        feed,
                        &welded,
                        kept_triangles,
                        cfg.max_mult,
                        file,
                        &|| digest.step(),
                    );
                };
                topology::build_edges_opposites_only_shared_fed(
                    triangles,
                    welded.positions.len(),
                    &mut consumer,
                    &mut counted,
                )
            }
            _ if give_triangles => {
                topology::build_edges_opposites_only_owned(own_triangles, welded.positions.len())
            }
            _ => topology::build_edges_opposites_only(&welded.triangles, welded.positions.len()),
        },
        || ahead_file.as_ref().filter(|_| two_threads).map(&copy_caps),
    );
    caps_ahead.transpose()?;
    helped?;
    sides_ahead?;
    let ahead = ahead_file.map(format::AheadFile::finish);
    timings.topology += ms(i);
    crate::trace::since("topology", i);
    stage("layout");
    let i = Instant::now();
    let plan = Plan::new(&edges, triangles as usize, cfg.max_mult);
    // A compressed file is one zstd stream, written in order from whole
    // buffers; an uncompressed one is filled block by block at its offsets.
    let layout = cfg
        .compress
        .map(|level| (level, layout::layout_planned(&welded, &edges, &plan)));
    timings.layout += ms(i);
    crate::trace::since("layout", i);
    let stats = mesh_stats(&soup, input_triangles, &welded, &plan);
    if stats.triangles == 0 {
        return Err(Error::input(
            input,
            format!(
                "no triangles to build ({} input triangles, {} degenerate, {} point and {} line primitives skipped)",
                stats.input_triangles,
                stats.degenerate_triangles,
                stats.skipped_points,
                stats.skipped_lines
            ),
        ));
    }
    let (bmin, bmax) = world_bounds.unwrap_or_else(|| bounds(&welded.positions));
    (mesh_header.bounds_min, mesh_header.bounds_max) = (bmin, bmax);
    (header.bounds_min, header.bounds_max) = (bmin, bmax);
    mesh_header.stats = stats;
    mesh_header.buckets = plan
        .buckets()
        .map(|(k, instances)| BucketHeader {
            k,
            instances,
            offset: 0,
            length: 0,
        })
        .collect();
    stage("write");
    let write_start = Instant::now();
    let written = match &layout {
        Some((level, layout)) => {
            let mut header = header;
            (header.input.bytes, header.input.sha256) = digest.finish();
            let mesh = MeshPayload {
                header: mesh_header,
                caps: &layout.caps,
                buckets: layout.buckets.iter().map(|b| b.data.as_slice()).collect(),
            };
            format::write_file(output, header, &[mesh], Some(*level))?
        }
        None => {
            let records = plan.records(&welded, &edges);
            format::write_file_streamed_finishing(
                output,
                header,
                mesh_header,
                &records,
                ahead,
                &|| digest.step(),
                || digest.finish(),
            )?
        }
    };
    timings.write = ms(write_start);
    timings.write_calls = written.write_calls.as_secs_f64() * 1e3;
    crate::trace::since("write", write_start);
    timings.total = ms(start);
    Ok(BuildOutput {
        header: written.header,
        file_bytes: written.bytes,
        elapsed: start.elapsed(),
        timings,
        warnings: soup.stats.warnings,
        write_bytes: written.write_bytes,
    })
}

/// Writes `caps` (one section, the units of `layout::CapsRecords`) into
/// `file` where its caps go, its blocks up to the sides reserved first;
/// the units are taken from `next` (`format::AheadFile::write_shared`:
/// other threads may be writing the same caps). A wait for the file
/// hashes more of `digest`.
fn write_caps_ahead(
    file: &format::AheadFile,
    caps: &dyn format::PayloadSource,
    digest: &load::DigestSlices,
    next: &std::sync::atomic::AtomicUsize,
) -> Result<()> {
    file.reserve(0, file.sides_offset())?;
    let mut bufs = format::UnitBuffers::new(layout::CapsRecords::UNIT_FLOATS);
    let step = || digest.step();
    file.write_shared(caps, 0, 0, file.caps_offset(), next, &mut bufs, &step)
}

/// The generator string written into headers: "svpack" and the crate version.
pub fn generator() -> String {
    format!("svpack {}", env!("CARGO_PKG_VERSION"))
}

/// Output path of each input in a batch build: `OUTDIR/<input stem>.svpk`.
/// Two inputs with the same stem would overwrite each other, so that is an
/// error naming both (nothing is built).
pub fn batch_outputs(
    inputs: &[std::path::PathBuf],
    outdir: &Path,
) -> Result<Vec<std::path::PathBuf>> {
    let mut seen: std::collections::HashMap<std::ffi::OsString, &Path> =
        std::collections::HashMap::new();
    let mut out = Vec::with_capacity(inputs.len());
    for input in inputs {
        let stem = input
            .file_stem()
            .ok_or_else(|| Error::input(input, "input has no file name"))?;
        if let Some(prev) = seen.insert(stem.to_os_string(), input) {
            return Err(Error::Other(format!(
                "inputs {} and {} would both write {}",
                prev.display(),
                input.display(),
                outdir.join(stem).with_extension("svpk").display()
            )));
        }
        let mut name = stem.to_os_string();
        name.push(".svpk");
        out.push(outdir.join(name));
    }
    Ok(out)
}

/// The order in which [`build_batch`] starts `inputs`: by
/// [`load::work_estimate`], largest first, inputs of equal estimate in the
/// order given.
pub fn batch_order(inputs: &[std::path::PathBuf]) -> Vec<usize> {
    let work: Vec<u64> = inputs.iter().map(|i| load::work_estimate(i)).collect();
    order_by(&work)
}

/// Indices of `work`, largest first, equal ones in the order given.
fn order_by(work: &[u64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..work.len()).collect();
    order.sort_by_key(|&n| std::cmp::Reverse(work[n]));
    order
}

/// Most memory a build is expected to add at its peak per byte of its soup
/// ([`load::soup_estimate`]), in halves: 4.5 bytes. Measured peaks with two
/// threads, less the process's 6 MiB before the build: the dragon's GLB
/// 53.6 MiB from a 15.0 MiB soup (3.6 a byte), its OBJ 64.6 MiB from 31.8
/// MiB of text (4.1 a byte of half the text, which the load holds beside
/// the parsed arrays), the 5M scene's 393 MiB (4.0) (benches/ROUNDS.md,
/// Fifty-first round; `python3 benches/memory_model.py` measures them).
const PEAK_HALVES_PER_SOUP_BYTE: u64 = 9;

/// Memory a build adds at its peak whatever its size: the pool's buffers,
/// huge-page rounding of its few large blocks (2 MiB each at most), and
/// small inputs' tables. The shared models under 5 MiB of soup added 0–14
/// MiB with two threads.
const PEAK_FIXED: u64 = 16 << 20;

/// Memory a build adds per thread of its pool (each thread's own buffers).
/// 2CylinderEngine's peak rose from 13.0 to 25.7 MiB from 1 to 8 threads
/// (`--threads 8` on 2 cores), the 5M scene's from 325 to 387 MiB.
const PEAK_PER_THREAD: u64 = 2 << 20;

/// What a compressed build holds on top, per byte of soup: the zstd frame
/// is made in memory from the whole file (`format`), and a file is about 8
/// bytes per byte of soup (the dragon 119.7 MiB from 15.0, the 5M scene
/// 687.6 from 86.6). With two threads the dragon's peak rose by 155 MiB
/// with `--compress`, the 5M scene's by 682 MiB.
const FRAME_PER_SOUP_BYTE: u64 = 8;

/// What a compressed build holds on top whatever its size: zstd's workers'
/// windows and buffers.
const FRAME_FIXED: u64 = 48 << 20;

/// An estimate of the most memory the build of `input` with `cfg`, on a
/// pool of `threads` threads, adds to the process, read from the file's
/// head alone ([`load::soup_estimate`]): 4.5 bytes per byte of soup, 16 MiB,
/// and 2 MiB per thread, plus 8 bytes per byte of soup and 48 MiB when the
/// output is compressed. It is meant to be above the build's peak: it was
/// 1.2–2.2 times the peak added on the dragon and the 5M scene with one
/// and two threads, plain and compressed, more on small inputs (their
/// fixed part). What a batch under a memory budget
/// counts each input as ([`BatchConfig::max_memory`]).
pub fn memory_estimate(input: &Path, cfg: &BuildConfig, threads: usize) -> u64 {
    memory_for_soup(load::soup_estimate(input), cfg, threads)
}

/// [`memory_estimate`] of an input whose soup estimate is `soup`.
fn memory_for_soup(soup: u64, cfg: &BuildConfig, threads: usize) -> u64 {
    let mut bytes = (soup.saturating_mul(PEAK_HALVES_PER_SOUP_BYTE) / 2)
        .saturating_add(PEAK_FIXED)
        .saturating_add(PEAK_PER_THREAD.saturating_mul(threads.max(1) as u64));
    if cfg.compress.is_some() {
        bytes = bytes
            .saturating_add(soup.saturating_mul(FRAME_PER_SOUP_BYTE))
            .saturating_add(FRAME_FIXED);
    }
    bytes
}

/// How a batch shares the machine ([`build_batch_with`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BatchConfig {
    /// Most inputs built at once, each on a loop of the batch's pool of as
    /// many threads (0: one per core).
    pub jobs: usize,
    /// A memory budget in bytes (`build --max-memory`): an input starts
    /// only while the [`memory_estimate`]s of the builds running, its own
    /// and the blocks the batch keeps for reuse (a quarter of the budget,
    /// at most `alloc::CACHE_BYTES`) fit in it, or when nothing else runs
    /// (an input larger than the budget is built alone). None: no budget.
    pub max_memory: Option<u64>,
}

impl BatchConfig {
    /// `jobs` at once, no memory budget.
    pub fn jobs(jobs: usize) -> Self {
        BatchConfig {
            jobs,
            max_memory: None,
        }
    }

    /// What the budget leaves the builds' estimates: all of it but the
    /// kept blocks' part (a quarter, at most `alloc::CACHE_BYTES`). None
    /// without a budget. An input whose estimate is above it is built
    /// alone.
    pub fn builds_budget(&self) -> Option<u64> {
        self.max_memory.map(|b| b - Self::kept_bytes(b))
    }

    /// The part of a budget a batch lets its kept blocks hold: a quarter,
    /// at most `alloc::CACHE_BYTES`.
    fn kept_bytes(budget: u64) -> u64 {
        (budget / 4).min(crate::alloc::CACHE_BYTES as u64)
    }
}

/// Builds every input into its output with up to `jobs` threads (0: all
/// cores): [`build_batch_with`] with no memory budget and no callbacks.
pub fn build_batch(
    inputs: &[std::path::PathBuf],
    outputs: &[std::path::PathBuf],
    cfg: &BuildConfig,
    jobs: usize,
) -> Vec<Result<BuildOutput>> {
    build_batch_with(
        inputs,
        outputs,
        cfg,
        &BatchConfig::jobs(jobs),
        &|_, _| {},
        &|_| {},
    )
}

/// Builds every input into its output, up to `batch.jobs` at once,
/// announcing each input's stages to `stage(input index, stage name)` and
/// each finished input to `done`. Each build is independent and its output
/// does not depend on the thread count or the budget, so every output is
/// byte-identical whatever `batch` is. Results come back in input order; a
/// failing input does not stop the others.
///
/// With more inputs than jobs, or a memory budget, the inputs start in
/// [`batch_order`], largest first: each of the batch's loops takes the
/// first input not yet started that fits the budget when its last build
/// ends. A loop that finds none ends, and its thread helps the builds still
/// running with their parallel passes; when a build ends, its loop starts
/// loops again up to `jobs`, for the inputs that now fit. Why largest
/// first: a batch lasts at least as long as its largest build. When the
/// inputs were split in halves in the order given, the largest could start
/// after others on its thread and then run on alone, its parse on one
/// thread; and built first, its freed blocks serve the smaller builds
/// after it (`crate::alloc::KeepFreed`), so a batch takes fewer fresh pages
/// (benches/ROUNDS.md, Fiftieth round). Why a budget: a batch on many cores
/// runs that many builds at once, and a machine's memory may hold fewer
/// (Fifty-first round).
pub fn build_batch_with(
    inputs: &[std::path::PathBuf],
    outputs: &[std::path::PathBuf],
    cfg: &BuildConfig,
    batch: &BatchConfig,
    stage: &(dyn Fn(usize, &'static str) + Sync),
    done: &(dyn Fn(usize) + Sync),
) -> Vec<Result<BuildOutput>> {
    // One guard for the whole batch: the blocks one input's build frees at
    // its end (its soup, welded mesh and edges) serve the next input's,
    // instead of each build starting from fresh pages (`crate::alloc`).
    // Under a budget they hold a part of it.
    let _keep = match batch.max_memory {
        Some(budget) => crate::alloc::KeepFreed::within(
            usize::try_from(BatchConfig::kept_bytes(budget)).unwrap_or(usize::MAX),
        ),
        None => crate::alloc::KeepFreed::new(),
    };
    // The old outputs the builds swap out are removed on a thread of the
    // batch's own (`crate::removals`), which every worker of its pool
    // hands them to.
    let remover = crate::removals::Remover::start();
    let mut pool = rayon::ThreadPoolBuilder::new().num_threads(batch.jobs);
    if let Some(r) = &remover {
        pool = pool.start_handler(r.attach());
    }
    let pool = pool.build();
    let slots: Vec<std::sync::OnceLock<Result<BuildOutput>>> =
        inputs.iter().map(|_| std::sync::OnceLock::new()).collect();
    let run = || {
        let threads = rayon::current_num_threads();
        let jobs = threads.min(inputs.len());
        let budget = batch.builds_budget();
        // With a loop per input and no budget every build starts at once,
        // and the estimates (a glTF's JSON read twice) would be spent for
        // nothing.
        let (order, cost) = if jobs < inputs.len() || budget.is_some() {
            // The order by [`batch_order`]'s measure, and the costs, from
            // one read of each input's head.
            let (work, soup): (Vec<u64>, Vec<u64>) =
                inputs.iter().map(|i| load::estimates(i)).unzip();
            let cost = match budget {
                Some(_) => soup
                    .iter()
                    .map(|&s| memory_for_soup(s, cfg, threads))
                    .collect(),
                None => vec![0; inputs.len()],
            };
            (order_by(&work), cost)
        } else {
            ((0..inputs.len()).collect(), vec![0; inputs.len()])
        };
        let queue = BatchQueue::new(order, cost, budget, jobs);
        let build = |n: usize| {
            let r = build_file_with(&inputs[n], &outputs[n], cfg, &|s| stage(n, s));
            done(n);
            let _ = slots[n].set(r);
        };
        rayon::scope(|s| {
            for _ in 1..jobs {
                s.spawn(|s| batch_loop(s, &queue, &build));
            }
            batch_loop(s, &queue, &build);
        })
    };
    match pool {
        Ok(pool) => pool.install(run),
        Err(_) => run(),
    }
    let mut results: Vec<Result<BuildOutput>> = slots
        .into_iter()
        .map(|slot| {
            slot.into_inner()
                .unwrap_or_else(|| Err(Error::Other("the build did not run".to_string())))
        })
        .collect();
    // An old output that could not be removed fails its input's build, as
    // when the build removed it itself (the new output is in place).
    for (output, e) in remover
        .map(crate::removals::Remover::finish)
        .unwrap_or_default()
    {
        if let Some(n) = outputs.iter().position(|o| *o == output) {
            results[n] = Err(e);
        }
    }
    results
}

/// The inputs of a batch waiting to start ([`build_batch_with`]).
struct BatchQueue {
    /// Input indices, largest first ([`batch_order`]).
    order: Vec<usize>,
    /// Each input's [`memory_estimate`] (0 without a budget).
    cost: Vec<u64>,
    /// The budget the running builds' estimates must fit, less the kept
    /// blocks' part.
    budget: Option<u64>,
    /// Most loops at once.
    jobs: usize,
    state: std::sync::Mutex<QueueState>,
}

struct QueueState {
    /// Every input of `order` before this one has started.
    next: usize,
    /// Which inputs have started (by input index).
    started: Vec<bool>,
    /// Inputs not started yet.
    waiting: usize,
    /// The estimates of the builds running.
    reserved: u64,
    /// Builds running.
    running: usize,
    /// Loops alive: running a build, or about to ask for one.
    loops: usize,
}

impl BatchQueue {
    /// A queue of the inputs in `order`, each costing `cost[input]`
    /// against `budget`, for `jobs` loops alive at first.
    fn new(order: Vec<usize>, cost: Vec<u64>, budget: Option<u64>, jobs: usize) -> Self {
        let state = QueueState {
            next: 0,
            started: vec![false; cost.len()],
            waiting: cost.len(),
            reserved: 0,
            running: 0,
            loops: jobs,
        };
        BatchQueue {
            order,
            cost,
            budget,
            jobs,
            state: std::sync::Mutex::new(state),
        }
    }

    /// The next input to build: the first in `order` not started that fits
    /// the budget beside the builds running, or any when none runs. None
    /// when none fits or none is left; the asking loop then ends.
    fn take(&self) -> Option<usize> {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        while st.next < self.order.len() && st.started[self.order[st.next]] {
            st.next += 1;
        }
        let fits = |st: &QueueState, n: usize| match self.budget {
            Some(budget) => st.running == 0 || st.reserved.saturating_add(self.cost[n]) <= budget,
            None => true,
        };
        let found = self.order[st.next..]
            .iter()
            .copied()
            .find(|&n| !st.started[n] && fits(&st, n));
        match found {
            Some(n) => {
                st.started[n] = true;
                st.waiting -= 1;
                st.reserved += self.cost[n];
                st.running += 1;
            }
            // (Saturating: a batch of no inputs starts with no loops but
            // the caller's.)
            None => st.loops = st.loops.saturating_sub(1),
        }
        found
    }

    /// Marks input `n`'s build ended, and returns how many loops to start
    /// beside the caller's for the inputs that may fit now.
    fn finish(&self, n: usize) -> usize {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        st.reserved -= self.cost[n];
        st.running -= 1;
        if self.budget.is_none() || st.waiting <= 1 {
            return 0;
        }
        // The caller's loop takes one of those waiting itself.
        let more = (self.jobs - st.loops).min(st.waiting - 1);
        st.loops += more;
        more
    }
}

/// One loop of a batch: takes inputs from `queue` and builds them until
/// none fits, starting more loops as builds end and free their budget.
fn batch_loop<'s>(s: &rayon::Scope<'s>, queue: &'s BatchQueue, build: &'s (dyn Fn(usize) + Sync)) {
    while let Some(n) = queue.take() {
        build(n);
        for _ in 0..queue.finish(n) {
            s.spawn(|s| batch_loop(s, queue, build));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::load::Part;

    /// `bounds` against the obvious per-component fold, for every count
    /// of positions up to past three 16-position steps (every remainder)
    /// and a large one, with NaN and infinite coordinates mixed in.
    /// Caught: the remainder left out; an unfilled lane's +infinity taken
    /// as a maximum (fewer than 16 positions); lanes mapped to the wrong
    /// component.
    #[test]
    fn bounds_match_a_plain_fold() {
        let mut next = crate::multiplicity::test_bits(0x9e37_79b9_7f4a_7c15);
        for n in (0..60).chain([1000, 4099]) {
            let pos: Vec<[f32; 3]> = (0..n)
                .map(|_| {
                    std::array::from_fn(|k| match next() % 50 {
                        0 => f32::NAN,
                        1 => f32::INFINITY,
                        2 => f32::NEG_INFINITY,
                        r => (r as f32 - 25.0) * (k as f32 + 1.5) + (next() % 7) as f32 * 0.125,
                    })
                })
                .collect();
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for p in &pos {
                for k in 0..3 {
                    if p[k] < lo[k] {
                        lo[k] = p[k];
                    }
                    if p[k] > hi[k] {
                        hi[k] = p[k];
                    }
                }
            }
            if n == 0 {
                (lo, hi) = ([0.0; 3], [0.0; 3]);
            }
            assert_eq!(bounds(&pos), (lo, hi), "{n} positions");
        }
    }

    /// A queue's decisions, step by step: inputs 0–3 costing 50, 30, 20 and
    /// 10 against a budget of 60, three loops. The largest starts with the
    /// smallest (the only one that fits beside it), the third loop ends;
    /// when the smallest ends one loop is started again, and finds nothing
    /// beside the largest; when the largest ends its loop starts one more,
    /// and the two middle inputs run together. An input above the budget
    /// runs when nothing else does; a batch of no inputs builds nothing.
    /// Caught: the budget ignored; a build's
    /// cost not given back when it ends; no loop started again when a
    /// build ends; an input above the budget never started; the loops
    /// counted down past zero (no inputs; an overflow in a debug build).
    #[test]
    fn a_batch_queue_starts_what_fits_and_restarts_loops() {
        let q = BatchQueue::new(vec![0, 1, 2, 3], vec![50, 30, 20, 10], Some(60), 3);
        assert_eq!(q.take(), Some(0));
        assert_eq!(q.take(), Some(3));
        assert_eq!(q.take(), None);
        assert_eq!(q.finish(3), 1, "one loop started again for 1 and 2");
        assert_eq!(q.take(), None, "neither 1 nor 2 fits beside 0");
        assert_eq!(q.take(), None, "the loop whose build ended ends too");
        assert_eq!(q.finish(0), 1);
        assert_eq!(q.take(), Some(1));
        assert_eq!(q.take(), Some(2), "1 and 2 together: 50 of 60");
        assert_eq!(q.finish(1), 0, "nothing waits");
        assert_eq!(q.take(), None);
        assert_eq!(q.finish(2), 0);
        assert_eq!(q.take(), None);
        // Above the budget alone: it waits for the running build to end.
        let q = BatchQueue::new(vec![0, 1], vec![100, 10], Some(60), 2);
        assert_eq!(q.take(), Some(0), "nothing runs: it starts");
        assert_eq!(q.take(), None, "1 does not fit beside it");
        assert_eq!(q.finish(0), 0);
        assert_eq!(q.take(), Some(1));
        // No inputs: nothing to take.
        let q = BatchQueue::new(Vec::new(), Vec::new(), None, 0);
        assert_eq!(q.take(), None);
        assert!(build_batch(&[], &[], &BuildConfig::default(), 2).is_empty());
        // No budget: the order, whatever the costs.
        let q = BatchQueue::new(vec![2, 0, 1], vec![0; 3], None, 2);
        assert_eq!([q.take(), q.take()], [Some(2), Some(0)]);
        assert_eq!(q.finish(2), 0);
        assert_eq!([q.take(), q.take()], [Some(1), None]);
    }

    /// Two parts of two triangles each over 6 vertices, vertex 5 unused.
    fn soup(positions: Vec<[f32; 3]>, indices: Vec<u32>) -> Soup {
        let part = |name: &str, first| Part {
            name: name.into(),
            first_triangle: first,
            triangle_count: 2,
        };
        Soup {
            positions,
            indices,
            parts: vec![part("front", 0), part("back", 2)],
            ..Soup::default()
        }
    }

    fn grid() -> Vec<[f32; 3]> {
        (0..6).map(|i| [i as f32, (i % 2) as f32, 0.0]).collect()
    }

    const TRIS: [u32; 12] = [0, 1, 2, 1, 3, 2, 2, 3, 4, 3, 0, 4];

    fn message(s: &Soup) -> String {
        check_soup(Path::new("m.obj"), s).unwrap_err().to_string()
    }

    #[test]
    fn check_soup_passes_clean_and_unused_non_finite_positions() {
        assert!(check_soup(Path::new("m.obj"), &soup(grid(), TRIS.to_vec())).is_ok());
        // Vertex 5 is used by no triangle: whatever it holds is no error
        // (the fast path fails on it and the walk clears it).
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let mut p = grid();
            p[5] = [0.0, bad, 0.0];
            assert!(check_soup(Path::new("m.obj"), &soup(p, TRIS.to_vec())).is_ok());
        }
        assert!(check_soup(Path::new("m.obj"), &Soup::default()).is_ok());
    }

    #[test]
    fn check_soup_names_the_first_bad_corner_and_its_part() {
        // A used non-finite position, in the second part.
        let mut p = grid();
        p[4] = [f32::NAN, 0.0, 0.0];
        let msg = message(&soup(p.clone(), TRIS.to_vec()));
        assert!(msg.contains("m.obj"), "{msg}");
        assert!(
            msg.contains("triangle 2 in back: vertex 4 has a non-finite position (NaN, 0, 0)"),
            "{msg}"
        );
        // An out-of-range index in the first part comes first.
        let mut t = TRIS.to_vec();
        t[4] = 9;
        let msg = message(&soup(p, t));
        assert!(
            msg.contains("triangle 1 in front: vertex index 9 out of range (6 vertices)"),
            "{msg}"
        );
        // An infinite position alone.
        let mut p = grid();
        p[0] = [0.0, 0.0, f32::INFINITY];
        let msg = message(&soup(p, TRIS.to_vec()));
        assert!(msg.contains("triangle 0 in front: vertex 0"), "{msg}");
        let msg = message(&soup(grid(), TRIS[..11].to_vec()));
        assert!(msg.contains("not a multiple of 3"), "{msg}");
    }
}
