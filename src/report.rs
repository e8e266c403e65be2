//! Summaries of a built file, for `build` and `inspect` (human text and JSON).
//!
//! Both commands derive the summary from the header alone, so what `inspect`
//! prints for a file is exactly what `build` printed when writing it.

use crate::error::{Error, Result};
use crate::format::{Header, MeshStats};
use crate::layout::paper_bytes;
use serde::Serialize;
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// Per-bucket figures.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct BucketSummary {
    /// Opposite vertices per instance.
    pub k: u32,
    /// Instances.
    pub instances: u64,
    /// Bytes.
    pub bytes: u64,
}

/// Per-mesh sizes.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct MeshSummary {
    /// Mesh name.
    pub name: String,
    /// Triangles.
    pub triangles: u64,
    /// Caps section bytes.
    pub caps_bytes: u64,
    /// Sides bytes (all buckets).
    pub sides_bytes: u64,
    /// Side buckets.
    pub buckets: Vec<BucketSummary>,
}

/// GPU memory of Partitioned Shadow Volumes (Gerhards et al. 2015, §4.1) for
/// `triangles`: a TOP tree of 4 nodes of 32 bytes per triangle, plus the root.
pub fn psv_bytes(triangles: u64) -> u64 {
    4 * 32 * (triangles + 1)
}

