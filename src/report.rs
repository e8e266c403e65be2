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
            compressed,
            stats: stats.clone(),
            buckets,
            sides_bytes,
            caps_bytes,
            header_bytes: h.payload_offset,
            container_bytes: h.payload_offset + h.payload_len,
            file_bytes,
            paper_bytes: paper_bytes(stats.edges, stats.triangles, stats.max_fan),
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
            "sides:   {} instances, {} (K = {})",
            self.stats.edge_instances,
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
            self.stats.triangles,
            human_bytes(self.caps_bytes)
        );
        let _ = write!(
            o,
            "output:  {}{}: header {}, sides {}, caps {}",
            human_bytes(self.file_bytes),
            if self.compressed {
                format!(
                    " (zstd; {} uncompressed)",
                    human_bytes(self.container_bytes)
                )
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
            self.stats.max_fan,
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
