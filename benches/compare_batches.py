#!/usr/bin/env python3
"""Two svpack binaries building the same inputs as one batch, alternated.

Usage: python3 benches/compare_batches.py [--jobs J] [--rounds R]
       [--new-args "ARGS"] OLD NEW INPUT...

Each round runs `build INPUT... -o DIR --quiet` with each binary into an
empty directory (`sync` first), the binaries swapping order every round
(default 8 rounds; with --jobs J, `--jobs J --threads J`, otherwise one
job per core). The inputs are linked into a scratch directory under
distinct names first, so that inputs of one stem (a model as .obj and as
.glb) can share a batch. Prints, per binary, the fastest and the median
wall time of the command, the median number of page faults and the
largest peak memory; checks that both binaries wrote the same bytes for
every input (exit status 1 otherwise). With --new-args, NEW's command
gets ARGS (split at spaces) too: OLD and NEW may then be one binary, to
compare an option against its absence (`--new-args "--max-memory 400M"`,
benches/ROUNDS.md, Fifty-first round).

Why: `build_batch` decides the order in which a batch's inputs start and
which thread builds which; that shows in the batch's wall time alone, as
the time of its largest build plus what waits for it (benches/ROUNDS.md,
Fiftieth round). `svpack bench --parallel` times one binary's batches;
this compares two.
"""
import filecmp
import os
import shutil
import statistics
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rebuild import option, run, spread  # noqa: E402


def main():
    args = sys.argv[1:]
    jobs = option(args, "--jobs", None)
    rounds = int(option(args, "--rounds", "8"))
    new_args = option(args, "--new-args", "").split()
    if len(args) < 3:
        sys.exit(__doc__)
    binaries = {"old": args[0], "new": args[1]}
    sources = args[2:]
    work = tempfile.mkdtemp(prefix="svpack-batches-", dir=".")
    ok = True
    try:
        inputs = []
        for i, src in enumerate(sources):
            path = os.path.join(work, f"in{i}_{os.path.basename(src)}")
            os.symlink(os.path.abspath(src), path)
            inputs.append(path)
        times = {b: [] for b in binaries}
        faults = {b: [] for b in binaries}
        peak = {b: 0.0 for b in binaries}
        outs = {b: os.path.join(work, f"out-{b}") for b in binaries}
        for r in range(rounds):
            order = list(binaries)
            if r % 2:
                order.reverse()
            for name in order:
                shutil.rmtree(outs[name], ignore_errors=True)
                subprocess.run(["sync"], check=True)
                extra = new_args if name == "new" else []
                wall, minflt, rss = run(binaries[name], inputs, outs[name], jobs, extra)
                times[name].append(wall)
                faults[name].append(minflt)
                peak[name] = max(peak[name], rss)
        for f in sorted(os.listdir(outs["old"])):
            a, b = os.path.join(outs["old"], f), os.path.join(outs["new"], f)
            if not os.path.exists(b) or not filecmp.cmp(a, b, shallow=False):
                print(f"outputs differ: {a} {b}")
                ok = False
        print(f"{len(sources)} inputs as one batch, {rounds} rounds, "
              f"{'--jobs ' + jobs if jobs else 'one job per core'}"
              f"{'; new with ' + ' '.join(new_args) if new_args else ''}")
        print("| binary | wall ms, fastest / median | page faults (median) | peak memory (MiB) |")
        print("|---|---:|---:|---:|")
        for name in binaries:
            print(f"| {name} | {spread(times[name])} "
                  f"| {statistics.median(faults[name]):.0f} | {peak[name]:.1f} |")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