/// Everything `build --json` and `inspect --json` print (stable field names).
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Summary {
    /// Tool that wrote the file.
    pub generator: String,
    /// Input file name.
    pub input_file: String,
    /// Input format.
    pub input_format: String,
    /// Input bytes read.
    pub input_bytes: u64,
    /// SHA-256 of the input, hex.
    pub input_sha256: String,
    /// K.
    pub max_mult: u32,
    /// Position encoding: "f32" or "unorm16".
    pub positions: String,
    /// Whether the file is zstd-wrapped.
    pub compressed: bool,
    /// Totals over all meshes (flattened into the JSON object).
    #[serde(flatten)]
    pub stats: MeshStats,
    /// Side buckets.
    pub buckets: Vec<BucketSummary>,
    /// Sum of bucket bytes.
    pub sides_bytes: u64,
    /// Caps bytes.
    pub caps_bytes: u64,
    /// Preamble, header and padding bytes.
    pub header_bytes: u64,
    /// Of those, the header room's zeros (format 2.1, `format::header_room`).
    pub header_room_bytes: u64,
    /// Uncompressed container bytes.
    pub container_bytes: u64,
    /// Bytes on disk.
    pub file_bytes: u64,
    /// The paper's uniform layout: 16·(2+maxMult)·e + 48·t, maxMult = max_fan.
    pub paper_bytes: u64,
    /// Partitioned Shadow Volumes' GPU footprint for the same triangles:
    /// 128·(t + 1) bytes.
    pub psv_bytes: u64,
    /// Size of the container as the zstd frame `build --compress-level
    /// zstd_level` writes (inspect only; equals `file_bytes` for compressed
    /// files).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zstd_bytes: Option<u64>,
    /// The zstd level of the frame: `build`'s for a compressed build,
    /// `inspect`'s for `zstd_bytes` of a plain file (a frame does not record
    /// its level, so a compressed file read back has none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zstd_level: Option<i32>,
    /// Per mesh.
    pub meshes: Vec<MeshSummary>,
    /// Lower bounds.
    pub bounds_min: [f32; 3],
    /// Upper bounds.
    pub bounds_max: [f32; 3],
    /// Build wall time in milliseconds (build only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_ms: Option<f64>,
    /// Wall time per stage (`build --timings`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub timings_ms: Option<crate::build::Timings>,
    /// Peak resident memory of the process in bytes (`build --timings`; for a
    /// batch, of the whole batch so far).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peak_memory_bytes: Option<u64>,
    /// What a batch under `--max-memory` counts this input's build as
    /// (`build::memory_estimate`, with the pool's threads; `build
    /// --timings`), to set a budget by.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory_estimate_bytes: Option<u64>,
    /// Whether the process met cold memory (`build --timings`): a fresh
    /// huge page slow to fault in, after which fresh buffers got small
    /// pages for a while (`alloc::cold_memory_seen`); it explains slower
    /// stages in the timings.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cold_memory: Option<bool>,
    /// Loader warnings (build only).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

/// `bytes` in lower-case hexadecimal, two digits each (the digests of
/// summaries and reports).
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

impl Summary {
    /// Summarises a header; `file_bytes` is the size on disk.
    pub fn from_header(h: &Header, file_bytes: u64, compressed: bool) -> Summary {
        // Whole-file totals over all meshes.
        let mut stats = MeshStats::default();
        let mut buckets: Vec<BucketSummary> = Vec::new();
        let mut caps_bytes = 0;
        for m in &h.meshes {
            stats.add(&m.stats);
            caps_bytes += m.caps.length;
            for b in &m.buckets {
                match buckets.iter_mut().find(|x| x.k == b.k) {
                    Some(x) => {
                        x.instances += b.instances;
                        x.bytes += b.length;
                    }
                    None => buckets.push(BucketSummary {
                        k: b.k,
                        instances: b.instances,
                        bytes: b.length,
                    }),
                }
            }
        }
        buckets.sort_by_key(|b| b.k);
        let sides_bytes = buckets.iter().map(|b| b.bytes).sum();
        Summary {
            generator: h.generator.clone(),
            input_file: h.input.file_name.clone(),
            input_format: h.input.format.clone(),
            input_bytes: h.input.bytes,
            input_sha256: hex(&h.input.sha256),
            max_mult: h.options.max_mult,
            positions: h
                .options
                .encoding()
                .map(|e| e.name().to_string())
                .unwrap_or_else(|_| format!("unknown ({})", h.options.positions)),
            compressed,
            stats: stats.clone(),
            buckets,
            sides_bytes,
            caps_bytes,
            header_bytes: h.payload_offset,
            header_room_bytes: h.reserved,
            container_bytes: h.payload_offset + h.payload_len,
            file_bytes,
            paper_bytes: paper_bytes(stats.edges, stats.triangles, stats.max_fan),
            psv_bytes: psv_bytes(stats.triangles),
            zstd_bytes: None,
            zstd_level: None,
            meshes: h
                .meshes
                .iter()
                .map(|m| MeshSummary {
                    name: m.name.clone(),
                    triangles: m.stats.triangles,
                    caps_bytes: m.caps.length,
                    sides_bytes: m.buckets.iter().map(|b| b.length).sum(),
                    buckets: m
                        .buckets
                        .iter()
                        .map(|b| BucketSummary {
                            k: b.k,
                            instances: b.instances,
                            bytes: b.length,
                        })
                        .collect(),
                })
                .collect(),
            bounds_min: h.bounds_min,
            bounds_max: h.bounds_max,
            time_ms: None,
            timings_ms: None,
            peak_memory_bytes: None,
            memory_estimate_bytes: None,
            cold_memory: None,
            warnings: Vec::new(),
        }
    }

    /// Compact human-readable summary (gltfpack style), several lines.
    pub fn to_text(&self) -> String {
        let mut o = String::new();
        let _ = writeln!(
            o,
            "input:   {} ({}, {}): {} triangles, {} vertices, {} primitives",
            self.input_file,
            self.input_format,
            human_bytes(self.input_bytes),
            self.stats.input_triangles,
            self.stats.input_vertices,
            self.stats.primitives
        );
        if self.stats.skipped_points + self.stats.skipped_lines > 0 {
            let _ = writeln!(
                o,
                "skipped: {} point and {} line primitives",
                self.stats.skipped_points, self.stats.skipped_lines
            );
        }
        let _ = writeln!(
            o,
            "weld:    {} vertices, {} degenerate triangles dropped, {} triangles kept",
            self.stats.welded_vertices, self.stats.degenerate_triangles, self.stats.triangles
        );
        let _ = writeln!(
            o,
            "edges:   {} ({} open, {} non-manifold, max fan {})",
            self.stats.edges,
            self.stats.open_edges,
            self.stats.non_manifold_edges,
            self.stats.max_fan
        );
        let hist: Vec<String> = self
            .stats
            .histogram
            .iter()
            .map(|h| format!("{}:{}", h.opposites, h.edges))
            .collect();
        let _ = writeln!(o, "         edges by opposite count  {}", hist.join("  "));
        let _ = writeln!(
            o,
            "sides:   {} instances, {} (K = {}, {} positions)",
            self.stats.edge_instances,
            human_bytes(self.sides_bytes),
            self.max_mult,
            self.positions
        );
        for b in &self.buckets {
            let _ = writeln!(
                o,
                "         k={:<2} {:>10} instances {:>10}",
                b.k,
                b.instances,
                human_bytes(b.bytes)
            );
        }
        let _ = writeln!(
            o,
            "caps:    {} triangles, {}",
            self.stats.triangles,
            human_bytes(self.caps_bytes)
        );
        let _ = write!(
            o,
            "output:  {}{}: header {}{}, sides {}, caps {}",
            human_bytes(self.file_bytes),
            if self.compressed {
                format!(
                    " (zstd{}; {} uncompressed)",
                    self.zstd_level
                        .map_or(String::new(), |l| format!(" level {l}")),
                    human_bytes(self.container_bytes)
                )
            } else {
                String::new()
            },
            human_bytes(self.header_bytes),
            if self.header_room_bytes > 0 {
                format!(" ({} of it room)", human_bytes(self.header_room_bytes))
            } else {
                String::new()
            },
            human_bytes(self.sides_bytes),
            human_bytes(self.caps_bytes),
        );
        if let Some(ms) = self.time_ms {
            let _ = write!(o, "; {ms:.1} ms");
        }
        if let Some(t) = &self.timings_ms {
            let _ = write!(
                o,
                "\ntimings: load {:.1} ms, weld {:.1} ms, topology {:.1} ms, layout {:.1} ms, write {:.1} ms; total {:.1} ms ({:.0} ns per input triangle); the output's copy into the file {:.1} ms (write calls, all threads)",
                t.load,
                t.weld,
                t.topology,
                t.layout,
                t.write,
                t.total,
                t.total * 1e6 / self.stats.input_triangles.max(1) as f64,
                t.write_calls
            );
            if let Some(peak) = self.peak_memory_bytes {
                let _ = write!(o, "; peak memory {}", human_bytes(peak));
            }
            if let Some(estimate) = self.memory_estimate_bytes {
                let _ = write!(o, " (estimate {})", human_bytes(estimate));
            }
            if self.cold_memory == Some(true) {
                o.push_str("; cold memory (fresh huge pages were slow, small pages used)");
            }
        }
        let _ = write!(
            o,
            "\npaper:   uniform layout with maxMult = {} would be {}; sides + caps here are {:.1}% of it",
            self.stats.max_fan,
            human_bytes(self.paper_bytes),
            pct(self.sides_bytes + self.caps_bytes, self.paper_bytes)
        );
        let _ = write!(
            o,
            "\ncompare: input file {} (output is {:.0}% of it); Partitioned Shadow Volumes would need {} of GPU memory",
            human_bytes(self.input_bytes),
            pct(self.file_bytes, self.input_bytes),
            human_bytes(self.psv_bytes)
        );
        if let Some(z) = self.zstd_bytes {
            let _ = write!(o, "; zstd-compressed {}", human_bytes(z));
            if let (false, Some(l)) = (self.compressed, self.zstd_level) {
                let _ = write!(o, " at level {l}");
            }
        }
        o.push('\n');
        o
    }
}

/// `a` as a percentage of `b` (0 when `b` is 0).
fn pct(a: u64, b: u64) -> f64 {
    if b == 0 {
        0.0
    } else {
        100.0 * a as f64 / b as f64
    }
}

/// `1234567` → `"1.18 MiB"`.
pub fn human_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.2} {}", UNITS[u])
    }
}

