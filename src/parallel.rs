//! `svpack bench --parallel`: how a build speeds up with threads on the
//! caller's models, and whether every thread count writes the same bytes.
//!
//! For each input, one build per thread count per round, the counts taking
//! turns (their order reversed every other round, so that a slow phase of
//! the machine falls on all of them alike); each build runs as `svpack
//! build --threads N` runs it ([`crate::build::build_batch`] with one input
//! and a pool of N threads), into a file of its own that is removed before
//! the next (so no build pays for removing the last one's output). A first,
//! untimed build with one thread reads the input into the page cache and
//! gives the reference output: every timed build's file must be the same
//! bytes (SHA-256 of the whole file), whatever its thread count. An input
//! whose first build is short gets more rounds than asked for
//! ([`ROUND_TIME`]). With two inputs or more, the whole set is also built
//! as one batch ([`crate::build::build_batch`] with N jobs, as `svpack
//! build A B ... -o DIR --threads N`), in [`ParallelConfig::rounds`]
//! rounds, each output checked against its input's reference.
//!
//! Why: the README's targets measure one-thread and two-thread builds of two
//! inputs on one machine (`benches/targets.py`); a studio's build machines
//! have other core counts and other models. This gives them the same
//! figures on their own: the time after parsing (weld, topology, layout and
//! write: what the thread count can speed up) and the whole build, the
//! speed-up over the first count (one thread unless told otherwise), and the
//! check that the outputs do not depend on the count.
//!
//! The builds run in this process, one after another: the pages one build
//! frees may serve the next, as in a batch, where a build in a fresh process
//! (one command per model) first touches fresh pages. Times are wall times
//! from the build's own stage clocks (`--timings`). The memory of a count
//! is the most the process's resident size rose during one of its builds
//! above its size just before it: the kernel's high-water mark, reset
//! before each build ([`crate::build::reset_peak_memory`]). Not the
//! process's peak: this process holds memory of its own and of the builds
//! before (malloc's arenas of their threads), some 15 MiB more than a
//! build's own process starts with.
//!
//! With [`ParallelConfig::command`] every build runs instead as a command
//! of its own (`svpack build --timings --json`, its times read from the
//! summary), as a pipeline that runs one command per model runs it: its
//! buffers start from fresh pages, which on a virtual machine can come
//! cold, and the memory is each command's peak.

use crate::build::{BuildConfig, Timings, build_batch, file_name};
use crate::error::{Error, Result};
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of a parallel run.
#[derive(Debug, Clone, Serialize)]
pub struct ParallelConfig {
    /// Thread counts to measure, each at least 1; measured in ascending
    /// order, each once. Speed-ups are against the smallest.
    pub threads: Vec<usize>,
    /// Timed builds per input and thread count, at least: an input whose
    /// untimed one-thread build took less than [`ROUND_TIME`] /
    /// `rounds` gets more rounds, so that its one-thread builds take
    /// about [`ROUND_TIME`] in all, up to [`MAX_ROUNDS`].
    pub rounds: usize,
    /// Run every build as a command of its own: this `svpack` binary's
    /// `build --timings --json` (the batch's as `build A B … -o DIR`), as a
    /// pipeline runs one command per model, so that each build's buffers
    /// start from fresh pages. None: every build runs in this process.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub command: Option<PathBuf>,
}

/// About how long an input's one-thread builds take in all: short builds
/// get more rounds than [`ParallelConfig::rounds`] until they fill it.
///
/// Why: the builds of a 70–90k-triangle model take 3–5 ms after parsing,
/// and four rounds of them put the bunny's and the armadillo's two-thread
/// speed-ups at 0.80× and 0.95×, ten at 1.33× and 1.66× (one local run
/// each): a few slow builds move the median of a short set.
pub const ROUND_TIME: std::time::Duration = std::time::Duration::from_secs(1);

/// Most rounds an input gets for being short (unless
/// [`ParallelConfig::rounds`] asks for more).
pub const MAX_ROUNDS: usize = 100;

/// The rounds for an input whose untimed one-thread build took `first`:
/// `least`, or as many as fill [`ROUND_TIME`], up to [`MAX_ROUNDS`].
fn rounds_for(first: std::time::Duration, least: usize) -> usize {
    let fill = (ROUND_TIME.as_secs_f64() / first.as_secs_f64().max(1e-6)).ceil();
    least.max((fill as usize).min(MAX_ROUNDS))
}

