//! `svpack bench --accuracy`: speed against error for the multiplicity
//! strategies, and size against error for the position encodings.
//!
//! Strategies (see [`Strategy`]): (a) Kim 2008, (b) Pečiva 2013, (c) the
//! reference edge in f32 (the format), (d) the reference edge in f64, (e)
//! exact predicates. For every input (the hard-case suite of
//! [`crate::hardcases`] and any model files) and many lights, each strategy's
//! volume is checked the way `svpack verify` checks a file: closedness,
//! triangles whose sides and caps disagree, and sample points against the exact
//! shadow truth. Speed is the single-core time of the evaluator over every
//! side record and every cap, all strategies timed in the same run.
//!
//! Encodings: each input is also built with unorm16 positions; the report
//! gives bytes, the largest vertex displacement relative to the bounds
//! diagonal, how many sample points change exact shadow state, and what
//! `verify` finds on the quantised file.
//!
//! Everything is seeded, so the counts are reproducible; times are not.

use crate::build::{BuildConfig, build_file};
use crate::error::{Error, Result};
use crate::evaluate::{Strategy, cap_signs_with, side_multiplicities_with};
use crate::evaluate_indexed::LIGHT_GROUP;
use crate::format::{Encoding, SvpkFile};
use crate::multiplicity::{Light, lex_less};
use crate::quantize::{self, RecordSpace};
use crate::shadow::{ShadowIndex, check_shadow, choose_samples, occluders};
use crate::verify::{
    Decoded, Evaluation, VerifyLight, check_closedness, choose_lights, decode, evaluate_into,
    evaluate_many_into,
};
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Options of an accuracy run.
#[derive(Debug, Clone, Serialize)]
pub struct AccuracyConfig {
    /// Generated lights per input (added to a hard case's own lights).
    pub lights: usize,
    /// Sample points per input for the shadow-truth check.
    pub samples: usize,
    /// Seed for lights and samples.
    pub seed: u64,
    /// Lights used for timing each model.
    pub timing_lights: usize,
    /// Timing repetitions (the fastest counts).
    pub timing_reps: usize,
    /// Include the built-in hard-case suite.
    pub hard_cases: bool,
}

impl Default for AccuracyConfig {
    fn default() -> Self {
        AccuracyConfig {
            lights: 16,
            samples: 64,
            seed: 1,
            timing_lights: 4,
            timing_reps: 3,
            hard_cases: true,
        }
    }
}

/// Errors of one strategy on one input, summed over lights.
#[derive(Debug, Clone, Default, Serialize)]
pub struct StrategyErrors {
    /// Strategy name.
    pub strategy: &'static str,
    /// Lights evaluated.
    pub lights: u64,
    /// Unbalanced edges of the emitted volumes.
    pub closedness_violations: u64,
    /// Triangles whose three side contributions and cap sign do not all agree.
    pub disagreeing_triangles: u64,
    /// Samples compared with the exact truth.
    pub samples: u64,
    /// Samples whose volume winding differs from the exact occluder count.
    pub sample_mismatches: u64,
    /// Lights with any violation, disagreement or mismatch.
    pub lights_with_errors: u64,
}

/// One encoding of one input.
#[derive(Debug, Clone, Serialize)]
pub struct EncodingResult {
    /// "f32" or "unorm16".
    pub encoding: &'static str,
    /// Bytes on disk.
    pub file_bytes: u64,
    /// Largest vertex displacement over the bounds diagonal (0 for f32).
    pub max_displacement: f64,
    /// Sample points (over all lights off every triangle plane) whose exact
    /// shadow state differs from the f32 geometry's.
    pub shadow_changes: u64,
    /// Sample points compared for that.
    pub shadow_compared: u64,
    /// Like `shadow_changes`, under every light (including lights on the surface).
    pub shadow_changes_all_lights: u64,
    /// Sample points compared for that.
    pub shadow_compared_all_lights: u64,
    /// `verify` on this file: closedness violations.
    pub closedness_violations: u64,
    /// `verify` on this file: sample mismatches against its own exact truth.
    pub sample_mismatches: u64,
    /// `verify` passed.
    pub verify_ok: bool,
}