/// Summaries of every `.svpk` file under `dir` (recursively), largest file
/// first (ties by path), each with the file's path; unreadable files carry
/// their error.
pub fn summarize_dir(
    dir: &std::path::Path,
) -> crate::error::Result<Vec<(std::path::PathBuf, crate::error::Result<Summary>)>> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let entries = std::fs::read_dir(&d).map_err(|e| crate::error::Error::io(&d, e))?;
        for e in entries {
            let p = e.map_err(|e| crate::error::Error::io(&d, e))?.path();
            if p.is_dir() {
                stack.push(p);
            } else if p
                .extension()
                .is_some_and(|x| x.eq_ignore_ascii_case("svpk"))
            {
                files.push(p);
            }
        }
    }
    let mut out: Vec<(std::path::PathBuf, crate::error::Result<Summary>)> = files
        .into_iter()
        .map(|p| {
            let s = crate::format::read_file(&p)
                .map(|f| Summary::from_header(&f.header, f.file_bytes, f.compressed));
            (p, s)
        })
        .collect();
    let size = |r: &crate::error::Result<Summary>| r.as_ref().map(|s| s.file_bytes).unwrap_or(0);
    out.sort_by(|a, b| size(&b.1).cmp(&size(&a.1)).then_with(|| a.0.cmp(&b.0)));
    Ok(out)
}

