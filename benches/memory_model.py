#!/usr/bin/env python3
"""Each input's estimated peak memory against the peak its build reaches.

Usage: python3 benches/memory_model.py [--binary B] [--threads T,...]
       [--reps N] [--compress] INPUT...

For each input and thread count, runs `svpack build INPUT -o TMP
--timings --json --quiet --threads T` N times (default 3) and prints the
estimate the summary gives (`memory_estimate_bytes`, what a batch under
`build --max-memory` counts the input as), the largest peak of the runs
(`peak_memory_bytes`), the peak less the process's own (the peak of a
build of fixtures/cube.obj, about 6 MiB), and the estimate over that. An
estimate below the peak it stands for (a ratio under 1) is flagged, and
the exit status is then 1.

Why: a batch under a budget trusts the estimate read from the file to be
above what each build adds (`build::memory_estimate`; benches/ROUNDS.md,
Fifty-first round); this is the check on real models, which the tests
make on the shared models in CI (tests/memory_budget.rs).
"""
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from rebuild import option  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MIB = 1 << 20


def summary(binary, src, out, threads, extra):
    p = subprocess.run([binary, "build", src, "-o", out, "--timings", "--json", "--quiet",
                        "--threads", str(threads), *extra], capture_output=True, text=True)
    if p.returncode != 0:
        return None
    return json.loads(p.stdout)


def main():
    args = sys.argv[1:]
    binary = option(args, "--binary", os.path.join(ROOT, "target", "release", "svpack"))
    counts = [int(t) for t in option(args, "--threads", "1,2").split(",")]
    reps = int(option(args, "--reps", "3"))
    extra = []
    if "--compress" in args:
        args.remove("--compress")
        extra.append("--compress")
    if not args:
        sys.exit(__doc__)
    ok = True
    with tempfile.TemporaryDirectory(prefix="svpack-memory-") as work:
        out = os.path.join(work, "out.svpk")
        base = max(summary(binary, os.path.join(ROOT, "fixtures", "cube.obj"), out, 1, [])
                   ["peak_memory_bytes"] for _ in range(reps))
        print(f"process alone (fixtures/cube.obj): {base / MIB:.1f} MiB"
              f"{'; compressed builds' if extra else ''}")
        print("| input | threads | estimate, MiB | peak, MiB | added, MiB | estimate / added |")
        print("|---|---:|---:|---:|---:|---:|")
        for src in args:
            for t in counts:
                runs = [summary(binary, src, out, t, extra) for _ in range(reps)]
                if any(r is None for r in runs):
                    print(f"| {os.path.basename(src)} | {t} | refused | | | |")
                    break
                estimate = runs[0]["memory_estimate_bytes"]
                peak = max(r["peak_memory_bytes"] for r in runs)
                added = max(peak - base, 0)
                # A build that adds less than 1 MiB has no useful ratio.
                ratio = f"{estimate / added:.2f}" if added >= MIB else "-"
                flag = "" if estimate >= added else " **below**"
                ok = ok and estimate >= added
                print(f"| {os.path.basename(src)} | {t} | {estimate / MIB:.1f} | {peak / MIB:.1f} "
                      f"| {added / MIB:.1f} | {ratio}{flag} |")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