/// Results for one input.
#[derive(Debug, Clone, Serialize)]
pub struct InputResult {
    /// Input name (file name or hard-case name).
    pub name: String,
    /// "hard-case" or "model".
    pub kind: &'static str,
    /// Triangles (caps records).
    pub triangles: u64,
    /// Side records.
    pub edge_instances: u64,
    /// Per strategy, in the order (a)–(e).
    pub strategies: Vec<StrategyErrors>,
    /// f32 then unorm16.
    pub encodings: Vec<EncodingResult>,
}

/// Per-strategy totals: the report's main table.
#[derive(Debug, Clone, Serialize)]
pub struct StrategySummary {
    /// Strategy name.
    pub strategy: &'static str,
    /// Single-core evaluator time per side record (edge instance), ns.
    pub ns_per_edge_instance: f64,
    /// Single-core evaluator time per cap triangle, ns.
    pub ns_per_cap: f64,
    /// Single-core time of the whole per-light evaluation (caps and sides)
    /// with the shared evaluator `verify` uses — each triangle once, sides as
    /// sums of their triangles' signs — per side record, ns. Only for
    /// consistent strategies (NaN for Kim, whose three edge tests differ).
    pub ns_per_edge_instance_shared: f64,
    /// The same with the lights evaluated four at a time
    /// ([`crate::verify::evaluate_many_into`]), per light and side record,
    /// ns. Only the reference strategy evaluates a group together; the
    /// others run light by light, so their figure repeats the one above.
    pub ns_per_edge_instance_grouped: f64,
    /// Totals over every input and light.
    pub errors: StrategyErrors,
    /// `lights_with_errors / lights`.
    pub fraction_lights_with_errors: f64,
    /// Hard cases with any error.
    pub hard_cases_with_errors: Vec<String>,
    /// Same fraction over the hard-case suite only.
    pub hard_case_fraction: f64,
    /// Same fraction over the model files only.
    pub model_fraction: f64,
}

/// The whole report (`accuracy.json`).
#[derive(Debug, Clone, Serialize)]
pub struct AccuracyReport {
    /// Options used.
    pub config: AccuracyConfig,
    /// Per strategy.
    pub strategies: Vec<StrategySummary>,
    /// Per input.
    pub inputs: Vec<InputResult>,
    /// Inputs that could not be built, with the error.
    pub failed: Vec<(String, String)>,
    /// Wall time of the run, seconds.
    pub seconds: f64,
}

/// Triangles of `d` whose side contributions (one per edge, as the sides
/// shader computes them for edge `A < B`) and cap sign do not all agree.
pub fn disagreeing_triangles(d: &Decoded, light: Light, strategy: Strategy) -> u64 {
    d.caps
        .iter()
        .filter(|t| {
            let p = t.map(|i| d.positions[i as usize]);
            let cap = strategy.cap_sign(p[0], p[1], p[2], light);
            (0..3).any(|e| {
                let (x, y, o) = (p[e], p[(e + 1) % 3], p[(e + 2) % 3]);
                // The record stores the edge as A < B; the triangle runs x → y.
                let s = if lex_less(x, y) {
                    strategy.side_sign(x, y, o, light)
                } else {
                    -strategy.side_sign(y, x, o, light)
                };
                s != cap
            })
        })
        .count() as u64
}

/// A built input: the f32 and unorm16 files, decoded.
struct Prepared {
    name: String,
    f32_file: SvpkFile,
    q_file: SvpkFile,
    d: Decoded,
    dq: Decoded,
    lights: Vec<Light>,
    max_displacement: f64,
}