impl Default for ParallelConfig {
    fn default() -> Self {
        ParallelConfig {
            threads: default_thread_counts(cores()),
            rounds: 10,
            command: None,
        }
    }
}

/// Cores this process may run on (1 when unknown).
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// 1, 2, 4, … below `cores`, then `cores` itself: the counts worth asking
/// for on a machine with that many cores.
pub fn default_thread_counts(cores: usize) -> Vec<usize> {
    let cores = cores.max(1);
    let mut v: Vec<usize> = std::iter::successors(Some(1usize), |&n| n.checked_mul(2))
        .take_while(|&n| n < cores)
        .collect();
    v.push(cores);
    v
}

/// Fastest and median of a set of timings, ms (or of a ratio of two such).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Spread {
    /// Smallest value.
    pub fastest: f64,
    /// Median (the mean of the two middle values of an even count).
    pub median: f64,
}

impl Spread {
    /// Fastest and median of `v` (empty: zeros).
    pub fn of(v: &[f64]) -> Spread {
        if v.is_empty() {
            return Spread::default();
        }
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        };
        Spread {
            fastest: v[0],
            median,
        }
    }

    /// `base` over `self`, fastest over fastest and median over median: the
    /// speed-up of `self`'s times against `base`'s.
    pub fn speedup_from(self, base: Spread) -> Spread {
        Spread {
            fastest: base.fastest / self.fastest,
            median: base.median / self.median,
        }
    }
}

/// One thread count on one input.
#[derive(Debug, Clone, Serialize)]
pub struct ThreadRun {
    /// Threads of the build's pool.
    pub threads: usize,
    /// The whole build (load to renamed file), ms.
    pub whole_ms: Spread,
    /// Weld + topology + layout + write, ms: the build after parsing.
    pub after_parsing_ms: Spread,
    /// The weld stage, ms.
    pub weld_ms: Spread,
    /// The topology stage, ms.
    pub topology_ms: Spread,
    /// The layout and write stages, ms.
    pub layout_write_ms: Spread,
    /// Speed-up after parsing against the first thread count.
    pub speedup: Spread,
    /// Speed-up of the whole build against the first thread count.
    pub whole_speedup: Spread,
    /// Every output of this count was the reference's bytes.
    pub identical: bool,
    /// Memory, bytes: in this process, the most its resident size rose
    /// during one of this count's builds above its size before it (see the
    /// module's notes); with [`ParallelConfig::command`], the largest peak
    /// of the count's commands (their `peak_memory_bytes`). None where it
    /// could not be measured.
    pub memory_bytes: Option<u64>,
}

/// One input.
#[derive(Debug, Clone, Serialize)]
pub struct InputResult {
    /// File name.
    pub input: String,
    /// Triangles in the output.
    pub triangles: u64,
    /// Bytes of the output.
    pub file_bytes: u64,
    /// SHA-256 of the reference output (hex).
    pub output_sha256: String,
    /// Timed builds per thread count ([`ParallelConfig::rounds`], or more
    /// for a short build).
    pub rounds: usize,
    /// Per thread count, ascending.
    pub runs: Vec<ThreadRun>,
}

/// One thread count on the whole set as one batch.
#[derive(Debug, Clone, Serialize)]
pub struct BatchRun {
    /// Jobs (threads of the batch's pool).
    pub threads: usize,
    /// Wall time of the batch, ms.
    pub wall_ms: Spread,
    /// Speed-up against the first thread count.
    pub speedup: Spread,
    /// Every output was its input's reference bytes.
    pub identical: bool,
    /// Memory, bytes, as [`ThreadRun::memory_bytes`], of the count's
    /// batches.
    pub memory_bytes: Option<u64>,
}

/// The whole set built as one batch.
#[derive(Debug, Clone, Serialize)]
pub struct BatchResult {
    /// The inputs in the batch (those that built).
    pub inputs: Vec<String>,
    /// Per thread count, ascending.
    pub runs: Vec<BatchRun>,
}

/// Everything a parallel run measured.
#[derive(Debug, Clone, Serialize)]
pub struct ParallelReport {
    /// The options (thread counts sorted and deduplicated).
    pub config: ParallelConfig,
    /// Cores this process could run on.
    pub cores: usize,
    /// Per input.
    pub inputs: Vec<InputResult>,
    /// The batch of every input that built, when there were two or more.
    pub batch: Option<BatchResult>,
    /// Why there is no batch although two inputs or more built.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub batch_note: Option<String>,
    /// Inputs that could not be built: (name, error).
    pub failed: Vec<(String, String)>,
    /// Wall time of the run, s.
    pub seconds: f64,
}

