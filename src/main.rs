//! `svpack` command line: parses options, calls the library, prints.
//!
//! Exit codes: 0 success, 1 input or usage error, 2 validation failure,
//! 3 lint found a denied problem.

use clap::{Parser, Subcommand};
use std::path::PathBuf;
use std::process::ExitCode;
use svpack::build::BuildConfig;
use svpack::format::{ZSTD_LEVEL, ZSTD_LEVELS};
use svpack::layout::{DEFAULT_MAX_MULT, MAX_MAX_MULT};
use svpack::report::Summary;

/// Large buffers ask for transparent huge pages (see `svpack::alloc`).
#[global_allocator]
static ALLOC: svpack::alloc::HugePageAlloc = svpack::alloc::HugePageAlloc;

/// Progress bars on stderr (indicatif hides them when stderr is not a terminal).
mod progress {
    use indicatif::{ProgressBar, ProgressStyle};
    use std::path::{Path, PathBuf};
    use std::time::Duration;

    /// Inputs this large (about a million triangles of OBJ) get a bar of their own.
    const LARGE_INPUT: u64 = 16 << 20;

    /// A bar for a build: one step per input, the current stage as message.
    pub struct Bar(Option<ProgressBar>);

    pub fn for_build(inputs: &[PathBuf], quiet: bool) -> Bar {
        let large = inputs.iter().any(|p| {
            std::fs::metadata(p)
                .map(|m| m.len() >= LARGE_INPUT)
                .unwrap_or(false)
        });
        if quiet || (inputs.len() < 2 && !large) {
            return Bar(None);
        }
        let pb = ProgressBar::new(inputs.len() as u64);
        pb.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {wide_msg}",
            )
            .expect("valid template"),
        );
        pb.enable_steady_tick(Duration::from_millis(120));
        Bar(Some(pb))
    }

    impl Bar {
        pub fn stage(&self, input: &Path, stage: &str) {
            if let Some(pb) = &self.0 {
                let name = input
                    .file_name()
                    .map(|n| n.to_string_lossy())
                    .unwrap_or_default();
                pb.set_message(format!("{name}: {stage}"));
            }
        }
        pub fn done_one(&self) {
            if let Some(pb) = &self.0 {
                pb.inc(1);
            }
        }
        pub fn finish(&self) {
            if let Some(pb) = &self.0 {
                pb.finish_and_clear();
            }
        }
    }

    /// A bar over the lights of `verify` for large files.
    pub fn for_lights(lights: usize, triangles: u64, quiet: bool) -> Option<ProgressBar> {
        if quiet || triangles < 1_000_000 {
            return None;
        }
        let pb = ProgressBar::new(lights as u64);
        pb.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} lights",
            )
            .expect("valid template"),
        );
        Some(pb)
    }
}

/// Silhouette shadow-volume geometry for WebGL 1 (Milet et al. 2015).
#[derive(Parser)]
#[command(name = "svpack", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Worker threads for everything that runs in parallel (builds of
    /// several inputs, the evaluator, verify, bench); 0 = one per core.
    /// Outputs are byte-identical whatever the value.
    #[arg(long, global = true, default_value_t = 0)]
    threads: usize,
    /// No progress bars. (They are shown on stderr only when it is a
    /// terminal, for several inputs or an input of 16 MiB or more.)
    #[arg(long, short, global = true)]
    quiet: bool,
}