/// The `svpack report` table: one line per file, largest first, and a total.
pub fn report_table(rows: &[(std::path::PathBuf, crate::error::Result<Summary>)]) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "{:>10} {:>10} {:>10} {:>10} {:>10} {:>8} {:>8}  file",
        "bytes", "triangles", "edges", "sides", "caps", "%paper", "%psv"
    );
    let (mut bytes, mut tris) = (0u64, 0u64);
    for (p, r) in rows {
        match r {
            Ok(s) => {
                bytes += s.file_bytes;
                tris += s.stats.triangles;
                let _ = writeln!(
                    o,
                    "{:>10} {:>10} {:>10} {:>10} {:>10} {:>7.1}% {:>7.1}%  {}",
                    human_bytes(s.file_bytes),
                    s.stats.triangles,
                    s.stats.edges,
                    human_bytes(s.sides_bytes),
                    human_bytes(s.caps_bytes),
                    pct(s.sides_bytes + s.caps_bytes, s.paper_bytes),
                    pct(s.file_bytes, s.psv_bytes),
                    p.display()
                );
            }
            Err(e) => {
                let _ = writeln!(o, "{:>10} {e}", "error");
            }
        }
    }
    let _ = writeln!(
        o,
        "{:>10} {:>10}  total of {} files",
        human_bytes(bytes),
        tris,
        rows.len()
    );
    o
}

/// Writes a benchmark's `STEM.md`, `STEM.json` (`report`, pretty-printed)
/// and `STEM.svg` into `out` (created if missing), each through a temp
/// file renamed into place, so that a failed run leaves the previous files
/// whole. Returns the paths.
pub fn write_bench_files(
    out: &Path,
    stem: &str,
    report: &impl Serialize,
    md: &str,
    svg: std::result::Result<String, String>,
) -> Result<[PathBuf; 3]> {
    let json = serde_json::to_string_pretty(report).map_err(|e| Error::Other(e.to_string()))?;
    let svg = svg.map_err(Error::Other)?;
    let (json, svg) = (json.as_str(), svg.as_str());
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let paths = ["md", "json", "svg"].map(|ext| out.join(format!("{stem}.{ext}")));
    for (p, data) in paths.iter().zip([md, json, svg]) {
        let tmp = p.with_extension("tmp");
        std::fs::write(&tmp, data).map_err(|e| Error::io(&tmp, e))?;
        std::fs::rename(&tmp, p).map_err(|e| Error::io(p, e))?;
    }
    Ok(paths)
}

/// The chart `draw` makes on a white SVG page of `size` pixels, as text:
/// the page and its final flush, which every bench's chart shares; a
/// drawing error comes back as its message.
pub fn svg_chart(
    size: (u32, u32),
    draw: impl for<'a, 'b> FnOnce(
        &'b plotters::drawing::DrawingArea<
            plotters::backend::SVGBackend<'a>,
            plotters::coord::Shift,
        >,
    ) -> std::result::Result<(), Box<dyn std::error::Error>>,
) -> std::result::Result<String, String> {
    use plotters::prelude::*;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        let drawn = (|| {
            root.fill(&WHITE)?;
            draw(&root)?;
            root.present()?;
            Ok::<_, Box<dyn std::error::Error>>(())
        })();
        drawn.map_err(|e| e.to_string())?;
    }
    Ok(svg)
}

/// The legend of `chart`'s labelled series at `position`, in a white,
/// slightly translucent box with a black border: every bench's chart has
/// it so.
pub fn chart_legend<'a, DB, CT>(
    chart: &mut plotters::chart::ChartContext<'a, DB, CT>,
    position: plotters::chart::SeriesLabelPosition,
) -> std::result::Result<(), plotters::drawing::DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: plotters::prelude::DrawingBackend + 'a,
    CT: plotters::coord::CoordTranslate,
{
    use plotters::prelude::*;
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
}
