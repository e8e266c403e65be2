#!/usr/bin/env python3
"""Measures every target of the performance issue in one run and prints
them as one Markdown table: target, what this run measured, and whether
it is met.

Usage: python3 benches/targets.py [--rounds N] [--scene TRIANGLES | --no-scene]
                                  [--no-criterion] [--binary PATH]

What it runs (the README's "Performance" section explains each target):

- builds: `svpack build INPUT -o FRESH --timings --json -q --threads T`
  with T = 1 and 2, alternated (this machine drifts from minute to
  minute, so only interleaved runs are compared), `sync` before each, on
  the full Stanford dragon as binary glTF and as OBJ
  (`benches/fetch_dragon.sh` is run when `target/dragon/dragon.glb` is
  absent) and on a generated scene (`examples/scene.rs`, 5M triangles by
  default, kept in `target/targets/` between runs). Every output of one
  input must be the same bytes, whatever the thread count and round: the
  script exits with status 1 otherwise. Reported: the time after parsing
  (weld + topology + layout + write), fastest and median, in ms and ns
  per input triangle; the two-thread speed-up of the fastest and of the
  medians, after parsing and of the whole build (`total`: an OBJ is
  parsed in two parts at once with two threads); peak memory
  against the input's positions and indices (12 bytes per declared vertex
  and per triangle) plus the output file. After each round's one-thread
  build, as many bytes as its output are written into a new file the way
  the build writes them, with nothing computed (`copy_alone`): the part
  of "after parsing" that is this host's page cache, in the same rounds;
  beside it, each build's own time in those copies (`write_calls` of
  `--timings`) and its time after parsing less them;
- criterion, one thread (`RAYON_NUM_THREADS=1`), on the dragon:
  `weld+topology+layout/ours_buckets` against meshoptimizer's
  `weld+topology+layout/meshopt_adjacency` in the same group
  (`benches/stages.rs`; `ours_buckets_kept`, with freed memory kept
  between iterations, beside them: the target counts as met only on the
  fresh-memory figure), and the evaluator
  `evaluate/dragon_full/caps+sides/reference_shared` per side record,
  with `…_4_lights` (four lights at once, per light) beside it; met with
  one light, or "with lights four at once" when only the second is under
  2 ns (`benches/evaluate.rs`); medians of criterion's samples;
- `benches/load_overhead.rs` on the dragon as OBJ and as binary glTF:
  our loaders against tobj and the gltf crate, the median of the
  per-round overheads with 1 and with 2 threads.

After the targets, a second table gives each input's stages (fastest /
median, ms) with 1 and 2 threads, their write calls, and the output's
copy alone, and
(unless `--no-criterion`) `stage_probe -- floor`'s lines: the first
target's runs with fresh and with recycled memory, and the fresh pages
of their output alone. Time
growing linearly with the triangle count is `bash benches/scaling.sh`'s
table, not measured here.

`--no-criterion` skips the last two (they compile the benches: minutes on
a fresh checkout). The binary is `target/release/svpack`, built first,
unless `--binary` names another.
"""
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DRAGON = os.path.join(ROOT, "target", "dragon", "dragon.glb")
DRAGON_OBJ = os.path.join(ROOT, "target", "dragon", "dragon.obj")