impl ParallelReport {
    /// Whether some thread count wrote other bytes than the reference, for
    /// some input or in the batch: (input or "batch", thread count).
    pub fn differing(&self) -> Vec<(String, usize)> {
        let inputs = self.inputs.iter().flat_map(|i| {
            i.runs
                .iter()
                .filter(|r| !r.identical)
                .map(|r| (i.input.clone(), r.threads))
        });
        let batch = self.batch.iter().flat_map(|b| {
            b.runs
                .iter()
                .filter(|r| !r.identical)
                .map(|r| ("batch".to_string(), r.threads))
        });
        inputs.chain(batch).collect()
    }
}

/// SHA-256 of the file at `path` (read or mapped as inputs are, hashed as
/// an input's digest is).
pub fn file_sha256(path: &Path) -> Result<[u8; 32]> {
    let bytes = crate::file_bytes::read_or_map(path).map_err(|e| Error::io(path, e))?;
    Ok(crate::load::InputDigest::of(&bytes).1)
}

/// Removes `path` if it is there.
fn remove_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => Err(Error::io(path, e)),
        _ => Ok(()),
    }
}

/// Builds `input` into `output` with a pool of `threads` threads, as the
/// command line does, after removing `output`: in this process, or with
/// `command` as that binary's `build` command.
fn build_once(
    input: &Path,
    output: &Path,
    threads: usize,
    command: Option<&Path>,
) -> Result<Built> {
    remove_if_present(output)?;
    if let Some(exe) = command {
        let args = [input.as_os_str(), "-o".as_ref(), output.as_os_str()];
        let json = run_build_command(exe, &args, threads, input)?;
        return built_from_summary(&json)
            .ok_or_else(|| Error::input(input, "the build's JSON summary lacks its timings"));
    }
    let cfg = BuildConfig::default();
    let (o, memory) = with_memory_added(|| {
        build_batch(
            &[input.to_path_buf()],
            &[output.to_path_buf()],
            &cfg,
            threads,
        )
        .pop()
        .expect("one result per input")
    });
    let o = o?;
    Ok(Built {
        timings: o.timings,
        triangles: o.header.meshes.iter().map(|m| m.stats.triangles).sum(),
        file_bytes: o.file_bytes,
        memory,
    })
}

/// Runs `work` with this process's peak memory reset before it (to its
/// resident size then), and returns how far the peak rose (None where the
/// peak cannot be reset or read).
fn with_memory_added<T>(work: impl FnOnce() -> T) -> (T, Option<u64>) {
    use crate::build::{peak_memory_bytes, reset_peak_memory};
    let start = reset_peak_memory().then(peak_memory_bytes).flatten();
    let out = work();
    let added = start
        .zip(peak_memory_bytes())
        .map(|(start, peak)| peak.saturating_sub(start));
    (out, added)
}

/// Runs `exe build ARGS --threads N --timings --json --quiet` and returns
/// its JSON summary; a failure names `what` (the input, or the batch's
/// directory) with the command's message.
fn run_build_command(
    exe: &Path,
    args: &[&std::ffi::OsStr],
    threads: usize,
    what: &Path,
) -> Result<serde_json::Value> {
    let out = std::process::Command::new(exe)
        .arg("build")
        .args(args)
        .args([
            "--threads",
            &threads.to_string(),
            "--timings",
            "--json",
            "--quiet",
        ])
        .output()
        .map_err(|e| Error::io(exe, e))?;
    if !out.status.success() {
        return Err(Error::input(
            what,
            format!(
                "`{} build` failed: {}",
                exe.display(),
                String::from_utf8_lossy(&out.stderr).trim()
            ),
        ));
    }
    serde_json::from_slice(&out.stdout)
        .map_err(|e| Error::input(what, format!("the build's JSON summary: {e}")))
}

/// The timings, size and peak memory of a `build --timings --json` summary.
fn built_from_summary(v: &serde_json::Value) -> Option<Built> {
    let t = &v["timings_ms"];
    let ms = |k: &str| t[k].as_f64();
    Some(Built {
        timings: Timings {
            load: ms("load")?,
            weld: ms("weld")?,
            topology: ms("topology")?,
            layout: ms("layout")?,
            write: ms("write")?,
            total: ms("total")?,
            write_calls: ms("write_calls")?,
        },
        triangles: v["triangles"].as_u64()?,
        file_bytes: v["file_bytes"].as_u64()?,
        memory: v["peak_memory_bytes"].as_u64(),
    })
}

