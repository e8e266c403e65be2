#!/usr/bin/env python3
"""Rebuilding in place against building fresh, for two svpack binaries.

Usage: python3 benches/rebuild.py [--jobs J] OLD NEW INPUT [COPIES] [ROUNDS]

Builds COPIES copies of INPUT (default 6) as one batch into an output
directory, ROUNDS times (default 8) per binary, the binaries alternating
and swapping order every round. Each round times, by wall clock around the
whole command:
  fresh  the batch into an empty directory (`sync` first);
  over   the same batch again over those outputs once they are written
         back (`sync` between), as a pipeline that rebuilds its assets
         finds them.
Prints the fastest and the median of each, and of the fresh batches the
median number of page faults (the process's minor faults, `wait4`: one
per huge page or small page faulted in, so fresh memory shows here) and
the largest peak memory; checks that both binaries' outputs are the same
bytes and that no temp file is left beside them (exit status 1
otherwise). With --jobs J the batches run with `--jobs J --threads J`
(otherwise the defaults: one per core).

Why: on a filesystem mounted with `discard` (this machine's ext4) removing
a written-back output waits for the device to discard its blocks (27 ms
for the dragon's 120 MiB, `cargo run --release --example stage_probe --
replace DIR`), and a build that replaces an output removes
the old one (benches/ROUNDS.md, Twentieth round); and a batch keeps the
large blocks one build frees for the next (`alloc::KeepFreed`), which a
single build cannot show (Twenty-seventh round).
"""
import filecmp
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time


def option(args, name, default):
    """Removes `name VALUE` from args and returns VALUE (or default)."""
    if name not in args:
        return default
    i = args.index(name)
    value = args[i + 1]
    del args[i:i + 2]
    return value


def spread(times):
    """"FASTEST / MEDIAN" of a list of ms, rounded to whole ms."""
    return f"{min(times):.0f} / {statistics.median(times):.0f}"


def run(binary, inputs, out, jobs, args=()):
    """Wall ms, minor faults and peak memory (MiB) of one command, with
    `args` added to it."""
    extra = ["--jobs", jobs, "--threads", jobs] if jobs else []
    start = time.perf_counter()
    p = subprocess.Popen([binary, "build", *inputs, "-o", out, "--quiet", *extra, *args],
                         stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(p.pid, 0)
    wall = (time.perf_counter() - start) * 1e3
    if status != 0:
        sys.exit(f"{binary} failed (status {status})")
    return wall, usage.ru_minflt, usage.ru_maxrss / 1024


def main():
    args = sys.argv[1:]
    jobs = option(args, "--jobs", None)
    if len(args) < 3:
        sys.exit(__doc__)
    old, new, src = args[:3]
    copies = int(args[3]) if len(args) > 3 else 6
    rounds = int(args[4]) if len(args) > 4 else 8
    work = tempfile.mkdtemp(prefix="svpack-rebuild-", dir=".")
    ok = True
    try:
        ext = os.path.splitext(src)[1]
        inputs = []
        for i in range(copies):
            path = os.path.join(work, f"in{i}{ext}")
            shutil.copyfile(src, path)
            inputs.append(path)
        times = {b: {"fresh": [], "over": []} for b in ("old", "new")}
        faults = {b: [] for b in ("old", "new")}
        peak = {b: 0.0 for b in ("old", "new")}
        # One input builds into a file, several into a directory.
        outs = {b: os.path.join(work, f"out-{b}" + ("" if copies > 1 else ".svpk"))
                for b in ("old", "new")}
        for r in range(rounds):
            order = [("old", old), ("new", new)]
            if r % 2:
                order.reverse()
            for name, binary in order:
                shutil.rmtree(outs[name], ignore_errors=True)
                if os.path.isfile(outs[name]):
                    os.remove(outs[name])
                subprocess.run(["sync"], check=True)
                wall, minflt, rss = run(binary, inputs, outs[name], jobs)
                times[name]["fresh"].append(wall)
                faults[name].append(minflt)
                peak[name] = max(peak[name], rss)
                subprocess.run(["sync"], check=True)
                times[name]["over"].append(run(binary, inputs, outs[name], jobs)[0])
                beside = outs[name] if copies > 1 else work
                left = [f for f in os.listdir(beside) if f.startswith(".svpack-")]
                if left:
                    print(f"{name}: temp files left: {left}")
                    ok = False
        pairs = ([(os.path.join(outs["old"], f), os.path.join(outs["new"], f))
                  for f in sorted(os.listdir(outs["old"]))]
                 if copies > 1 else [(outs["old"], outs["new"])])
        for a, b in pairs:
            if not filecmp.cmp(a, b, shallow=False):
                print(f"outputs differ: {a} {b}")
                ok = False
        print(f"{copies} copies of {src}, {rounds} rounds, wall ms, fastest / median")
        print("| binary | fresh | over the written-back outputs "
              "| page faults (fresh, median) | peak memory (MiB) |")
        print("|---|---:|---:|---:|---:|")
        for name in ("old", "new"):
            t = times[name]
            print(f"| {name} | {spread(t['fresh'])} | {spread(t['over'])} "
                  f"| {statistics.median(faults[name]):.0f} | {peak[name]:.1f} |")
    finally:
        shutil.rmtree(work, ignore_errors=True)
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
