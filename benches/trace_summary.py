#!/usr/bin/env python3
"""Sums up a build's timeline (`svpack build --trace FILE`).

    python3 benches/trace_summary.py FILE [--stage NAME] [--json]
    python3 benches/trace_summary.py FILE FILE... [--stage NAME]

Prints:
- the stages (load, weld, topology, layout, write) with their start and
  length;
- per thread, the time in each kind of interval, counted once: an
  interval's time inside a nested one of the same thread goes to the
  nested one (the weld's steps inside `weld`, a copier's fills inside the
  emit pass that waits for them), and the thread's idle time between the
  first stage's start and the last stage's end (with `--stage`, within
  that stage alone: the first interval of that name);
- the copies into the page cache (`file write`): how many, their total, how
  long two overlapped (the kernel serialises writes into one file, so
  about none), and how long no thread wrote between the first write and
  the last one.

Given several traces (builds of one input), it prints instead, for each
stage and each kind of interval (summed over the threads), the fastest
and the median over the builds.

Why: a two-thread build's time is a chain of passes and copies shared
between two threads, and these sums say which one the chain waits for
(README, "Why the unmet targets are not met").
"""
import argparse
import json
import sys
from collections import defaultdict

STAGES = ("load", "weld", "topology", "layout", "write")


def intervals(path):
    """The trace's complete events as (thread, name, start, end) in ms, and
    the threads' names."""
    with open(path) as f:
        events = json.load(f)["traceEvents"]
    names = {}
    spans = []
    for e in events:
        if e.get("ph") == "M" and e.get("name") == "thread_name":
            names[e["tid"]] = e["args"]["name"]
        elif e.get("ph") == "X":
            # Whole nanoseconds, so that steps timed back to back (one's
            # end the next one's start) meet exactly despite rounding.
            start = round(e["ts"] * 1e3)
            end = round((e["ts"] + e["dur"]) * 1e3)
            spans.append((e["tid"], e["name"], start / 1e6, end / 1e6))
    return spans, names


def exclusive(spans):
    """Per thread and name, the time of its intervals not inside a nested
    interval of the same thread (the stages count as containers only)."""
    out = defaultdict(lambda: defaultdict(float))
    by_thread = defaultdict(list)
    for tid, name, s, e in spans:
        by_thread[tid].append((s, -(e - s), name, e))
    for tid, items in by_thread.items():
        items.sort()
        # Walk in start order with a stack of open intervals; each moment
        # goes to the innermost open interval.
        stack = []  # [name, end] of the open intervals, innermost last
        t = None

        def advance(to):
            if stack and t is not None and to > t:
                out[tid][stack[-1][0]] += to - t

        for s, _neg, name, e in items:
            while stack and stack[-1][1] <= s:
                advance(stack[-1][1])
                t = stack[-1][1]
                stack.pop()
            advance(s)
            t = s
            stack.append([name, e])
        while stack:
            advance(stack[-1][1])
            t = stack[-1][1]
            stack.pop()
    return out


def union_length(ranges):
    total, end = 0.0, None
    for s, e in sorted(ranges):
        if end is None or s > end:
            total += e - s
            end = e
        elif e > end:
            total += e - end
            end = e
    return total