#[derive(Subcommand)]
enum Command {
    /// Build .svpk files from glTF 2.0 (.gltf/.glb) or OBJ files.
    ///
    /// One input: OUTPUT is the file to write (or a directory). Several
    /// inputs: OUTPUT is a directory (created if missing) and each input
    /// writes OUTPUT/<input stem>.svpk; failing inputs are reported at the
    /// end and the others are still built.
    Build {
        /// Input .gltf, .glb or .obj files.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Output .svpk file, or directory for several inputs (written atomically).
        #[arg(short, long)]
        output: PathBuf,
        /// Inputs built in parallel (0: one per core). Outputs are identical
        /// whatever the value.
        #[arg(long, default_value_t = 0)]
        jobs: usize,
        /// Memory budget of a batch, as bytes or with a binary unit (K, M,
        /// G, T: 1024^n; `512M`, `8G`, `1.5GiB`). An input starts only
        /// while the estimated peaks of the builds running, its own and the
        /// blocks kept for reuse (a quarter, at most 256 MiB) fit; one whose
        /// estimate is above what that leaves is built alone. The estimate is read from each file (`--timings` prints
        /// it); outputs are identical whatever the budget.
        #[arg(long, value_name = "SIZE", value_parser = parse_size)]
        max_memory: Option<u64>,
        /// K: most opposite vertices per side instance; edges with more are
        /// split. The sides shader needs 3 + K vertex attributes; the default 5
        /// fits the 8 every WebGL 1 device has.
        #[arg(long, default_value_t = DEFAULT_MAX_MULT,
              value_parser = clap::value_parser!(u32).range(1..=MAX_MAX_MULT as i64))]
        max_mult: u32,
        /// Wrap the file in a standard zstd frame (readers detect it), at
        /// level 9 unless --compress-level gives another.
        #[arg(long)]
        compress: bool,
        /// zstd level of the frame, 1 (fastest) to 22 (smallest); implies
        /// --compress. The file inside the frame is the same at every level.
        /// `svpack bench --compression` measures each level's size and speed
        /// on your models.
        #[arg(long, value_name = "LEVEL", allow_negative_numbers = true,
              value_parser = clap::value_parser!(i32).range(*ZSTD_LEVELS.start() as i64..=*ZSTD_LEVELS.end() as i64))]
        compress_level: Option<i32>,
        /// Position encoding: `f32` (16 bytes per vec4, exact input
        /// positions) or `unorm16` (8 bytes per vec4: positions quantised to
        /// 16 bits over the mesh bounds; format-spec §4.5). Quantisation moves
        /// vertices by at most half a step (bounds / 131070 per axis); the
        /// volumes stay closed.
        #[arg(long, value_enum, default_value_t = PositionsArg::F32)]
        positions: PositionsArg,
        /// Print the summary as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// After writing, run `verify` on the output (exit 2 if it fails).
        #[arg(long)]
        verify: bool,
        /// Add per-stage wall times (load, weld, topology, layout, write,
        /// total), the time inside the calls that copy the output into the
        /// file (write_calls, summed over threads), peak memory and whether
        /// the build met cold memory to the summary (`timings_ms`,
        /// `peak_memory_bytes`, `cold_memory` in JSON).
        #[arg(long)]
        timings: bool,
        /// Write a timeline of the build's threads to FILE, as Chrome trace
        /// event JSON (open it in ui.perfetto.dev): the stages, the weld's
        /// steps, the topology's passes, each unit's fill and write, and the
        /// waits between them. `benches/trace_summary.py FILE` sums it up.
        #[arg(long, value_name = "FILE")]
        trace: Option<PathBuf>,
        #[command(flatten)]
        lights: LightArgs,
    },
    /// Read a .svpk file back, check it, and report what it holds.
    Inspect {
        /// The .svpk file.
        file: PathBuf,
        /// Print the summary as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// zstd level of the compressed size reported for a plain file (the
        /// size `build --compress-level LEVEL` writes).
        #[arg(long, value_name = "LEVEL", default_value_t = ZSTD_LEVEL, allow_negative_numbers = true,
              value_parser = clap::value_parser!(i32).range(*ZSTD_LEVELS.start() as i64..=*ZSTD_LEVELS.end() as i64))]
        compress_level: i32,
    },
    /// Check assets for problems that matter to shadow geometry (codes in
    /// README). Exit 3 when a denied finding is present; error-severity
    /// findings are always denied.
    Lint {
        /// Input .gltf, .glb or .obj files.
        #[arg(required = true)]
        inputs: Vec<PathBuf>,
        /// Print findings as JSON (an array of {file, findings | error}).
        #[arg(long)]
        json: bool,
        /// Deny `warnings` (every warning) or the given codes; repeatable.
        #[arg(long, value_name = "warnings|CODE")]
        deny: Vec<String>,
        /// K used to predict which edges `build` will split.
        #[arg(long, default_value_t = DEFAULT_MAX_MULT,
              value_parser = clap::value_parser!(u32).range(1..=MAX_MAX_MULT as i64))]
        max_mult: u32,
    },
    /// Summarise every .svpk file under a directory as one table, largest first.
    Report {
        /// Directory searched recursively for .svpk files.
        dir: PathBuf,
        /// Print a JSON array of {file, summary | error} instead.
        #[arg(long)]
        json: bool,
    },
    /// Benchmarks. `--accuracy`: speed against error of the multiplicity
    /// strategies (Kim 2008, Pečiva 2013, reference edge f32 and f64, exact)
    /// and of the f32 and unorm16 encodings, on the built-in hard-case suite
    /// and INPUTS; writes accuracy.md, accuracy.json and accuracy.svg to --out.
    /// `--compression`: size against speed of the zstd levels of `build
    /// --compress-level` on INPUTS (f32 and unorm16); writes compression.md,
    /// compression.json and compression.svg to --out. `--parallel`: build
    /// speed-up with each thread count on INPUTS (and on all of them as one
    /// batch), every output checked to be the same bytes whatever the count;
    /// writes parallel.md, parallel.json and parallel.svg to --out, and
    /// exits 1 if some output differs.
    #[command(group(clap::ArgGroup::new("which").required(true).args(["accuracy", "compression", "parallel"])))]
    Bench {
        /// Run the accuracy benchmark.
        #[arg(long)]
        accuracy: bool,
        /// Run the compression benchmark (needs INPUTS).
        #[arg(long, requires = "inputs")]
        compression: bool,
        /// Run the thread-scaling benchmark (needs INPUTS).
        #[arg(long, requires = "inputs")]
        parallel: bool,
        /// Model files (.obj, .gltf, .glb); for --accuracy, besides the
        /// hard-case suite.
        inputs: Vec<PathBuf>,
        /// Output directory (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Generated lights per input (--accuracy).
        #[arg(long, default_value_t = 16)]
        lights: usize,
        /// Sample points per input for the shadow-truth checks (--accuracy).
        #[arg(long, default_value_t = 64)]
        samples: usize,
        /// Seed for lights and samples (--accuracy).
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Leave out the built-in hard-case suite (--accuracy).
        #[arg(long)]
        no_hard_cases: bool,
        /// zstd levels measured by --compression, comma-separated.
        #[arg(long, value_delimiter = ',', allow_negative_numbers = true, default_values_t = svpack::compression::CompressionConfig::default().levels,
              value_parser = clap::value_parser!(i32).range(*ZSTD_LEVELS.start() as i64..=*ZSTD_LEVELS.end() as i64))]
        levels: Vec<i32>,
        /// Timing runs per measurement: for --compression the fastest counts
        /// (default 3); for --parallel, timed builds per input and thread
        /// count (default 10).
        #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
        reps: Option<u64>,
        /// Thread counts measured by --parallel, comma-separated (default 1,
        /// 2, 4, … and the number of cores).
        #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u64).range(1..=1024))]
        thread_counts: Vec<u64>,
        /// With --parallel: run every build as a command of its own (this
        /// binary's `build`), as a pipeline runs one command per model, its
        /// memory fresh; the memory column is then each command's peak.
        #[arg(long, requires = "parallel")]
        fresh_process: bool,
    },
    /// Replay a .svpk file on the CPU: check the sides/caps bijection and,
    /// per light, that the emitted shadow volume is closed. Exit 2 on failure.
    Verify {
        /// The .svpk file.
        file: PathBuf,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        lights: LightArgs,
    },
}

