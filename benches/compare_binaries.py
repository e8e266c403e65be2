#!/usr/bin/env python3
"""Alternates two svpack binaries on one input and compares their builds.

Usage: python3 benches/compare_binaries.py OLD_BINARY NEW_BINARY INPUT [ROUNDS]

Each round runs `build INPUT -o FRESH --timings --threads T --json` with
T = 1 and 2, the two binaries back to back in alternating order (this
machine drifts from minute to minute, so only interleaved runs are
compared), with `sync` before each run and the output removed first. Prints,
per binary and thread count, the fastest and median time after parsing
(weld + topology + layout + write), of layout + write, and the largest peak
memory; checks that both binaries wrote the same bytes in every run.
"""
import json
import os
import subprocess
import sys
import tempfile


def build(binary, inp, out, threads):
    if os.path.exists(out):
        os.remove(out)
    subprocess.run(["sync"], check=True)
    run = subprocess.run(
        [binary, "build", inp, "-o", out, "--timings", "--threads", str(threads), "--json", "-q"],
        capture_output=True, text=True, check=True)
    d = json.loads(run.stdout)
    t = d["timings_ms"]
    return (t["total"] - t["load"], t["layout"] + t["write"], d["peak_memory_bytes"] / 2**20)


def main():
    if len(sys.argv) not in (4, 5):
        sys.exit(__doc__)
    old, new, inp = sys.argv[1:4]
    rounds = int(sys.argv[4]) if len(sys.argv) == 5 else 6
    bins = {"old": old, "new": new}
    res = {}
    with tempfile.TemporaryDirectory(dir=os.path.dirname(os.path.abspath(inp))) as work:
        for r in range(rounds):
            for t in (1, 2):
                outs = {}
                for name in (["old", "new"] if r % 2 == 0 else ["new", "old"]):
                    outs[name] = os.path.join(work, name + ".svpk")
                    res.setdefault((name, t), []).append(build(bins[name], inp, outs[name], t))
                with open(outs["old"], "rb") as a, open(outs["new"], "rb") as b:
                    if a.read() != b.read():
                        sys.exit(f"round {r}, {t} threads: the binaries wrote different files")
    print("| binary | threads | after parsing, fastest / median (ms) | layout + write, fastest / median (ms) | peak memory (MiB) |")
    print("|---|---:|---:|---:|---:|")
    for (name, t), v in sorted(res.items(), key=lambda kv: (kv[0][1], kv[0][0] != "old")):
        after = sorted(x[0] for x in v)
        lw = sorted(x[1] for x in v)
        print(f"| {name} | {t} | {after[0]:.1f} / {after[len(after) // 2]:.1f} "
              f"| {lw[0]:.1f} / {lw[len(lw) // 2]:.1f} | {max(x[2] for x in v):.1f} |")


if __name__ == "__main__":
    main()
