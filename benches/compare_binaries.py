#!/usr/bin/env python3
"""Alternates two svpack binaries on one input and compares their builds.

Usage: python3 benches/compare_binaries.py [--allow-different] [--replace] [--rest SECONDS] [--threads T[,T...]] [--by-slot] OLD_BINARY NEW_BINARY INPUT [ROUNDS]

Each round runs `build INPUT -o FRESH --timings --threads T --json` with
T = 1 and 2 (or the counts --threads lists), the two binaries back to back in alternating order (this
machine drifts from minute to minute, so only interleaved runs are
compared), with `sync` before each run and the output removed first (with
--replace it is kept: each build replaces that binary's output of the
previous run, as rebuilding in place does; an untimed build makes the first
one). With --rest S each run waits S seconds after its `sync`: on a
virtual machine whose host takes freed guest memory back (free page
reporting, about two seconds after memory is freed), back-to-back runs get
the memory the run before freed, still backed, and rested runs get cold
memory, as a build started on its own does (`alloc::cold_memory_seen`).
Prints,
per binary and thread count, the fastest and median whole build, load (the
parse and what the loader adds), time after parsing
(weld + topology + layout + write), weld, topology, layout + write, and the
largest peak memory; checks that both binaries wrote the same bytes in every run (with
--allow-different, for versions whose headers are known to differ, it only
says how many runs differed).

With --by-slot the rows are split by the build's place in its pair: first
(right after the last pair's outputs were removed) or second (right after
the first build of the pair). Why: on a virtual machine whose host takes
freed memory back, the first build's output can take the page cache the
removed outputs freed, still backed, and the second's cannot; on the 5M
scene the second slot's write stage took five times the first's
(benches/ROUNDS.md, "Forty-sixth round"), so a median over both slots
mixes two populations.
"""
import filecmp
import json
import os
import subprocess
import sys
import tempfile
import time


def build(binary, inp, out, threads, replace=False, rest=0.0):
    if os.path.exists(out) and not replace:
        os.remove(out)
    subprocess.run(["sync"], check=True)
    time.sleep(rest)
    run = subprocess.run(
        [binary, "build", inp, "-o", out, "--timings", "--threads", str(threads), "--json", "-q"],
        capture_output=True, text=True, check=True)
    d = json.loads(run.stdout)
    t = d["timings_ms"]
    return (t["total"] - t["load"], t["layout"] + t["write"], d["peak_memory_bytes"] / 2**20,
            t["total"], t["weld"], t["topology"], t["load"])


def main():
    args = sys.argv[1:]
    allow_different = "--allow-different" in args
    replace = "--replace" in args
    rest = 0.0
    if "--rest" in args:
        i = args.index("--rest")
        rest = float(args[i + 1])
        del args[i:i + 2]
    threads = (1, 2)
    if "--threads" in args:
        i = args.index("--threads")
        threads = tuple(int(t) for t in args[i + 1].split(","))
        del args[i:i + 2]
    by_slot = "--by-slot" in args
    args = [a for a in args if a not in ("--allow-different", "--replace", "--by-slot")]
    if len(args) not in (3, 4):
        sys.exit(__doc__)
    old, new, inp = args[:3]
    rounds = int(args[3]) if len(args) == 4 else 6
    different = 0
    bins = {"old": old, "new": new}
    res = {}
    with tempfile.TemporaryDirectory(dir=os.path.dirname(os.path.abspath(inp))) as work:
        if replace:
            for name in bins:
                build(bins[name], inp, os.path.join(work, name + ".svpk"), 2)
        for r in range(rounds):
            for t in threads:
                outs = {}
                for slot, name in enumerate(["old", "new"] if r % 2 == 0 else ["new", "old"]):
                    outs[name] = os.path.join(work, name + ".svpk")
                    key = (name, t, ("first", "second")[slot] if by_slot else "")
                    res.setdefault(key, []).append(
                        build(bins[name], inp, outs[name], t, replace, rest))
                # Compared in small chunks: reading both outputs whole took
                # 250 MB of memory between runs, whose freeing changed what
                # memory the next build found (cold or not, see --rest).
                if not filecmp.cmp(outs["old"], outs["new"], shallow=False):
                    if not allow_different:
                        sys.exit(f"round {r}, {t} threads: the binaries wrote different files")
                    different += 1
                # Both removed once compared (unless rebuilding in place):
                # kept until each binary's next build, the 5M scene's 720
                # MB outputs made every write stage of the NEW slot slow
                # (981 against 235 ms at the fastest in one run;
                # benches/ROUNDS.md, Nineteenth and Twenty-second rounds).
                if not replace:
                    for o in outs.values():
                        os.remove(o)
    if allow_different:
        print(f"{different} of {len(threads) * rounds} pairs of outputs differed")
    slot_head = " slot |" if by_slot else ""
    print(f"| binary | threads |{slot_head} whole build, fastest / median (ms) "
          "| load | after parsing, fastest / median (ms) | weld | topology | layout + write "
          "| peak memory (MiB) |")
    print("|---|---:|" + ("---|" if by_slot else "") + "---:|---:|---:|---:|---:|---:|---:|")
    for (name, t, slot), v in sorted(res.items(),
                                     key=lambda kv: (kv[0][1], kv[0][2], kv[0][0] != "old")):
        def col(i):
            x = sorted(run[i] for run in v)
            return f"{x[0]:.1f} / {x[len(x) // 2]:.1f}"
        slot_cell = f" {slot} |" if by_slot else ""
        print(f"| {name} | {t} |{slot_cell} {col(3)} | {col(6)} | {col(0)} | {col(4)} | {col(5)} "
              f"| {col(1)} "
              f"| {max(x[2] for x in v):.1f} |")


if __name__ == "__main__":
    main()
