#!/usr/bin/env python3
"""Alternates two svpack binaries on a batch: one input built COPIES times
in one command, as a pipeline builds many assets.

Usage: python3 benches/compare_batch.py [--jobs J[,J...]] OLD_BINARY NEW_BINARY INPUT [COPIES] [ROUNDS]

Each round runs `build COPY_1 ... COPY_N -o DIR --jobs J --threads J -q`
(the copies are symbolic links to INPUT with names of their own, so each
writes DIR/<name>.svpk) with J = 1 and 2 (or the counts --jobs lists),
the two binaries back to back in alternating order, with `sync` before each
run and the outputs removed first. Prints, per binary and job count, the
fastest and median wall time, the median number of page faults (minor
faults of the process, `wait4`: one per huge page or small page faulted
in, so fresh memory shows here) and the largest peak memory; checks that
both binaries wrote the same bytes in every run. Why a batch: a build
keeps the large blocks it frees for the next input's build
(`alloc::KeepFreed`), which a single build cannot show.
"""
import filecmp
import os
import statistics
import subprocess
import sys
import tempfile
import time


def build(binary, copies, out, jobs):
    """Wall time (s), minor faults and peak memory (MiB) of one batch."""
    subprocess.run(["sync"], check=True)
    t = time.perf_counter()
    p = subprocess.Popen([binary, "build", *copies, "-o", out, "--jobs", str(jobs),
                          "--threads", str(jobs), "-q"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    if status != 0:
        sys.exit(f"{binary} failed on the batch (status {status})")
    return wall, usage.ru_minflt, usage.ru_maxrss / 1024


def main():
    args = sys.argv[1:]
    jobs = (1, 2)
    if "--jobs" in args:
        i = args.index("--jobs")
        jobs = tuple(int(j) for j in args[i + 1].split(","))
        del args[i:i + 2]
    if len(args) not in (3, 4, 5):
        sys.exit(__doc__)
    old, new, inp = args[:3]
    count = int(args[3]) if len(args) > 3 else 6
    rounds = int(args[4]) if len(args) > 4 else 8
    bins = {"old": old, "new": new}
    res = {}
    ext = os.path.splitext(inp)[1]
    with tempfile.TemporaryDirectory(dir=os.path.dirname(os.path.abspath(inp))) as work:
        copies = []
        for c in range(count):
            link = os.path.join(work, f"copy{c}{ext}")
            os.symlink(os.path.abspath(inp), link)
            copies.append(link)
        for r in range(rounds):
            for j in jobs:
                outs = {}
                for name in (["old", "new"] if r % 2 == 0 else ["new", "old"]):
                    outs[name] = os.path.join(work, "out-" + name)
                    res.setdefault((name, j), []).append(build(bins[name], copies, outs[name], j))
                for c in range(count):
                    a, b = (os.path.join(outs[n], f"copy{c}.svpk") for n in ("old", "new"))
                    if not filecmp.cmp(a, b, shallow=False):
                        sys.exit(f"round {r}, {j} jobs, copy {c}: the binaries wrote different files")
                for o in outs.values():
                    for c in range(count):
                        os.remove(os.path.join(o, f"copy{c}.svpk"))
    print(f"| binary | jobs | {count} builds, fastest / median (s) | page faults, median | peak memory (MiB) |")
    print("|---|---:|---:|---:|---:|")
    for (name, j), v in sorted(res.items(), key=lambda kv: (kv[0][1], kv[0][0] != "old")):
        walls = sorted(x[0] for x in v)
        print(f"| {name} | {j} | {walls[0]:.3f} / {walls[len(walls) // 2]:.3f} "
              f"| {statistics.median(x[1] for x in v):.0f} | {max(x[2] for x in v):.1f} |")


if __name__ == "__main__":
    main()