/// The counts of round `r`: ascending in even rounds, descending in odd.
fn round_order(counts: &[usize], r: usize) -> Vec<usize> {
    let mut v = counts.to_vec();
    if r % 2 == 1 {
        v.reverse();
    }
    v
}

/// The timings of one thread count's builds of one input, and whether
/// every one of them wrote the reference's bytes.
#[derive(Default)]
struct Samples {
    whole: Vec<f64>,
    after: Vec<f64>,
    weld: Vec<f64>,
    topology: Vec<f64>,
    layout_write: Vec<f64>,
    identical: bool,
    /// Each build's memory ([`ThreadRun::memory_bytes`]).
    memory: Vec<Option<u64>>,
}

/// The largest of `memory`, or None if one was not measured.
fn largest(memory: &[Option<u64>]) -> Option<u64> {
    memory.iter().try_fold(0, |most, m| m.map(|m| most.max(m)))
}

/// What the bench reads of one build.
struct Built {
    timings: Timings,
    triangles: u64,
    file_bytes: u64,
    /// As [`ThreadRun::memory_bytes`], of this build.
    memory: Option<u64>,
}

impl Samples {
    fn new() -> Samples {
        Samples {
            identical: true,
            ..Samples::default()
        }
    }

    fn push(&mut self, b: &Built) {
        let t = &b.timings;
        self.memory.push(b.memory);
        self.whole.push(t.total);
        self.after.push(t.weld + t.topology + t.layout + t.write);
        self.weld.push(t.weld);
        self.topology.push(t.topology);
        self.layout_write.push(t.layout + t.write);
    }
}

/// A validated copy of `cfg`: counts sorted, each once; at least one round.
fn checked(cfg: &ParallelConfig) -> Result<ParallelConfig> {
    let mut threads = cfg.threads.clone();
    if threads.is_empty() || threads.contains(&0) {
        return Err(Error::Other(
            "thread counts must be given and each at least 1".into(),
        ));
    }
    threads.sort_unstable();
    threads.dedup();
    Ok(ParallelConfig {
        threads,
        rounds: cfg.rounds.max(1),
        command: cfg.command.clone(),
    })
}