/// Light selection shared by `verify` and `build --verify`.
#[derive(clap::Args)]
struct LightArgs {
    /// A light x,y,z,w (w = 1 point, w = 0 directional), world space;
    /// repeatable. Negative and exponent values work: --light -1e6,2,-3.5,1
    #[arg(long = "light", value_name = "X,Y,Z,W", allow_hyphen_values = true,
          value_parser = parse_light)]
    light: Vec<[f32; 4]>,
    /// Number of lights chosen deterministically (around and inside the
    /// bounds, on vertices, on edge lines, in triangle planes, directional
    /// parallel to faces). Default 16 when no --light is given.
    #[arg(long)]
    lights: Option<usize>,
    /// Seed for --lights.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Sample points per mesh for the shadow-truth check (in and around the
    /// bounds, and on a receiver plane below the model); 0 skips the check.
    #[arg(long, default_value_t = 256)]
    samples: usize,
    /// Evaluator replayed: `reference` (the format's contract, what the
    /// shaders compute); peers: `kim` (Kim 2008's per-edge light plane, to see
    /// it crack), `peciva` (Pečiva 2013: discard triangles whose three edge
    /// tests disagree), `reference-f64`, `exact`.
    #[arg(long, value_enum, default_value_t = EvaluatorArg::Reference)]
    evaluator: EvaluatorArg,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum PositionsArg {
    F32,
    Unorm16,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum EvaluatorArg {
    Reference,
    Kim,
    Peciva,
    ReferenceF64,
    Exact,
}

/// A size in bytes: a number, optionally with a fraction, then an optional
/// binary unit (K, M, G, T, each 1024 times the last, with an optional
/// "iB" or "B"; case ignored): `4096`, `512M`, `1.5GiB`.
fn parse_size(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let bad = || {
        format!("{s:?} is not a size (a number of bytes, or with K, M, G or T: 512M, 8G, 1.5GiB)")
    };
    let value: f64 = number.parse().map_err(|_| bad())?;
    let unit = unit.trim().to_ascii_lowercase();
    let shift = match unit.as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        _ => return Err(bad()),
    };
    let bytes = (value * (1u64 << shift) as f64).round();
    if !(1.0..1.8e19).contains(&bytes) {
        return Err(format!(
            "{s:?}: the size must be at least 1 byte and below 16 EiB"
        ));
    }
    Ok(bytes as u64)
}