fn prepare(
    input: &Path,
    name: String,
    explicit: &[Light],
    cfg: &AccuracyConfig,
    dir: &Path,
) -> Result<Prepared> {
    let out = |e: &str| dir.join(format!("{}.{e}.svpk", sanitize(&name)));
    let f32_path = out("f32");
    let q_path = out("unorm16");
    build_file(input, &f32_path, &BuildConfig::default())?;
    build_file(
        input,
        &q_path,
        &BuildConfig {
            positions: Encoding::Unorm16,
            ..BuildConfig::default()
        },
    )?;
    let f32_file = crate::format::read_file(&f32_path)?;
    let q_file = crate::format::read_file(&q_path)?;
    let d = decode(&f32_file, 0);
    let dq = decode(&q_file, 0);
    let mut lights = explicit.to_vec();
    lights.extend(choose_lights(&d, cfg.lights, cfg.seed));
    // Largest displacement, measured on the input positions as the builder quantises them.
    let soup = crate::load::load(input)?;
    let (lo, hi) = quantize::used_bounds(&soup.positions, &soup.indices);
    let space = RecordSpace::unorm16_box(lo, hi);
    let q = quantize::to_record_space(&soup.positions, &space, Encoding::Unorm16);
    let diag = (0..3)
        .map(|k| (hi[k] as f64 - lo[k] as f64).powi(2))
        .sum::<f64>()
        .sqrt()
        .max(f64::MIN_POSITIVE);
    let max_displacement = soup
        .indices
        .iter()
        .map(|&i| {
            let (p, w) = (soup.positions[i as usize], space.to_world(q[i as usize]));
            (0..3)
                .map(|k| (w[k] - p[k] as f64).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max)
        / diag;
    Ok(Prepared {
        name,
        f32_file,
        q_file,
        d,
        dq,
        lights,
        max_displacement,
    })
}

fn sanitize(name: &str) -> String {
    name.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

/// Errors of every strategy on one prepared input.
fn strategy_errors(p: &Prepared, index: &ShadowIndex, samples: &[[f32; 3]]) -> Vec<StrategyErrors> {
    Strategy::ALL
        .iter()
        .map(|&s| {
            let mut e = StrategyErrors {
                strategy: s.name(),
                ..Default::default()
            };
            // Lights in parallel (the closedness check is sequential per
            // light); integer sums, so the totals do not depend on threads.
            let per_light: Vec<(u64, u64, u64, u64)> = p
                .lights
                .par_iter()
                .map_init(Evaluation::default, |ev, &light| {
                    evaluate_into(&p.d, light, s, ev);
                    let c = check_closedness(&p.d, light, ev);
                    let dis = disagreeing_triangles(&p.d, light, s);
                    let sh = check_shadow(&p.d, index, light, ev, samples);
                    (c.violations, dis, sh.samples, sh.mismatches)
                })
                .collect();
            for (v, dis, n, mism) in per_light {
                e.lights += 1;
                e.closedness_violations += v;
                e.disagreeing_triangles += dis;
                e.samples += n;
                e.sample_mismatches += mism;
                e.lights_with_errors += (v + dis + mism > 0) as u64;
            }
            e
        })
        .collect()
}

/// f32 and unorm16 results for one prepared input.
fn encoding_results(
    p: &Prepared,
    index: &ShadowIndex,
    samples: &[[f32; 3]],
    cfg: &AccuracyConfig,
    reference: &StrategyErrors,
) -> Vec<EncodingResult> {
    // Exact shadow state of every (light, sample) on both geometries; the
    // quantised one is asked in its record space.
    let qindex = ShadowIndex::new(&p.dq);
    let flat = zero_area(&p.d);
    // (changed, compared) under all lights and under generic lights only: a
    // light on the surface (on a vertex, an edge line or in a face's plane:
    // the hard placements) ends up on one side of it or the other after any
    // displacement, which flips the shadow of everything behind that face and
    // says little about quantisation in normal use.
    let per_light: Vec<[u64; 4]> = p
        .lights
        .par_iter()
        .map(|&light| {
            let off = off_every_plane(&p.d, &flat, light);
            let lq = p.dq.space.light_to_record(light);
            let mut c = [0u64; 4];
            for &s in samples {
                let a = occluders(index, light, s);
                let b = occluders(&qindex, lq, p.dq.space.point_to_record(s));
                if let (Some(a), Some(b)) = (a, b) {
                    let changed = ((a > 0) != (b > 0)) as u64;
                    c[0] += changed;
                    c[1] += 1;
                    if off {
                        c[2] += changed;
                        c[3] += 1;
                    }
                }
            }
            c
        })
        .collect();
    let sum = |i: usize| per_light.iter().map(|c| c[i]).sum::<u64>();
    let (all, generic) = ((sum(0), sum(1)), (sum(2), sum(3)));
    // The f32 file's verify result is the reference strategy's row (same
    // evaluator, lights and samples); the quantised file is verified under
    // the same world lights plus lights generated in its own record space,
    // where hard placements (on its vertices, in its planes) are exact.
    let mut lights: Vec<VerifyLight> = p.lights.iter().map(|&l| VerifyLight::World(l)).collect();
    lights.extend(
        choose_lights(&p.dq, cfg.lights.div_ceil(2), cfg.seed)
            .into_iter()
            .map(VerifyLight::Record),
    );
    let rep = crate::verify::verify(&p.q_file, &lights, Strategy::Reference, cfg.samples);
    vec![
        EncodingResult {
            encoding: Encoding::F32.name(),
            file_bytes: p.f32_file.file_bytes,
            max_displacement: 0.0,
            shadow_changes: 0,
            shadow_compared: 0,
            shadow_changes_all_lights: 0,
            shadow_compared_all_lights: 0,
            closedness_violations: reference.closedness_violations,
            sample_mismatches: reference.sample_mismatches,
            verify_ok: reference.closedness_violations + reference.sample_mismatches == 0,
        },
        EncodingResult {
            encoding: Encoding::Unorm16.name(),
            file_bytes: p.q_file.file_bytes,
            max_displacement: p.max_displacement,
            shadow_changes: generic.0,
            shadow_compared: generic.1,
            shadow_changes_all_lights: all.0,
            shadow_compared_all_lights: all.1,
            closedness_violations: rep.closedness_violations,
            sample_mismatches: rep.sample_mismatches,
            verify_ok: rep.ok,
        },
    ]
}

/// Whether `light` lies off the plane of every triangle of `d` with area
/// (exactly; `flat` marks the zero-area triangles, which have no plane).
fn off_every_plane(d: &Decoded, flat: &[bool], light: Light) -> bool {
    d.caps.par_iter().zip(flat).all(|(t, &flat)| {
        let p = t.map(|i| d.positions[i as usize]);
        flat || crate::evaluate::exact_sign(p[0], p[1], p[2], light) != 0
    })
}

/// Zero-area (collinear) triangles: every point lies in their "plane", so
/// the four corners of a tetrahedron all give orientation 0.
fn zero_area(d: &Decoded) -> Vec<bool> {
    let probes = [
        [0.0, 0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0, 1.0],
        [0.0, 1.0, 0.0, 1.0],
        [0.0, 0.0, 1.0, 1.0],
    ];
    d.caps
        .iter()
        .map(|t| {
            let p = t.map(|i| d.positions[i as usize]);
            probes
                .iter()
                .all(|&l| crate::evaluate::exact_sign(p[0], p[1], p[2], l) == 0)
        })
        .collect()
}

/// Single-core evaluator time of `strategy` on `d` for `lights`: seconds for
/// all side records, for all caps, for the shared evaluation light by light
/// and for the same in groups of four lights (fastest of `reps` each).
fn time_strategy(
    d: &Decoded,
    lights: &[Light],
    strategy: Strategy,
    reps: usize,
) -> (f64, f64, f64, f64) {
    let mut best = (f64::INFINITY, f64::INFINITY, f64::INFINITY, f64::INFINITY);
    let mut sides: Vec<Vec<i8>> = d.buckets.iter().map(|b| vec![0; b.records()]).collect();
    let mut caps = vec![0i8; d.caps.len()];
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        for &l in lights {
            for (b, m) in d.buckets.iter().zip(&mut sides) {
                side_multiplicities_with(strategy, b.k, &b.data, l, m);
            }
        }
        let ts = t.elapsed().as_secs_f64();
        let t = Instant::now();
        for &l in lights {
            cap_signs_with(strategy, &d.caps_data, l, &mut caps);
        }
        let tc = t.elapsed().as_secs_f64();
        std::hint::black_box((&sides, &caps));
        let t = Instant::now();
        if strategy != Strategy::Kim {
            let mut ev = Evaluation::default();
            for &l in lights {
                evaluate_into(d, l, strategy, &mut ev);
                std::hint::black_box(&ev);
            }
        }
        let tsh = t.elapsed().as_secs_f64();
        let t = Instant::now();
        if strategy != Strategy::Kim {
            let mut evs = vec![Evaluation::default(); LIGHT_GROUP];
            for group in lights.chunks(LIGHT_GROUP) {
                evaluate_many_into(d, group, strategy, &mut evs[..group.len()]);
                std::hint::black_box(&evs);
            }
        }
        let tg = t.elapsed().as_secs_f64();
        best = (
            best.0.min(ts),
            best.1.min(tc),
            best.2.min(tsh),
            best.3.min(tg),
        );
    }
    best
}

/// Runs the accuracy benchmark over the hard-case suite (if enabled) and
/// `inputs`, writing intermediate files under `work_dir`. `progress` is
/// called with a line per finished input.
pub fn run(
    inputs: &[PathBuf],
    cfg: &AccuracyConfig,
    work_dir: &Path,
    progress: &mut dyn FnMut(&str),
) -> Result<AccuracyReport> {
    let start = Instant::now();
    let mut jobs: Vec<(PathBuf, String, &'static str, Vec<Light>)> = Vec::new();
    if cfg.hard_cases {
        for c in crate::hardcases::cases() {
            let path = work_dir.join(format!("{}.obj", c.name));
            std::fs::write(&path, crate::hardcases::obj(&c.v, &c.f))
                .map_err(|e| Error::io(&path, e))?;
            jobs.push((path, c.name.to_string(), "hard-case", c.lights.clone()));
        }
    }
    for i in inputs {
        let name = crate::build::file_name(i);
        jobs.push((i.clone(), name, "model", Vec::new()));
    }
    let single = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| Error::Other(format!("cannot start a thread pool: {e}")))?;
    let mut results = Vec::new();
    let mut failed = Vec::new();
    // Timing totals per strategy: (side seconds, records, cap seconds, caps).
    let mut timing = vec![(0.0f64, 0u64, 0.0f64, 0u64, 0.0f64, 0.0f64); Strategy::ALL.len()];
    for (path, name, kind, explicit) in &jobs {
        let t = Instant::now();
        let p = match prepare(path, name.clone(), explicit, cfg, work_dir) {
            Ok(p) => p,
            Err(e) => {
                progress(&format!("{name}: skipped ({e})"));
                failed.push((name.clone(), e.to_string()));
                continue;
            }
        };
        let index = ShadowIndex::new(&p.d);
        let samples = choose_samples(&p.d, cfg.samples, cfg.seed);
        let strategies = strategy_errors(&p, &index, &samples);
        let reference = strategies
            .iter()
            .find(|e| e.strategy == Strategy::Reference.name())
            .expect("reference is one of the strategies");
        let encodings = encoding_results(&p, &index, &samples, cfg, reference);
        let records: u64 = p.d.buckets.iter().map(|b| b.records() as u64).sum();
        // Hard cases are far too small to time; models are timed, every
        // strategy in the same run, on one thread.
        if *kind == "model" {
            let lights = &p.lights[..cfg.timing_lights.min(p.lights.len())];
            for (tot, &s) in timing.iter_mut().zip(&Strategy::ALL) {
                let (ts, tc, tsh, tg) =
                    single.install(|| time_strategy(&p.d, lights, s, cfg.timing_reps));
                tot.0 += ts;
                tot.4 += tsh;
                tot.5 += tg;
                tot.1 += records * lights.len() as u64;
                tot.2 += tc;
                tot.3 += p.d.caps.len() as u64 * lights.len() as u64;
            }
        }
        progress(&format!(
            "{name}: {} triangles, {} lights, {:.1} s",
            p.d.caps.len(),
            p.lights.len(),
            t.elapsed().as_secs_f64()
        ));
        results.push(InputResult {
            name: p.name.clone(),
            kind,
            triangles: p.d.caps.len() as u64,
            edge_instances: records,
            strategies,
            encodings,
        });
    }
    let strategies = Strategy::ALL
        .iter()
        .enumerate()
        .map(|(i, &s)| {
            let mut total = StrategyErrors {
                strategy: s.name(),
                ..Default::default()
            };
            let (mut hard, mut model) = ((0u64, 0u64), (0u64, 0u64));
            let mut hard_names = Vec::new();
            for r in &results {
                let e = &r.strategies[i];
                total.lights += e.lights;
                total.closedness_violations += e.closedness_violations;
                total.disagreeing_triangles += e.disagreeing_triangles;
                total.samples += e.samples;
                total.sample_mismatches += e.sample_mismatches;
                total.lights_with_errors += e.lights_with_errors;
                let bucket = if r.kind == "hard-case" {
                    if e.lights_with_errors > 0 {
                        hard_names.push(r.name.clone());
                    }
                    &mut hard
                } else {
                    &mut model
                };
                bucket.0 += e.lights_with_errors;
                bucket.1 += e.lights;
            }
            let frac = |(a, b): (u64, u64)| if b == 0 { 0.0 } else { a as f64 / b as f64 };
            let t = timing[i];
            StrategySummary {
                strategy: s.name(),
                ns_per_edge_instance: if t.1 == 0 {
                    f64::NAN
                } else {
                    t.0 * 1e9 / t.1 as f64
                },
                ns_per_cap: if t.3 == 0 {
                    f64::NAN
                } else {
                    t.2 * 1e9 / t.3 as f64
                },
                ns_per_edge_instance_shared: if t.1 == 0 || s == Strategy::Kim {
                    f64::NAN
                } else {
                    t.4 * 1e9 / t.1 as f64
                },
                ns_per_edge_instance_grouped: if t.1 == 0 || s == Strategy::Kim {
                    f64::NAN
                } else {
                    t.5 * 1e9 / t.1 as f64
                },
                fraction_lights_with_errors: frac((total.lights_with_errors, total.lights)),
                errors: total,
                hard_cases_with_errors: hard_names,
                hard_case_fraction: frac(hard),
                model_fraction: frac(model),
            }
        })
        .collect();
    Ok(AccuracyReport {
        config: cfg.clone(),
        strategies,
        inputs: results,
        failed,
        seconds: start.elapsed().as_secs_f64(),
    })
}

fn ns(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.1}")
    } else {
        "–".into()
    }
}