/// Runs the benchmark on `inputs`, writing the builds' files into
/// `work_dir`. `progress` gets a line per input and thread count measured.
pub fn run(
    inputs: &[PathBuf],
    cfg: &ParallelConfig,
    work_dir: &Path,
    progress: &mut dyn FnMut(&str),
) -> Result<ParallelReport> {
    let cfg = checked(cfg)?;
    let start = Instant::now();
    let out = work_dir.join("one.svpk");
    let mut results = Vec::new();
    let mut failed = Vec::new();
    // (input path, its reference digest) of every input that built.
    let mut built: Vec<(PathBuf, [u8; 32])> = Vec::new();
    let command = cfg.command.as_deref();
    for input in inputs {
        let name = file_name(input);
        let started = Instant::now();
        let first = match build_once(input, &out, 1, command) {
            Ok(o) => o,
            Err(e) => {
                progress(&format!("{name}: skipped ({e})"));
                failed.push((name, e.to_string()));
                continue;
            }
        };
        let reference = file_sha256(&out)?;
        let rounds = rounds_for(started.elapsed(), cfg.rounds);
        let mut samples: Vec<Samples> = cfg.threads.iter().map(|_| Samples::new()).collect();
        for r in 0..rounds {
            for t in round_order(&cfg.threads, r) {
                let i = cfg.threads.iter().position(|&c| c == t).expect("a count");
                let o = build_once(input, &out, t, command)?;
                samples[i].push(&o);
                if file_sha256(&out)? != reference {
                    samples[i].identical = false;
                }
            }
        }
        let runs = thread_runs(&cfg.threads, &samples);
        for run in &runs {
            progress(&count_line(
                &name,
                run.threads,
                "after parsing ",
                run.after_parsing_ms,
                run.speedup,
                run.identical,
            ));
        }
        results.push(InputResult {
            input: name,
            rounds,
            triangles: first.triangles,
            file_bytes: first.file_bytes,
            output_sha256: crate::report::hex(&reference),
            runs,
        });
        built.push((input.clone(), reference));
    }
    remove_if_present(&out)?;
    let (batch, batch_note) = if built.len() < 2 {
        (None, None)
    } else {
        match run_batch(&built, &cfg, work_dir, progress)? {
            Ok(b) => (Some(b), None),
            Err(note) => (None, Some(note)),
        }
    };
    Ok(ParallelReport {
        config: cfg,
        cores: cores(),
        inputs: results,
        batch,
        batch_note,
        failed,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Each count's spreads from its samples, speed-ups against the first.
fn thread_runs(counts: &[usize], samples: &[Samples]) -> Vec<ThreadRun> {
    let base = (Spread::of(&samples[0].after), Spread::of(&samples[0].whole));
    counts
        .iter()
        .zip(samples)
        .map(|(&threads, s)| {
            let (after, whole) = (Spread::of(&s.after), Spread::of(&s.whole));
            ThreadRun {
                threads,
                whole_ms: whole,
                after_parsing_ms: after,
                weld_ms: Spread::of(&s.weld),
                topology_ms: Spread::of(&s.topology),
                layout_write_ms: Spread::of(&s.layout_write),
                speedup: after.speedup_from(base.0),
                whole_speedup: whole.speedup_from(base.1),
                identical: s.identical,
                memory_bytes: largest(&s.memory),
            }
        })
        .collect()
}

/// The inputs of `built` as one batch per count per round, into
/// `work_dir/batch`, each output checked against its reference; or, as
/// commands, why the command line would refuse the batch (inputs that
/// share a stem).
fn run_batch(
    built: &[(PathBuf, [u8; 32])],
    cfg: &ParallelConfig,
    work_dir: &Path,
    progress: &mut dyn FnMut(&str),
) -> Result<std::result::Result<BatchResult, String>> {
    let dir = work_dir.join("batch");
    let inputs: Vec<PathBuf> = built.iter().map(|(p, _)| p.clone()).collect();
    // In this process numbered, not named by stem as the command line
    // names them: inputs with the same stem (a model as .obj and as .glb)
    // can be measured together, and an output's name is not in its bytes.
    // As a command, by stem, as the command line names them.
    let outputs: Vec<PathBuf> = match &cfg.command {
        Some(_) => match crate::build::batch_outputs(&inputs, Path::new("DIR")) {
            Ok(named) => named
                .iter()
                .map(|o| dir.join(o.file_name().expect("a file name")))
                .collect(),
            Err(e) => return Ok(Err(format!("not measured as one command: {e}"))),
        },
        None => (0..inputs.len())
            .map(|i| dir.join(format!("{i}.svpk")))
            .collect(),
    };
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    let build = BuildConfig::default();
    let mut wall: Vec<Vec<f64>> = vec![Vec::new(); cfg.threads.len()];
    let mut identical = vec![true; cfg.threads.len()];
    let mut memory: Vec<Vec<Option<u64>>> = vec![Vec::new(); cfg.threads.len()];
    for r in 0..cfg.rounds {
        for t in round_order(&cfg.threads, r) {
            let i = cfg.threads.iter().position(|&c| c == t).expect("a count");
            for o in &outputs {
                remove_if_present(o)?;
            }
            let start = Instant::now();
            let used = if let Some(exe) = &cfg.command {
                let mut args: Vec<&std::ffi::OsStr> =
                    inputs.iter().map(|l| l.as_os_str()).collect();
                args.extend(["-o".as_ref(), dir.as_os_str()]);
                let json = run_build_command(exe, &args, t, &dir)?;
                // An array of {input, output, ok, summary}; each summary's
                // peak is the process's so far.
                json.as_array().and_then(|items| {
                    items.iter().try_fold(0, |most, item| {
                        let peak = item["summary"]["peak_memory_bytes"].as_u64()?;
                        Some(peak.max(most))
                    })
                })
            } else {
                let (results, added) =
                    with_memory_added(|| build_batch(&inputs, &outputs, &build, t));
                for res in results {
                    res?;
                }
                added
            };
            wall[i].push(start.elapsed().as_secs_f64() * 1e3);
            memory[i].push(used);
            for (o, (_, reference)) in outputs.iter().zip(built) {
                if file_sha256(o)? != *reference {
                    identical[i] = false;
                }
            }
        }
    }
    for o in &outputs {
        remove_if_present(o)?;
    }
    let base = Spread::of(&wall[0]);
    let runs: Vec<BatchRun> = cfg
        .threads
        .iter()
        .zip(wall.iter().zip(identical).zip(&memory))
        .map(|(&threads, ((w, identical), memory))| {
            let wall_ms = Spread::of(w);
            BatchRun {
                threads,
                wall_ms,
                speedup: wall_ms.speedup_from(base),
                identical,
                memory_bytes: largest(memory),
            }
        })
        .collect();
    for run in &runs {
        progress(&count_line(
            &format!("batch of {}", inputs.len()),
            run.threads,
            "",
            run.wall_ms,
            run.speedup,
            run.identical,
        ));
    }
    Ok(Ok(BatchResult {
        inputs: built.iter().map(|(p, _)| file_name(p)).collect(),
        runs,
    }))
}

/// A progress line: "LABEL: N threads: WHAT fastest / median ms (speed-ups)",
/// and the alarm when an output differed.
fn count_line(
    label: &str,
    threads: usize,
    what: &str,
    ms: Spread,
    speedup: Spread,
    identical: bool,
) -> String {
    format!(
        "{label}: {threads} thread{}: {what}{:.1} / {:.1} ms ({:.2}× / {:.2}×){}",
        if threads == 1 { "" } else { "s" },
        ms.fastest,
        ms.median,
        speedup.fastest,
        speedup.median,
        if identical { "" } else { ", OUTPUT DIFFERS" }
    )
}

/// Bytes as MiB with one decimal, or a dash when not measured.
fn mib(bytes: Option<u64>) -> String {
    bytes.map_or("–".to_string(), |b| {
        format!("{:.1}", b as f64 / 1048576.0)
    })
}

/// "identical", or what a reader must not miss.
fn output_word(identical: bool) -> &'static str {
    if identical {
        "identical"
    } else {
        "**DIFFERS**"
    }
}

/// The report as markdown: one table per input, then the batch's.
pub fn to_markdown(r: &ParallelReport) -> String {
    let mut o = String::new();
    let base = r.config.threads[0];
    let memory = if r.config.command.is_some() {
        "peak memory"
    } else {
        "memory added"
    };
    let _ = writeln!(
        o,
        "Builds with each thread count as `svpack build --threads N` runs them (at least {} rounds, more for short builds, the counts taking turns; {} core{} here). Times are fastest / median ms; \"after parsing\" is weld + topology + layout + write; speed-ups are against {base} thread{}, efficiency is the fastest speed-up per thread{}. {} \"output\" says whether every build wrote the bytes of the first one-thread build.\n",
        r.config.rounds,
        r.cores,
        if r.cores == 1 { "" } else { "s" },
        if base == 1 { "" } else { "s" },
        if base == 1 {
            ""
        } else {
            " over the first count's"
        },
        if r.config.command.is_some() {
            "Every build ran as a command of its own (`svpack build --timings --json`), as a pipeline runs one command per model; \"peak memory\" is the largest peak of the count's commands."
        } else {
            "Every build ran in this one process; \"memory added\" is the most its resident size rose during one of the count's builds, above its size before it."
        },
    );
    for i in &r.inputs {
        let _ = writeln!(
            o,
            "**{}** ({} triangles, a {:.2} MB output; {} rounds)\n",
            i.input,
            i.triangles,
            i.file_bytes as f64 / 1e6,
            i.rounds
        );
        let _ = writeln!(
            o,
            "| threads | whole build | after parsing | weld | topology | layout + write | speed-up after parsing | speed-up whole | efficiency | {memory}, MiB | output |"
        );
        let _ = writeln!(o, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|");
        for run in &i.runs {
            let s = |x: Spread| format!("{:.1} / {:.1}", x.fastest, x.median);
            let x = |x: Spread| format!("{:.2}× / {:.2}×", x.fastest, x.median);
            let _ = writeln!(
                o,
                "| {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {} | {} |",
                run.threads,
                s(run.whole_ms),
                s(run.after_parsing_ms),
                s(run.weld_ms),
                s(run.topology_ms),
                s(run.layout_write_ms),
                x(run.speedup),
                x(run.whole_speedup),
                run.speedup.fastest * base as f64 / run.threads as f64,
                mib(run.memory_bytes),
                output_word(run.identical),
            );
        }
        o.push('\n');
    }
    if let Some(b) = &r.batch {
        let _ = writeln!(
            o,
            "**The {} inputs as one batch** (`svpack build {} -o DIR --threads N`): wall time, fastest / median ms\n",
            b.inputs.len(),
            b.inputs.join(" ")
        );
        let _ = writeln!(
            o,
            "| threads | batch | speed-up | efficiency | {memory}, MiB | outputs |"
        );
        let _ = writeln!(o, "|---:|---:|---:|---:|---:|---|");
        for run in &b.runs {
            let _ = writeln!(
                o,
                "| {} | {:.1} / {:.1} | {:.2}× / {:.2}× | {:.2} | {} | {} |",
                run.threads,
                run.wall_ms.fastest,
                run.wall_ms.median,
                run.speedup.fastest,
                run.speedup.median,
                run.speedup.fastest * base as f64 / run.threads as f64,
                mib(run.memory_bytes),
                output_word(run.identical),
            );
        }
        o.push('\n');
    }
    if let Some(note) = &r.batch_note {
        let _ = writeln!(o, "The batch: {note}.\n");
    }
    for (name, e) in &r.failed {
        let _ = writeln!(o, "- {name}: not measured ({e})");
    }
    o
}

/// The report as an SVG chart: the fastest speed-up after parsing against
/// the thread count, one line per input (and the batch's, of its whole
/// wall time), beside the ideal (speed-up = threads / the first count).
pub fn to_svg(r: &ParallelReport) -> std::result::Result<String, String> {
    use plotters::prelude::*;
    let base = r.config.threads[0] as f64;
    let max_t = *r.config.threads.last().expect("a count") as f64;
    let mut lines: Vec<(String, Vec<(f64, f64)>)> = r
        .inputs
        .iter()
        .map(|i| {
            let pts = i
                .runs
                .iter()
                .map(|x| (x.threads as f64, x.speedup.fastest))
                .collect();
            (i.input.clone(), pts)
        })
        .collect();
    if let Some(b) = &r.batch {
        let pts = b
            .runs
            .iter()
            .map(|x| (x.threads as f64, x.speedup.fastest))
            .collect();
        lines.push((format!("batch of {} (whole builds)", b.inputs.len()), pts));
    }
    let ymax = lines
        .iter()
        .flat_map(|(_, p)| p.iter().map(|&(_, y)| y))
        .filter(|y| y.is_finite())
        .fold(max_t / base, f64::max)
        * 1.35;
    crate::report::svg_chart((760, 480), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption("svpack: build speed-up with threads", ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d((base - 0.25)..(max_t + 0.25), 0.0..ymax)?;
        chart
            .configure_mesh()
            .x_desc(format!("threads ({} cores here)", r.cores))
            .x_label_formatter(&|x| {
                if x.fract() == 0.0 {
                    format!("{x:.0}")
                } else {
                    String::new()
                }
            })
            .y_desc(format!(
                "speed-up after parsing over {base} thread{}, fastest",
                if base == 1.0 { "" } else { "s" }
            ))
            .draw()?;
        let ideal = BLACK.mix(0.35);
        chart
            .draw_series(LineSeries::new(
                [(base, 1.0), (max_t, max_t / base)],
                ideal.stroke_width(1),
            ))?
            .label("ideal")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], ideal));
        for (n, (name, pts)) in lines.iter().enumerate() {
            let color = Palette99::pick(n).to_rgba();
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))?
                .label(name.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color));
            chart.draw_series(
                pts.iter()
                    .map(|&(x, y)| Circle::new((x, y), 3, color.filled())),
            )?;
        }
        crate::report::chart_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    })
}