fn parse_light(s: &str) -> Result<[f32; 4], String> {
    svpack::verify::parse_light(s)
}

/// Verifies `file` with the chosen lights and prints the report; returns
/// whether everything held.
fn run_verify(
    file: &std::path::Path,
    args: &LightArgs,
    json: bool,
    quiet: bool,
) -> Result<bool, svpack::error::Error> {
    let f = svpack::format::read_file(file)?;
    use svpack::verify::VerifyLight;
    let mut lights: Vec<VerifyLight> = args.light.iter().map(|&l| VerifyLight::World(l)).collect();
    let generated = args
        .lights
        .unwrap_or(if lights.is_empty() { 16 } else { 0 });
    // Decoded once, for the lights and for the checks; the report's time
    // covers both, as `verify_with`'s does.
    let start = std::time::Instant::now();
    let decoded = svpack::verify::decode_all(&f);
    if generated > 0 && f.header.meshes.iter().any(|m| m.caps.count > 0) {
        // Generated in record space, where the hard placements are exact
        // (the same as world space for f32 files).
        let d = &decoded[0];
        let world = f.encoding() == svpack::format::Encoding::F32;
        lights.extend(
            svpack::verify::choose_lights(d, generated, args.seed)
                .into_iter()
                .map(|l| {
                    if world {
                        VerifyLight::World(l)
                    } else {
                        VerifyLight::Record(l)
                    }
                }),
        );
    }
    use svpack::evaluate::Strategy;
    let strategy = match args.evaluator {
        EvaluatorArg::Reference => Strategy::Reference,
        EvaluatorArg::Kim => Strategy::Kim,
        EvaluatorArg::Peciva => Strategy::Peciva,
        EvaluatorArg::ReferenceF64 => Strategy::ReferenceF64,
        EvaluatorArg::Exact => Strategy::Exact,
    };
    let triangles = f.header.meshes.iter().map(|m| m.caps.count).sum();
    let bar = progress::for_lights(lights.len(), triangles, quiet);
    let mut rep =
        svpack::verify::verify_decoded(&decoded, &lights, strategy, args.samples, &|| {
            if let Some(b) = &bar {
                b.inc(1)
            }
        });
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    rep.time_ms = start.elapsed().as_secs_f64() * 1e3;
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&rep).expect("report serialises")
        );
    } else {
        println!(
            "verify {}: {} triangles, {} edge instances, {} lights",
            file.display(),
            rep.triangles,
            rep.edge_instances,
            rep.lights.len()
        );
        println!(
            "structure: {} bijection errors, {} record errors (wrong .w values or A >= B){}",
            rep.bijection_errors,
            rep.record_errors,
            rep.first_problem
                .as_deref()
                .map(|p| format!(" (first: {p})"))
                .unwrap_or_default()
        );
        println!(
            "  light                                      silhouette    quads     caps  violations  samples  on-face  mismatches     ms"
        );
        for l in &rep.lights {
            let name = format!(
                "({}, {}, {}, {}){}",
                l.light[0],
                l.light[1],
                l.light[2],
                l.light[3],
                if l.space == "record" { " rec" } else { "" }
            );
            println!(
                "  {name:<42} {:>10} {:>8} {:>8} {:>11} {:>8} {:>8} {:>11} {:>6.1}",
                l.silhouette_instances,
                l.side_quads,
                l.caps,
                l.closedness_violations,
                l.samples,
                l.samples_on_faces,
                l.sample_mismatches,
                l.time_ms
            );
        }
        if let Some(m) = &rep.first_mismatch {
            println!("first mismatch: {m}");
        }
        if rep.orientation_errors > 0 {
            println!(
                "note: {} triangle orientations differ from the exact ones (f32 precision; lights within rounding distance of triangle planes)",
                rep.orientation_errors
            );
        }
        println!(
            "{}: {} closedness violations, {} sample mismatches ({} samples compared, {} on volume faces) over {} lights ({} failing), {:.1} ms",
            if rep.ok { "OK" } else { "FAILED" },
            rep.closedness_violations,
            rep.sample_mismatches,
            rep.samples,
            rep.samples_on_faces,
            rep.lights.len(),
            rep.failing_lights,
            rep.time_ms
        );
    }
    Ok(rep.ok)
}