def run(cmd, env=None, **kw):
    """Runs `cmd` from the repository root; its output is returned."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    return subprocess.run(cmd, cwd=ROOT, env=full_env, check=True, **kw)


def digest(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def build(binary, inp, out, threads):
    """One timed build into a fresh `out`: its JSON summary."""
    if os.path.exists(out):
        os.remove(out)
    run(["sync"])
    r = run([binary, "build", inp, "-o", out, "--timings", "--threads", str(threads),
             "--json", "-q"], capture_output=True, text=True)
    return json.loads(r.stdout)


def after_parsing(summary):
    t = summary["timings_ms"]
    return t["weld"] + t["topology"] + t["layout"] + t["write"]


COPY_BLOCK = 2 << 20


def copy_alone(path, size):
    """The floor of a build's writes: `size` bytes put into a new file at
    `path` as the build's writer puts its output (the previous file of that
    name removed first, `sync`, the blocks reserved, then positioned writes
    of 2 MiB from one buffer already in cache; `format::write_file_streamed`),
    with nothing computed. Returns the time in ms from the reservation to
    the last write. Why: every build copies its whole output into the page
    cache (the caps in its topology stage, the sides in its write stage),
    and how fast this host hands the page cache fresh memory changes from
    minute to minute (`examples/first_touch.rs`); timed in the same rounds
    as the builds, the copy alone tells how much of "after parsing" no code
    of svpack's can take away. It meets cold memory as a build does, so
    its fastest is the floor: a run of two rounds timed the dragon's copy
    at 233 ms, where runs of ten took 22–24 ms at the fastest."""
    if os.path.exists(path):
        os.remove(path)
    run(["sync"])
    block = memoryview(bytes(range(256)) * (COPY_BLOCK // 256))
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        start = time.perf_counter()
        os.posix_fallocate(fd, 0, size)
        at = 0
        while at < size:
            n = min(COPY_BLOCK, size - at)
            at += os.pwrite(fd, block[:n], at)
        return (time.perf_counter() - start) * 1e3
    finally:
        os.close(fd)


def measure_builds(binary, inp, rounds):
    """Alternated 1- and 2-thread builds of `inp`: per thread count, the
    times after parsing and the peak memories, and the input's size terms;
    after each round's one-thread build, its output's copy alone
    (`copy_alone`)."""
    times = {1: [], 2: []}
    totals = {1: [], 2: []}
    stages = {1: [], 2: []}
    peaks = {1: [], 2: []}
    copies = []
    first = None
    with tempfile.TemporaryDirectory(dir=os.path.dirname(os.path.abspath(inp))) as work:
        out = os.path.join(work, "out.svpk")
        copy = os.path.join(work, "copy.bin")
        for r in range(rounds):
            for t in ((1, 2) if r % 2 == 0 else (2, 1)):
                s = build(binary, inp, out, t)
                if t == 1:
                    copies.append(copy_alone(copy, s["file_bytes"]))
                times[t].append(after_parsing(s))
                ms = s["timings_ms"]
                totals[t].append(ms["total"])
                stages[t].append((ms["weld"], ms["topology"], ms["layout"] + ms["write"],
                                  ms["write_calls"]))
                peaks[t].append(s["peak_memory_bytes"])
                d = digest(out)
                if first is None:
                    first = (d, t, s)
                elif d != first[0]:
                    sys.exit(f"{inp}: the {t}-thread output of round {r + 1} differs from the "
                             f"{first[1]}-thread output of round 1 (same input, same options)")
    s = first[2]
    sizes = {
        "triangles": s["input_triangles"],
        "inputs": 12 * s["input_vertices"] + 12 * s["input_triangles"],
        "output": s["file_bytes"],
        "edge_instances": s["edge_instances"],
    }
    return times, peaks, sizes, stages, copies, totals


def criterion_median(group_dir, bench_dir):
    """Median time (ns) of one criterion benchmark's last run."""
    path = os.path.join(ROOT, "target", "criterion", group_dir, bench_dir, "new", "estimates.json")
    with open(path) as f:
        return json.load(f)["median"]["point_estimate"]


