#!/usr/bin/env python3
"""Counts the fresh pages one svpack command makes the kernel hand out.

Usage: python3 benches/fresh_pages.py [--by-stage] BINARY ARGS...

Runs `BINARY ARGS...` under `perf record -e kmem:mm_page_alloc` (which
follows that process and its threads only) and sums the pages allocated to
it, in MiB, by kind:
  huge     transparent huge pages (anonymous memory of svpack's allocator);
  anon4k   zeroed 4 KiB pages (anonymous memory from malloc, parsers);
  cache    page-cache pages for writes (the output file);
  other    everything else (page tables, the input file read into the cache).

Why: on this virtual machine a fresh page can cost ten times a reused one
(the host faults it in too; `examples/first_touch.rs`), and timings drift
from minute to minute, while these counts are the same from run to run. With
--by-stage (build the binary with `RUSTFLAGS="-C force-frame-pointers=yes"`)
each page is charged to the first svpack stage module on its call stack
(load, weld, topology, layout, format, verify) or to tobj.

Needs `perf` with access to kernel tracepoints (root, or a low
kernel.perf_event_paranoid). Prints only; asserts nothing.
"""
import collections
import os
import re
import subprocess
import sys
import tempfile

STAGES = ["topology", "weld", "layout", "format", "load::", "verify", "tobj", "build::"]


def kind(flags):
    if "TRANSHUGE" in flags:
        return "huge"
    if "__GFP_ZERO" in flags and "HIGHUSER" in flags:
        return "anon4k"
    if "__GFP_WRITE" in flags:
        return "cache"
    return "other"


def main():
    args = sys.argv[1:]
    by_stage = bool(args) and args[0] == "--by-stage"
    if by_stage:
        args = args[1:]
    if not args:
        sys.exit(__doc__)
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "perf.data")
        record = ["perf", "record", "-q", "-o", data, "-e", "kmem:mm_page_alloc"]
        if by_stage:
            record.append("-g")
        subprocess.run(record + ["--"] + args, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        fields = "trace,ip,sym" if by_stage else "trace"
        script = subprocess.run(["perf", "script", "-i", data, "-F", fields],
                                capture_output=True, text=True, check=True).stdout
    sums = collections.Counter()
    current = None  # (kind, bytes, stage) of the event being read

    def close():
        if current is not None:
            k, size, stage = current
            sums[(k, stage)] += size

    for line in script.splitlines():
        m = re.search(r"order=(\d+).*gfp_flags=(\S+)", line)
        if m:
            close()
            current = [kind(m.group(2)), 4096 << int(m.group(1)), "?"]
            continue
        if by_stage and current is not None and current[2] == "?":
            for s in STAGES:
                if s in line:
                    current[2] = s.rstrip(":")
                    break
    close()
    total = collections.Counter()
    for (k, _), size in sums.items():
        total[k] += size
    print(" ".join(f"{k} {total[k] / 2**20:.1f} MiB" for k in ["huge", "anon4k", "cache", "other"]))
    if by_stage:
        for (k, stage), size in sorted(sums.items(), key=lambda x: -x[1]):
            if size >= 2**19:
                print(f"  {k:7} {stage:9} {size / 2**20:7.1f} MiB")


if __name__ == "__main__":
    main()