fn print_summary(s: &Summary, json: bool) {
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(s).expect("summary serialises")
        );
    } else {
        print!("{}", s.to_text());
    }
}

/// Outcome of a command that ran without input errors.
enum Outcome {
    Ok,
    ValidationFailed,
    LintDenied,
}

/// Runs lint on every input and prints; returns whether a denied finding was found.
fn run_lint(
    inputs: &[PathBuf],
    json: bool,
    deny: &[String],
    max_mult: u32,
) -> Result<Outcome, svpack::error::Error> {
    use svpack::lint::{CODES, Severity};
    for d in deny {
        if d != "warnings" && !CODES.iter().any(|c| c.0 == d) {
            let known: Vec<&str> = CODES.iter().map(|c| c.0).collect();
            return Err(svpack::error::Error::Other(format!(
                "--deny {d}: unknown code (use `warnings` or one of: {})",
                known.join(", ")
            )));
        }
    }
    let denied = |f: &svpack::lint::Finding| {
        f.severity == Severity::Error
            || (f.severity == Severity::Warning && deny.iter().any(|d| d == "warnings"))
            || deny.iter().any(|d| d == f.code)
    };
    let mut any_denied = false;
    let mut failures = 0;
    let mut items = Vec::new();
    if !json {
        println!(
            "{:<8} {:<22} {:>9}  {:<24} message (first example)",
            "severity", "code", "count", "file"
        );
    }
    for input in inputs {
        match svpack::lint::lint_file(input, max_mult) {
            Ok(findings) => {
                any_denied |= findings.iter().any(denied);
                if json {
                    items.push(serde_json::json!({ "file": input, "findings": findings }));
                } else {
                    for f in &findings {
                        let example = f
                            .examples
                            .first()
                            .map(|e| {
                                format!(
                                    " (triangle {} in {}, {:?})",
                                    e.triangle, e.part, e.positions
                                )
                            })
                            .unwrap_or_default();
                        println!(
                            "{:<8} {:<22} {:>9}  {:<24} {}{example}{}",
                            format!("{:?}", f.severity).to_lowercase(),
                            f.code,
                            f.count,
                            input
                                .file_name()
                                .map(|n| n.to_string_lossy().into_owned())
                                .unwrap_or_default(),
                            f.message,
                            if denied(f) { "  [denied]" } else { "" }
                        );
                    }
                }
            }
            Err(e) => {
                eprintln!("error: {e}");
                failures += 1;
                if json {
                    items.push(serde_json::json!({ "file": input, "error": e.to_string() }));
                }
            }
        }
    }
    if json {
        println!(
            "{}",
            serde_json::to_string_pretty(&items).expect("serialises")
        );
    }
    if failures > 0 {
        return Err(svpack::error::Error::Other(format!(
            "{failures} of {} inputs could not be read",
            inputs.len()
        )));
    }
    Ok(if any_denied {
        Outcome::LintDenied
    } else {
        Outcome::Ok
    })
}