/// The report as markdown (what README shows).
pub fn to_markdown(r: &AccuracyReport) -> String {
    let mut o = String::new();
    let hard = r.inputs.iter().filter(|i| i.kind == "hard-case").count();
    let models = r.inputs.len() - hard;
    let _ = writeln!(
        o,
        "Strategies on {hard} hard cases and {models} models, {} generated lights per input (plus each hard case's own), {} samples per input, seed {}. Times: one core, all strategies in the same run, over the models' side records and caps: per record as the vertex shaders evaluate them, and (\"shared\") the whole per-light evaluation, caps and sides, with each triangle evaluated once and sides summing their triangles' signs, per side record (this needs a consistent strategy), and the same with the lights four at a time (\"4 lights\": the reference strategy evaluates each group in one pass; the others light by light).\n",
        r.config.lights, r.config.samples, r.config.seed
    );
    let _ = writeln!(
        o,
        "| strategy | ns / edge instance | ns / cap | ns / edge instance, shared | shared, 4 lights | closedness violations | disagreeing triangles | sample mismatches | lights with errors | hard cases with errors |"
    );
    let _ = writeln!(o, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|");
    for s in &r.strategies {
        let e = &s.errors;
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {} | {} | {} | {} / {} | {} / {} ({:.1}%) | {} |",
            s.strategy,
            ns(s.ns_per_edge_instance),
            ns(s.ns_per_cap),
            ns(s.ns_per_edge_instance_shared),
            ns(s.ns_per_edge_instance_grouped),
            e.closedness_violations,
            e.disagreeing_triangles,
            e.sample_mismatches,
            e.samples,
            e.lights_with_errors,
            e.lights,
            100.0 * s.fraction_lights_with_errors,
            if s.hard_cases_with_errors.is_empty() {
                "none".to_string()
            } else {
                s.hard_cases_with_errors.join(", ")
            }
        );
    }
    let _ = writeln!(
        o,
        "\nLights with errors per input (closedness violation, sides/caps disagreement or sample mismatch):\n"
    );
    let names: Vec<&str> = r.strategies.iter().map(|s| s.strategy).collect();
    let _ = writeln!(o, "| input | triangles | {} |", names.join(" | "));
    let _ = writeln!(o, "|---|---:|{}", "---:|".repeat(names.len()));
    for i in &r.inputs {
        let cells: Vec<String> = i
            .strategies
            .iter()
            .map(|e| format!("{} / {}", e.lights_with_errors, e.lights))
            .collect();
        let _ = writeln!(
            o,
            "| {} | {} | {} |",
            i.name,
            i.triangles,
            cells.join(" | ")
        );
    }
    let _ = writeln!(
        o,
        "\nEncodings: f32 against 16-bit quantised positions (`--positions unorm16`). Displacement is the largest vertex move over the bounds diagonal; shadow changes count (light, sample) pairs whose exact shadow state differs from the f32 geometry's, under the lights that lie off every triangle's plane, and under all lights (a light placed exactly on the surface ends up on one side of it after any displacement, so everything behind that face flips); verify is `svpack verify` on the quantised file (closedness violations / sample mismatches).\n"
    );
    let _ = writeln!(
        o,
        "| input | f32 bytes | unorm16 bytes | ratio | max displacement | shadow changes, generic lights | shadow changes, all lights | verify unorm16 |"
    );
    let _ = writeln!(o, "|---|---:|---:|---:|---:|---:|---:|---|");
    let (mut fb, mut qb, mut ch, mut cmp, mut viol) = (0u64, 0u64, 0u64, 0u64, 0u64);
    let (mut cha, mut cmpa) = (0u64, 0u64);
    let mut worst = 0.0f64;
    for i in &r.inputs {
        let (f, q) = (&i.encodings[0], &i.encodings[1]);
        fb += f.file_bytes;
        qb += q.file_bytes;
        ch += q.shadow_changes;
        cmp += q.shadow_compared;
        cha += q.shadow_changes_all_lights;
        cmpa += q.shadow_compared_all_lights;
        viol += q.closedness_violations;
        worst = worst.max(q.max_displacement);
        let _ = writeln!(
            o,
            "| {} | {} | {} | {:.3} | {:.2e} | {} / {} ({:.3}%) | {} / {} ({:.2}%) | {} ({} / {}) |",
            i.name,
            f.file_bytes,
            q.file_bytes,
            q.file_bytes as f64 / f.file_bytes as f64,
            q.max_displacement,
            q.shadow_changes,
            q.shadow_compared,
            100.0 * q.shadow_changes as f64 / q.shadow_compared.max(1) as f64,
            q.shadow_changes_all_lights,
            q.shadow_compared_all_lights,
            100.0 * q.shadow_changes_all_lights as f64 / q.shadow_compared_all_lights.max(1) as f64,
            if q.verify_ok { "ok" } else { "FAIL" },
            q.closedness_violations,
            q.sample_mismatches
        );
    }
    let _ = writeln!(
        o,
        "| **all** | {fb} | {qb} | {:.3} | {worst:.2e} | {ch} / {cmp} ({:.3}%) | {cha} / {cmpa} ({:.2}%) | {viol} closedness violations |",
        qb as f64 / fb.max(1) as f64,
        100.0 * ch as f64 / cmp.max(1) as f64,
        100.0 * cha as f64 / cmpa.max(1) as f64
    );
    if !r.failed.is_empty() {
        let _ = writeln!(o, "\nNot built:\n");
        for (n, e) in &r.failed {
            let _ = writeln!(o, "- {n}: {e}");
        }
    }
    o
}

