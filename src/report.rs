//! Summaries of a built file, for `build` and `inspect` (human text and JSON).
//!
//! Both commands derive the summary from the header alone, so what `inspect`
//! prints for a file is exactly what `build` printed when writing it.

use crate::format::{Header, MeshStats};
use crate::layout::paper_bytes;
use serde::Serialize;
use std::fmt::Write;

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

/// One opposite-count histogram bar.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct HistogramSummary {
    /// Opposite-vertex count.
    pub opposites: u32,
    /// Edges with that count.
    pub edges: u64,
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
    /// Whether the file is zstd-wrapped.
    pub compressed: bool,
    /// Triangle primitives / OBJ groups read.
    pub primitives: u64,
    /// Input triangles (before welding).
    pub input_triangles: u64,
    /// Input vertices.
    pub input_vertices: u64,
    /// Welded vertices.
    pub welded_vertices: u64,
    /// Dropped degenerate triangles.
    pub degenerate_triangles: u64,
    /// Skipped point primitives.
    pub skipped_points: u64,
    /// Skipped line primitives.
    pub skipped_lines: u64,
    /// Kept triangles (caps records).
    pub triangles: u64,
    /// Undirected edges.
    pub edges: u64,
    /// Side instances.
    pub edge_instances: u64,
    /// Edges with one opposite vertex.
    pub open_edges: u64,
    /// Edges with more than two opposite vertices.
    pub non_manifold_edges: u64,
    /// Largest opposite count.
    pub max_fan: u32,
    /// Edges by opposite count.
    pub opposite_histogram: Vec<HistogramSummary>,
    /// Side buckets.
    pub buckets: Vec<BucketSummary>,
    /// Sum of bucket bytes.
    pub sides_bytes: u64,
    /// Caps bytes.
    pub caps_bytes: u64,
    /// Preamble, header and padding bytes.
    pub header_bytes: u64,
    /// Uncompressed container bytes.
    pub container_bytes: u64,
    /// Bytes on disk.
    pub file_bytes: u64,
    /// The paper's uniform layout: 16·(2+maxMult)·e + 48·t, maxMult = max_fan.
    pub paper_bytes: u64,
    /// Lower bounds.
    pub bounds_min: [f32; 3],
    /// Upper bounds.
    pub bounds_max: [f32; 3],
    /// Build wall time in milliseconds (build only).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub time_ms: Option<f64>,
    /// Loader warnings (build only).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub warnings: Vec<String>,
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().fold(String::new(), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

impl Summary {
    /// Summarises a header; `file_bytes` is the size on disk.
    pub fn from_header(h: &Header, file_bytes: u64, compressed: bool) -> Summary {
        // Whole-file totals over all meshes.
        let mut s = MeshStats::default();
        let mut hist: Vec<u64> = Vec::new();
        let mut buckets: Vec<BucketSummary> = Vec::new();
        let mut caps_bytes = 0;
        for m in &h.meshes {
            let t = &m.stats;
            s.primitives += t.primitives;
            s.input_triangles += t.input_triangles;
            s.input_vertices += t.input_vertices;
            s.welded_vertices += t.welded_vertices;
            s.degenerate_triangles += t.degenerate_triangles;
            s.skipped_points += t.skipped_points;
            s.skipped_lines += t.skipped_lines;
            s.triangles += t.triangles;
            s.edges += t.edges;
            s.edge_instances += t.edge_instances;
            s.open_edges += t.open_edges;
            s.non_manifold_edges += t.non_manifold_edges;
            s.max_fan = s.max_fan.max(t.max_fan);
            for e in &t.histogram {
                let n = e.opposites as usize;
                if n >= hist.len() {
                    hist.resize(n + 1, 0);
                }
                hist[n] += e.edges;
            }
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
            compressed,
            primitives: s.primitives,
            input_triangles: s.input_triangles,
            input_vertices: s.input_vertices,
            welded_vertices: s.welded_vertices,
            degenerate_triangles: s.degenerate_triangles,
            skipped_points: s.skipped_points,
            skipped_lines: s.skipped_lines,
            triangles: s.triangles,
            edges: s.edges,
            edge_instances: s.edge_instances,
            open_edges: s.open_edges,
            non_manifold_edges: s.non_manifold_edges,
            max_fan: s.max_fan,
            opposite_histogram: hist
                .iter()
                .enumerate()
                .filter(|(_, c)| **c > 0)
                .map(|(n, &c)| HistogramSummary {
                    opposites: n as u32,
                    edges: c,
                })
                .collect(),
            buckets,
            sides_bytes,
            caps_bytes,
            header_bytes: h.payload_offset,
            container_bytes: h.payload_offset + h.payload_len,
            file_bytes,
            paper_bytes: paper_bytes(s.edges, s.triangles, s.max_fan),
            bounds_min: h.bounds_min,
            bounds_max: h.bounds_max,
            time_ms: None,
            warnings: Vec::new(),
        }
    }

    /// Compact human-readable summary (gltfpack style), several lines.
    pub fn to_text(&self) -> String {
        let mut o = String::new();
        let pct = |a: u64, b: u64| {
            if b == 0 {
                0.0
            } else {
                100.0 * a as f64 / b as f64
            }
        };
        let _ = writeln!(
            o,
            "input:   {} ({}, {}): {} triangles, {} vertices, {} primitives",
            self.input_file,
            self.input_format,
            human_bytes(self.input_bytes),
            self.input_triangles,
            self.input_vertices,
            self.primitives
        );
        if self.skipped_points + self.skipped_lines > 0 {
            let _ = writeln!(
                o,
                "skipped: {} point and {} line primitives",
                self.skipped_points, self.skipped_lines
            );
        }
        let _ = writeln!(
            o,
            "weld:    {} vertices, {} degenerate triangles dropped, {} triangles kept",
            self.welded_vertices, self.degenerate_triangles, self.triangles
        );
        let _ = writeln!(
            o,
            "edges:   {} ({} open, {} non-manifold, max fan {})",
            self.edges, self.open_edges, self.non_manifold_edges, self.max_fan
        );
        let hist: Vec<String> = self
            .opposite_histogram
            .iter()
            .map(|h| format!("{}:{}", h.opposites, h.edges))
            .collect();
        let _ = writeln!(o, "         edges by opposite count  {}", hist.join("  "));
        let _ = writeln!(
            o,
            "sides:   {} instances, {} (K = {})",
            self.edge_instances,
            human_bytes(self.sides_bytes),
            self.max_mult
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
            self.triangles,
            human_bytes(self.caps_bytes)
        );
        let _ = write!(
            o,
            "output:  {}{}: header {}, sides {}, caps {}",
            human_bytes(self.file_bytes),
            if self.compressed {
                format!(" (zstd; {} uncompressed)", human_bytes(self.container_bytes))
            } else {
                String::new()
            },
            human_bytes(self.header_bytes),
            human_bytes(self.sides_bytes),
            human_bytes(self.caps_bytes),
        );
        if let Some(ms) = self.time_ms {
            let _ = write!(o, "; {ms:.1} ms");
        }
        let _ = write!(
            o,
            "\npaper:   uniform layout with maxMult = {} would be {}; sides + caps here are {:.1}% of it",
            self.max_fan,
            human_bytes(self.paper_bytes),
            pct(self.sides_bytes + self.caps_bytes, self.paper_bytes)
        );
        o.push('\n');
        o
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