fn run(cli: Cli) -> Result<Outcome, svpack::error::Error> {
    if cli.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(cli.threads)
            .build_global()
            .map_err(|e| {
                svpack::error::Error::Other(format!("cannot start {} threads: {e}", cli.threads))
            })?;
    }
    match cli.command {
        Command::Build {
            inputs,
            output,
            jobs,
            max_memory,
            max_mult,
            compress,
            compress_level,
            positions,
            json,
            verify,
            timings,
            trace,
            lights,
        } => {
            let compress = compress_level.or(compress.then_some(ZSTD_LEVEL));
            let cfg = BuildConfig {
                max_mult,
                compress,
                positions: match positions {
                    PositionsArg::F32 => svpack::format::Encoding::F32,
                    PositionsArg::Unorm16 => svpack::format::Encoding::Unorm16,
                },
            };
            let batch = inputs.len() > 1 || output.is_dir();
            let outputs = if batch {
                std::fs::create_dir_all(&output)
                    .map_err(|e| svpack::error::Error::io(&output, e))?;
                svpack::build::batch_outputs(&inputs, &output)?
            } else {
                vec![output.clone()]
            };
            let batch_cfg = svpack::build::BatchConfig {
                jobs: if jobs == 0 { cli.threads } else { jobs },
                max_memory,
            };
            // The pool's threads, which each build's estimate counts.
            let threads = match batch_cfg.jobs {
                0 => rayon::current_num_threads(),
                n => n,
            };
            let estimate =
                |input: &std::path::Path| svpack::build::memory_estimate(input, &cfg, threads);
            if let (Some(budget), Some(left)) = (max_memory, batch_cfg.builds_budget())
                && batch
                && !cli.quiet
            {
                for input in &inputs {
                    let e = estimate(input);
                    if e > left {
                        eprintln!(
                            "note: {}: its estimated peak, {}, is above the {} that --max-memory {} leaves the builds (the rest holds freed blocks for reuse); it is built with no other build beside it",
                            input.display(),
                            svpack::report::human_bytes(e),
                            svpack::report::human_bytes(left),
                            svpack::report::human_bytes(budget)
                        );
                    }
                }
            }
            let bar = progress::for_build(&inputs, cli.quiet);
            let trace_file = trace
                .as_deref()
                .map(svpack::trace::TraceFile::create)
                .transpose()?;
            let recording = trace_file.as_ref().map(|_| svpack::trace::start());
            let results = svpack::build::build_batch_with(
                &inputs,
                &outputs,
                &cfg,
                &batch_cfg,
                &|n, stage| bar.stage(&inputs[n], stage),
                &|_| bar.done_one(),
            );
            bar.finish();
            if let (Some(file), Some(recording)) = (trace_file, recording) {
                file.write(&recording.finish())?;
            }
            let mut failures = Vec::new();
            let mut json_items = Vec::new();
            let mut verify_failed = false;
            for ((input, output), result) in inputs.iter().zip(&outputs).zip(results) {
                match result {
                    Ok(out) => {
                        for w in &out.warnings {
                            eprintln!("warning: {}: {w}", input.display());
                        }
                        let mut s =
                            Summary::from_header(&out.header, out.file_bytes, compress.is_some());
                        s.zstd_level = compress;
                        s.time_ms = Some(out.elapsed.as_secs_f64() * 1e3);
                        if timings {
                            s.timings_ms = Some(out.timings);
                            s.peak_memory_bytes = svpack::build::peak_memory_bytes();
                            s.memory_estimate_bytes = Some(estimate(input));
                            s.cold_memory = Some(svpack::alloc::cold_memory_seen());
                        }
                        s.warnings = out.warnings;
                        if json && batch {
                            json_items.push(serde_json::json!({
                                "input": input, "output": output, "ok": true, "summary": s
                            }));
                        } else {
                            if !json {
                                println!("{} -> {}", input.display(), output.display());
                            }
                            print_summary(&s, json);
                        }
                        if verify && !run_verify(output, &lights, json && !batch, cli.quiet)? {
                            verify_failed = true;
                        }
                    }
                    Err(e) => {
                        if !batch {
                            return Err(e);
                        }
                        eprintln!("error: {e}");
                        if json {
                            json_items.push(serde_json::json!({
                                "input": input, "output": output, "ok": false, "error": e.to_string()
                            }));
                        }
                        failures.push(e.to_string());
                    }
                }
            }
            if json && batch {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&json_items).expect("serialises")
                );
            }
            if !failures.is_empty() {
                eprintln!("{} of {} inputs failed:", failures.len(), inputs.len());
                for f in &failures {
                    eprintln!("  {f}");
                }
                return Err(svpack::error::Error::Other(format!(
                    "{} of {} inputs failed",
                    failures.len(),
                    inputs.len()
                )));
            }
            if verify_failed {
                return Ok(Outcome::ValidationFailed);
            }
        }
        Command::Inspect {
            file,
            json,
            compress_level,
        } => {
            let f = svpack::format::read_file(&file)?;
            let mut s = Summary::from_header(&f.header, f.file_bytes, f.compressed);
            s.zstd_bytes = Some(svpack::format::zstd_size(&f, compress_level));
            s.zstd_level = (!f.compressed).then_some(compress_level);
            if !json {
                println!(
                    "{}: svpk {}.{}, written by {}",
                    file.display(),
                    svpack::format::VERSION_MAJOR,
                    f.version_minor,
                    f.header.generator
                );
            }
            print_summary(&s, json);
        }
        Command::Lint {
            inputs,
            json,
            deny,
            max_mult,
        } => return run_lint(&inputs, json, &deny, max_mult),
        Command::Report { dir, json } => {
            let rows = svpack::report::summarize_dir(&dir)?;
            if json {
                let items: Vec<serde_json::Value> = rows
                    .iter()
                    .map(|(p, r)| match r {
                        Ok(s) => serde_json::json!({ "file": p, "summary": s }),
                        Err(e) => serde_json::json!({ "file": p, "error": e.to_string() }),
                    })
                    .collect();
                println!(
                    "{}",
                    serde_json::to_string_pretty(&items).expect("serialises")
                );
            } else {
                print!("{}", svpack::report::report_table(&rows));
            }
            if rows.iter().any(|r| r.1.is_err()) {
                return Err(svpack::error::Error::Other(
                    "some files could not be read".into(),
                ));
            }
        }
        Command::Bench {
            accuracy: _,
            compression,
            parallel,
            inputs,
            out,
            lights,
            samples,
            seed,
            no_hard_cases,
            levels,
            reps,
            thread_counts,
            fresh_process,
        } => {
            let progress = &mut |line: &str| eprintln!("{line}");
            // The parallel bench's builds write where its report goes, as a
            // build writes beside its outputs; the others' files are small
            // or not timed.
            let work = if parallel {
                std::fs::create_dir_all(&out).map_err(|e| svpack::error::Error::io(&out, e))?;
                tempfile::Builder::new()
                    .prefix(".svpack-bench")
                    .tempdir_in(&out)
            } else {
                tempfile::tempdir()
            }
            .map_err(|e| svpack::error::Error::io(&out, e))?;
            let mut differing = Vec::new();
            let (md, paths, seconds, failed) = if parallel {
                let mut cfg = svpack::parallel::ParallelConfig::default();
                if !thread_counts.is_empty() {
                    cfg.threads = thread_counts.iter().map(|&t| t as usize).collect();
                }
                cfg.rounds = reps.map_or(cfg.rounds, |r| r as usize);
                if fresh_process {
                    let exe = std::env::current_exe().map_err(|e| {
                        svpack::error::Error::Other(format!(
                            "--fresh-process: cannot find this program's file: {e}"
                        ))
                    })?;
                    cfg.command = Some(exe);
                }
                let rep = svpack::parallel::run(&inputs, &cfg, work.path(), progress)?;
                let paths = svpack::parallel::write_outputs(&rep, &out)?;
                differing = rep.differing();
                let md = svpack::parallel::to_markdown(&rep);
                (md, paths, rep.seconds, rep.failed.len())
            } else if compression {
                let cfg = svpack::compression::CompressionConfig {
                    levels,
                    reps: reps.map_or(
                        svpack::compression::CompressionConfig::default().reps,
                        |r| r as usize,
                    ),
                };
                let rep = svpack::compression::run(&inputs, &cfg, work.path(), progress)?;
                let paths = svpack::compression::write_outputs(&rep, &out)?;
                let md = svpack::compression::to_markdown(&rep);
                (md, paths, rep.seconds, rep.failed.len())
            } else {
                let cfg = svpack::accuracy::AccuracyConfig {
                    lights,
                    samples,
                    seed,
                    hard_cases: !no_hard_cases,
                    ..Default::default()
                };
                let rep = svpack::accuracy::run(&inputs, &cfg, work.path(), progress)?;
                let paths = svpack::accuracy::write_outputs(&rep, &out)?;
                let md = svpack::accuracy::to_markdown(&rep);
                (md, paths, rep.seconds, rep.failed.len())
            };
            print!("{md}");
            for p in paths {
                eprintln!("wrote {}", p.display());
            }
            eprintln!("{seconds:.1} s");
            if !differing.is_empty() {
                let which: Vec<String> = differing
                    .iter()
                    .map(|(input, t)| {
                        format!("{input} with {t} thread{}", if *t == 1 { "" } else { "s" })
                    })
                    .collect();
                return Err(svpack::error::Error::Other(format!(
                    "outputs differ from the one-thread build's: {}",
                    which.join(", ")
                )));
            }
            if failed > 0 {
                return Err(svpack::error::Error::Other(format!(
                    "{failed} inputs could not be built"
                )));
            }
        }
        Command::Verify { file, json, lights } => {
            if !run_verify(&file, &lights, json, cli.quiet)? {
                return Ok(Outcome::ValidationFailed);
            }
        }
    }
    Ok(Outcome::Ok)
}