/// Speed against error as an SVG scatter plot: x = ns per edge instance, y =
/// percentage of lights with errors (hard cases and models as two series).
pub fn to_svg(r: &AccuracyReport) -> std::result::Result<String, String> {
    use plotters::prelude::*;
    crate::report::svg_chart((720, 440), |root| {
        let xmax = r
            .strategies
            .iter()
            .map(|s| s.ns_per_edge_instance)
            .filter(|v| v.is_finite())
            .fold(1.0, f64::max)
            * 1.15;
        let ymax = r
            .strategies
            .iter()
            .flat_map(|s| [s.hard_case_fraction, s.model_fraction])
            .fold(0.0, f64::max)
            .max(0.01)
            * 100.0
            * 1.2;
        let mut chart = ChartBuilder::on(root)
            .caption("svpack: evaluator speed against error", ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..xmax, 0.0..ymax)?;
        chart
            .configure_mesh()
            .x_desc("ns per edge instance (one core)")
            .y_desc("% of lights with errors")
            .draw()?;
        // Hard cases as large rings, models as dots, so equal points stay visible.
        let series = [("hard-case suite", RED, true), ("models", BLUE, false)];
        for (label, color, hard) in series {
            let pts: Vec<(f64, f64, &str)> = r
                .strategies
                .iter()
                .filter(|s| s.ns_per_edge_instance.is_finite())
                .map(|s| {
                    let y = if hard {
                        s.hard_case_fraction
                    } else {
                        s.model_fraction
                    };
                    (s.ns_per_edge_instance, 100.0 * y, s.strategy)
                })
                .collect();
            let marker = move |c: (f64, f64)| -> DynElement<'static, SVGBackend, (f64, f64)> {
                if hard {
                    Circle::new(c, 8, color.stroke_width(2)).into_dyn()
                } else {
                    Circle::new(c, 4, color.filled()).into_dyn()
                }
            };
            chart
                .draw_series(pts.iter().map(|&(x, y, _)| marker((x, y))))?
                .label(label)
                .legend(move |(x, y)| {
                    if hard {
                        Circle::new((x, y), 6, color.stroke_width(2)).into_dyn()
                    } else {
                        Circle::new((x, y), 4, color.filled()).into_dyn()
                    }
                });
            // Names once, above the model points (offset in pixels).
            if !hard {
                chart.draw_series(pts.iter().enumerate().map(|(i, &(x, y, name))| {
                    // Alternate heights so neighbouring names do not overlap.
                    let dy = if i % 2 == 0 { -22 } else { -38 };
                    EmptyElement::at((x, y))
                        + Text::new(
                            name.to_string(),
                            (6, dy),
                            ("sans-serif", 13).into_font().color(&BLACK),
                        )
                }))?;
            }
        }
        crate::report::chart_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

/// Writes `accuracy.md`, `accuracy.json` and `accuracy.svg` into `out`
/// (each atomically). Returns the three paths.
pub fn write_outputs(r: &AccuracyReport, out: &Path) -> Result<[PathBuf; 3]> {
    crate::report::write_bench_files(out, "accuracy", r, &to_markdown(r), to_svg(r))
}