def summary(path, stage=None):
    spans, names = intervals(path)
    stages = [(n, s, e) for _t, n, s, e in spans if n in STAGES]
    if not stages:
        sys.exit(f"{path}: no build stages in the trace")
    first = min(s for _n, s, _e in stages)
    last = max(e for _n, _s, e in stages)
    everything = (first, last)
    if stage is not None:
        window = [(s, e) for n, s, e in stages if n == stage]
        if not window:
            sys.exit(f"{path}: no stage named {stage!r}")
        first, last = min(window)
        # Each interval clipped to the stage.
        spans = [(t, n, max(s, first), min(e, last)) for t, n, s, e in spans
                 if e > first and s < last]
    excl = exclusive(spans)
    # Every moment of a thread's intervals goes to exactly one of them.
    for tid, kinds in excl.items():
        covered = union_length([(s, e) for t, _n, s, e in spans if t == tid])
        assert abs(sum(kinds.values()) - covered) < 1e-6, (path, tid, dict(kinds), covered)
    threads = {}
    for tid in sorted(excl):
        kinds = {n: v for n, v in excl[tid].items() if n not in STAGES and v > 0}
        busy = union_length(
            [(max(s, first), min(e, last)) for t, n, s, e in spans
             if t == tid and n not in STAGES and e > first and s < last]
        )
        threads[names.get(tid, str(tid))] = {
            "busy_ms": busy,
            "idle_ms": (last - first) - busy,
            "by_kind_ms": dict(sorted(kinds.items(), key=lambda kv: -kv[1])),
        }
    writes = sorted((s, e, t) for t, n, s, e in spans if n == "file write")
    overlap = 0.0
    for i, (s, e, t) in enumerate(writes):
        for s2, e2, t2 in writes[i + 1:]:
            if s2 >= e:
                break
            if t2 != t:
                overlap += min(e, e2) - s2
    total = sum(e - s for s, e, _t in writes)
    # (The last write to end, not the last to start.)
    last_write = max((e for _s, e, _t in writes), default=None)
    gaps = (last_write - writes[0][0]) - union_length([(s, e) for s, e, _ in writes]) if writes else 0.0
    return {
        "build_ms": everything[1] - everything[0],
        "window": stage or "build",
        "window_ms": last - first,
        "stages": [{"name": n, "start_ms": s - everything[0], "ms": e - s} for n, s, e in sorted(stages, key=lambda x: x[1])],
        "threads": threads,
        "writes": {
            "count": len(writes),
            "total_ms": total,
            "overlapping_ms": overlap,
            "first_ms": writes[0][0] - everything[0] if writes else None,
            "last_end_ms": last_write - everything[0] if writes else None,
            "none_writing_between_ms": gaps,
        },
    }


def across(paths, stage):
    """Per stage and per kind (summed over threads): fastest and median
    over the builds."""
    stages, kinds = defaultdict(list), defaultdict(list)
    for path in paths:
        s = summary(path, stage)
        for st in s["stages"]:
            stages[st["name"]].append(st["ms"])
        total = defaultdict(float)
        for t in s["threads"].values():
            for k, v in t["by_kind_ms"].items():
                total[k] += v
        for k, v in total.items():
            kinds[k].append(v)
    def stat(v):
        v = sorted(v)
        return f"{v[0]:8.2f} / {v[len(v) // 2]:8.2f}"
    print(f"{len(paths)} builds; fastest / median, ms")
    for name in STAGES:
        if name in stages:
            print(f"stage {name:<22} {stat(stages[name])}")
    print(f"within: {stage or 'build'} (each kind summed over the threads; a build without it counts 0)")
    for k in sorted(kinds, key=lambda k: -sorted(kinds[k])[len(kinds[k]) // 2]):
        v = kinds[k] + [0.0] * (len(paths) - len(kinds[k]))
        print(f"  {k:<28} {stat(v)}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("trace", nargs="+")
    ap.add_argument("--stage", help="sum up within this stage only (topology, write, ...)")
    ap.add_argument("--json", action="store_true", help="print the sums as JSON")
    args = ap.parse_args()
    if len(args.trace) > 1:
        across(args.trace, args.stage)
        return
    s = summary(args.trace[0], args.stage)
    if args.json:
        print(json.dumps(s, indent=2))
        return
    print(f"build (first stage to last): {s['build_ms']:.2f} ms")
    for st in s["stages"]:
        print(f"  {st['name']:<10} from {st['start_ms']:8.2f} ms  {st['ms']:8.2f} ms")
    print(f"sums within: {s['window']}, {s['window_ms']:.2f} ms")
    for name, t in s["threads"].items():
        print(f"thread {name}: busy {t['busy_ms']:.2f} ms, idle {t['idle_ms']:.2f} ms")
        for kind, ms in t["by_kind_ms"].items():
            print(f"  {kind:<22} {ms:8.2f} ms")
    w = s["writes"]
    if w["count"]:
        print(
            f"writes: {w['count']}, {w['total_ms']:.2f} ms in all, "
            f"{w['overlapping_ms']:.2f} ms of it overlapping; "
            f"from {w['first_ms']:.2f} to {w['last_end_ms']:.2f} ms, "
            f"{w['none_writing_between_ms']:.2f} ms of that with no thread writing"
        )


if __name__ == "__main__":
    main()