fn main() -> ExitCode {
    // `svpack … | head` must end quietly like any Unix tool, not panic in
    // println! when the reader goes away: restore the default SIGPIPE action
    // (Rust ignores the signal and turns it into an error).
    #[cfg(unix)]
    // SAFETY: called first thing in main, before any other thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // clap uses exit code 2 for usage errors; 2 is reserved for
            // validation failures here, so usage errors exit with 1.
            let _ = e.print();
            return if e.use_stderr() {
                ExitCode::from(1)
            } else {
                ExitCode::SUCCESS
            };
        }
    };
    match run(cli) {
        Ok(Outcome::Ok) => ExitCode::SUCCESS,
        Ok(Outcome::ValidationFailed) => ExitCode::from(2),
        Ok(Outcome::LintDenied) => ExitCode::from(3),
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::parse_size;

    /// Sizes in bytes and binary units, case ignored, a fraction allowed;
    /// anything else refused with a message naming the text. Caught: `K`
    /// taken as 1 (no shift); `KiB` not accepted.
    #[test]
    fn sizes_take_binary_units() {
        for (text, bytes) in [
            ("4096", 4096),
            ("1b", 1),
            ("2K", 2048),
            ("2 KiB", 2048),
            ("512M", 512 << 20),
            ("512mb", 512 << 20),
            ("1.5GiB", 3 << 29),
            ("8g", 8 << 30),
            ("1T", 1 << 40),
        ] {
            assert_eq!(parse_size(text), Ok(bytes), "{text}");
        }
        for text in [
            "",
            "M",
            "1.2.3",
            "5X",
            "0",
            "0.1",
            "-1G",
            "1e3",
            "99999999T",
        ] {
            let e = parse_size(text).unwrap_err();
            assert!(e.contains(&format!("{text:?}")), "{text}: {e}");
        }
    }
}