/// Writes `parallel.md`, `parallel.json` and `parallel.svg` into `out`
/// (each atomically). Returns the three paths.
pub fn write_outputs(r: &ParallelReport, out: &Path) -> Result<[PathBuf; 3]> {
    crate::report::write_bench_files(out, "parallel", r, &to_markdown(r), to_svg(r))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Powers of two below the core count, then the count. Caught: the
    /// core count left out when it is no power of two, and listed twice
    /// when it is.
    #[test]
    fn default_counts_double_up_to_the_cores() {
        assert_eq!(default_thread_counts(0), [1]);
        assert_eq!(default_thread_counts(1), [1]);
        assert_eq!(default_thread_counts(2), [1, 2]);
        assert_eq!(default_thread_counts(6), [1, 2, 4, 6]);
        assert_eq!(default_thread_counts(8), [1, 2, 4, 8]);
    }

    /// The median of an even count is the mean of the middle two, and a
    /// speed-up divides the base by the time, fastest by fastest and
    /// median by median. Caught: the upper middle taken as the median;
    /// the ratio upside down.
    #[test]
    fn spreads_and_speedups() {
        let s = Spread::of(&[5.0, 1.0, 4.0, 2.0]);
        assert_eq!((s.fastest, s.median), (1.0, 3.0));
        let s = Spread::of(&[5.0, 1.0, 4.0]);
        assert_eq!((s.fastest, s.median), (1.0, 4.0));
        let base = Spread {
            fastest: 60.0,
            median: 80.0,
        };
        let two = Spread {
            fastest: 40.0,
            median: 32.0,
        };
        assert_eq!(
            two.speedup_from(base),
            Spread {
                fastest: 1.5,
                median: 2.5
            }
        );
    }

    /// Counts are sorted and deduplicated, 0 and an empty list refused,
    /// and the rounds alternate the order.
    #[test]
    fn counts_are_checked_and_take_turns() {
        let c = checked(&ParallelConfig {
            threads: vec![4, 1, 2, 4],
            rounds: 0,
            command: None,
        })
        .unwrap();
        assert_eq!((c.threads.as_slice(), c.rounds), (&[1, 2, 4][..], 1));
        for bad in [vec![], vec![1, 0]] {
            let cfg = ParallelConfig {
                threads: bad,
                rounds: 3,
                command: None,
            };
            assert!(checked(&cfg).is_err());
        }
        assert_eq!(round_order(&[1, 2, 4], 0), [1, 2, 4]);
        assert_eq!(round_order(&[1, 2, 4], 1), [4, 2, 1]);
    }

    /// Short builds get rounds until they fill about a second, within
    /// the least asked for and the cap. Caught: the cap applied to what
    /// was asked for (`--reps 150` gave 100).
    #[test]
    fn short_builds_get_more_rounds() {
        let ms = std::time::Duration::from_millis;
        assert_eq!(rounds_for(ms(2000), 10), 10);
        assert_eq!(rounds_for(ms(80), 10), 13);
        assert_eq!(rounds_for(ms(4), 10), MAX_ROUNDS);
        assert_eq!(rounds_for(std::time::Duration::ZERO, 3), MAX_ROUNDS);
        assert_eq!(rounds_for(ms(4), 150), 150);
        assert_eq!(rounds_for(ms(80), 2), 13);
    }

    /// `differing` names every input and batch count whose outputs were
    /// not all the reference's, and nothing else; the markdown gives a
    /// dash for memory not measured.
    #[test]
    fn differing_names_each_count_that_wrote_other_bytes() {
        let run = |threads, identical| ThreadRun {
            threads,
            whole_ms: Spread::default(),
            after_parsing_ms: Spread::default(),
            weld_ms: Spread::default(),
            topology_ms: Spread::default(),
            layout_write_ms: Spread::default(),
            speedup: Spread::default(),
            whole_speedup: Spread::default(),
            identical,
            memory_bytes: None,
        };
        let input = |name: &str, runs| InputResult {
            input: name.into(),
            triangles: 0,
            file_bytes: 0,
            output_sha256: String::new(),
            rounds: 1,
            runs,
        };
        let batch_run = |threads, identical| BatchRun {
            threads,
            wall_ms: Spread::default(),
            speedup: Spread::default(),
            identical,
            memory_bytes: Some(3 << 20),
        };
        let mut r = ParallelReport {
            config: ParallelConfig::default(),
            cores: 2,
            inputs: vec![
                input("a", vec![run(1, true), run(2, true)]),
                input("b", vec![run(1, true), run(2, false)]),
            ],
            batch: Some(BatchResult {
                inputs: vec!["a".into(), "b".into()],
                runs: vec![batch_run(1, true), batch_run(2, true)],
            }),
            batch_note: None,
            failed: Vec::new(),
            seconds: 0.0,
        };
        assert_eq!(r.differing(), [("b".to_string(), 2)]);
        r.batch.as_mut().unwrap().runs[0].identical = false;
        r.inputs[1].runs[1].identical = true;
        assert_eq!(r.differing(), [("batch".to_string(), 1)]);
        // Memory not measured is a dash; measured, MiB.
        let md = to_markdown(&r);
        assert!(md.contains("| 0.00 | – | identical |"), "{md}");
        assert!(md.contains("| 3.0 | **DIFFERS** |"), "{md}");
    }
}