def measure_criterion():
    one = {"RAYON_NUM_THREADS": "1", "SVPACK_BENCH_ONLY": "dragon_full"}
    common = ["--warm-up-time", "1", "--measurement-time", "3"]
    run(["cargo", "bench", "--bench", "stages", "--"] + common +
        [r"^weld\+topology\+layout/(ours_buckets|ours_buckets_kept|meshopt_adjacency)/dragon_full$"],
        env=one, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ours = criterion_median("weld+topology+layout", "ours_buckets_dragon_full")
    kept = criterion_median("weld+topology+layout", "ours_buckets_kept_dragon_full")
    peer = criterion_median("weld+topology+layout", "meshopt_adjacency_dragon_full")
    run(["cargo", "bench", "--bench", "evaluate", "--"] + common +
        [r"^evaluate/dragon_full/caps\+sides/reference_shared(_4_lights)?$"],
        env=one, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    evaluate = (criterion_median("evaluate_dragon_full", "caps+sides_reference_shared"),
                criterion_median("evaluate_dragon_full", "caps+sides_reference_shared_4_lights") / 4)
    r = run(["cargo", "bench", "--bench", "load_overhead"],
            env={"SVPACK_BENCH_ONLY": "dragon_full,dragon_full_glb", "SVPACK_BENCH_SCENE": "10000",
                 "SVPACK_BENCH_ROUNDS": "7"},
            capture_output=True, text=True)
    overhead = {}
    for line in r.stdout.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 10 and cells[0].startswith("dragon_full"):
            # "fastest, median of rounds" with 1 and with 2 threads.
            overhead[cells[0]] = tuple(float(c.split(",")[1].strip().rstrip("%"))
                                       for c in (cells[6], cells[7]))
    return ours, kept, peer, evaluate, overhead


def row(target, measured, met):
    print(f"| {target} | {measured} | {met} |")


def met_at(fastest, median):
    """The "met?" cell of a target measured at the fastest and at the median
    of the rounds: either can meet it without the other (a slow phase of the
    machine can take the fastest two-thread round's ratio under the median's)."""
    if fastest and median:
        return "yes"
    if fastest:
        return "at the fastest"
    return "at the median" if median else "no"


def main():
    args = sys.argv[1:]
    def option(name, default):
        if name in args:
            i = args.index(name)
            value = args[i + 1]
            del args[i:i + 2]
            return value
        return default
    rounds = int(option("--rounds", "10"))
    scene_triangles = int(option("--scene", "5000000"))
    binary = option("--binary", None)
    no_scene = "--no-scene" in args
    no_criterion = "--no-criterion" in args
    args = [a for a in args if a not in ("--no-scene", "--no-criterion")]
    if args:
        sys.exit(__doc__)
    if binary is None:
        run(["cargo", "build", "--release", "--quiet", "--bin", "svpack"])
        binary = os.path.join(ROOT, "target", "release", "svpack")
    if not os.path.exists(DRAGON):
        run(["bash", "benches/fetch_dragon.sh"])
    inputs = [("Stanford dragon (glTF)", DRAGON), ("Stanford dragon (OBJ)", DRAGON_OBJ)]
    if not no_scene:
        scene = os.path.join(ROOT, "target", "targets", f"scene_{scene_triangles}.obj")
        if not os.path.exists(scene):
            os.makedirs(os.path.dirname(scene), exist_ok=True)
            run(["cargo", "run", "--release", "--quiet", "--example", "scene", "--",
                 str(scene_triangles), scene + ".tmp"], stdout=subprocess.DEVNULL)
            os.replace(scene + ".tmp", scene)
        inputs.append((f"{scene_triangles / 1e6:g}M scene", scene))

    results = []
    for name, path in inputs:
        print(f"building {name}: {rounds} rounds of 1 and 2 threads", file=sys.stderr)
        results.append((name,) + measure_builds(binary, path, rounds))

    print("| target | measured | met? |")
    print("|---|---|---|")
    if not no_criterion:
        print("criterion benches (one thread) and load_overhead", file=sys.stderr)
        ours, kept, peer, evaluate, overhead = measure_criterion()
        ratio = ours / peer
        # Met on the fresh-memory figure; the kept one is shown beside it.
        row("weld + topology + buckets ≤ 1/10 of meshopt's adjacency, one thread (dragon)",
            f"{ours / 1e6:.1f} ms against {peer / 1e6:.1f} ms: **{ratio:.3f}**; with freed "
            f"memory kept between runs, as meshoptimizer's malloc keeps most of its own: "
            f"{kept / 1e6:.1f} ms, {kept / peer:.3f}",
            "yes" if ratio <= 0.1 else ("with memory kept" if kept / peer <= 0.1 else "no"))
    for name, times, _, sizes, stages, copies, _ in results:
        n = sizes["triangles"]
        fast, med = min(times[1]), statistics.median(times[1])
        cfast, cmed = min(copies), statistics.median(copies)
        # Each build's time less its own copy into the file (`write_calls`).
        own = [t - s[3] for t, s in zip(times[1], stages[1])]
        ofast, omed = min(own), statistics.median(own)
        row(f"after parsing ≤ 80 ns per triangle, one thread ({name})",
            f"fastest {fast:.1f} ms = **{fast * 1e6 / n:.0f} ns**, median {med:.1f} ms = "
            f"{med * 1e6 / n:.0f} ns; less each build's own copy into the file "
            f"(`write_calls`): fastest {ofast:.1f} ms = {ofast * 1e6 / n:.0f} ns, median "
            f"{omed:.1f} ms = {omed * 1e6 / n:.0f} ns; the copy alone in the same rounds "
            f"({sizes['output'] / 2**20:.1f} MiB, `copy_alone`): fastest {cfast:.1f} ms = "
            f"{cfast * 1e6 / n:.0f} ns, median {cmed:.1f} ms = {cmed * 1e6 / n:.0f} ns",
            met_at(fast * 1e6 / n <= 80, med * 1e6 / n <= 80))
    for name, times, _, _, _, _, totals in results:
        for what, v in (("after parsing", times), ("whole build", totals)):
            fast = min(v[1]) / min(v[2])
            med = statistics.median(v[1]) / statistics.median(v[2])
            row(f"2 threads ≥ 1.6× one, byte-identical ({name}, {what})",
                f"{min(v[1]):.1f} → {min(v[2]):.1f} ms: **{fast:.2f}×** at the fastest; "
                f"{statistics.median(v[1]):.1f} → {statistics.median(v[2]):.1f} ms: {med:.2f}× "
                f"at the median; every output identical",
                met_at(fast >= 1.6, med >= 1.6))
    for name, _, peaks, sizes, _, _, _ in results:
        base = sizes["inputs"] + sizes["output"]
        row(f"peak memory ≤ 2.5 × (input positions and indices + output) ({name})",
            f"{max(peaks[1]) / 2**20:.1f} / {max(peaks[2]) / 2**20:.1f} MiB with 1 / 2 threads = "
            f"**{max(peaks[1]) / base:.2f} / {max(peaks[2]) / base:.2f} ×** "
            f"({sizes['inputs'] / 2**20:.1f} + {sizes['output'] / 2**20:.1f} MiB)",
            "yes" if max(max(peaks[1]), max(peaks[2])) <= 2.5 * base else "no")
    if not no_criterion:
        dragon_instances = results[0][3]["edge_instances"]
        ev1, ev4 = evaluate
        per, per4 = ev1 / dragon_instances, ev4 / dragon_instances
        row("CPU evaluator ≤ 2 ns per edge instance per core (dragon)",
            f"one light: {ev1 / 1e6:.2f} ms for {dragon_instances:,} side records and the caps, "
            f"**{per:.2f} ns**; four lights at once: {ev4 / 1e6:.2f} ms per light, **{per4:.2f} ns**",
            "yes" if per <= 2 else ("with lights four at once" if per4 <= 2 else "no"))
        for name, (one, two) in sorted(overhead.items()):
            label = "glTF" if name.endswith("_glb") else "OBJ"
            row(f"loading overhead ≤ 10% of the parser's time (dragon, {label})",
                f"median of rounds {one:+.1f}% with 1 thread, **{two:+.1f}%** with 2",
                "yes" if two <= 10 else "no")
    print()
    print("| input | threads | after parsing | weld | topology | layout + write "
          "| its write calls (all threads) | the output's copy alone |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, times, _, _, stages, copies, _ in results:
        for t in (1, 2):
            cells = [f"{min(v):.1f} / {statistics.median(v):.1f}"
                     for v in [times[t]] + [[s[i] for s in stages[t]] for i in range(4)]]
            # One copy per round, after the one-thread build.
            cells.append(f"{min(copies):.1f} / {statistics.median(copies):.1f}" if t == 1 else "")
            print(f"| {name} | {t} | " + " | ".join(cells) + " |")
    if not no_criterion:
        # What fresh memory costs the first target at least: the same runs
        # with memory recycled, plus the fresh pages of their output alone
        # (`examples/stage_probe.rs`, `floor`).
        print("the fresh-memory floor (stage_probe floor)", file=sys.stderr)
        run(["cargo", "build", "--release", "--quiet", "--example", "stage_probe"])
        r = run([os.path.join(ROOT, "target", "release", "examples", "stage_probe"), "floor",
                 DRAGON], capture_output=True, text=True)
        print()
        print("The fresh-memory floor under the first target (`cargo run --release --example "
              "stage_probe -- floor target/dragon/dragon.glb`, one thread):")
        print()
        print("```text")
        print(r.stdout.rstrip())
        print("```")

if __name__ == "__main__":
    main()
