#!/usr/bin/env python3
"""Alternates two svpack binaries running `verify` on one file and compares
their reports.

Usage: python3 benches/compare_verify.py OLD_BINARY NEW_BINARY FILE [ROUNDS] [-- VERIFY_ARGS...]

Each round runs `verify FILE --json VERIFY_ARGS` with both binaries back to
back, in alternating order (this machine drifts from minute to minute, so
only interleaved runs are compared), under `/usr/bin/time` for the wall time
and the peak resident memory. Prints each run, then per binary the fastest
and median time and the largest peak. Exits non-zero when the two reports
differ in anything but their `time_ms` fields (the exit status of `verify`,
2 when a check fails, is compared too).
"""
import json
import subprocess
import sys
import tempfile


def run(binary, path, extra):
    with tempfile.NamedTemporaryFile("r") as t:
        p = subprocess.run(
            ["/usr/bin/time", "-f", "%e %M", "-o", t.name, binary, "verify", path, "--json", "-q"]
            + extra,
            capture_output=True, text=True)
        secs, kib = t.read().strip().splitlines()[-1].split()
    report = json.loads(p.stdout)
    report.pop("time_ms", None)
    for light in report.get("lights", []):
        light.pop("time_ms", None)
    return float(secs), int(kib) / 1024, (p.returncode, report)


def main():
    args = sys.argv[1:]
    extra = []
    if "--" in args:
        at = args.index("--")
        args, extra = args[:at], args[at + 1:]
    if len(args) not in (3, 4):
        sys.exit(__doc__)
    old, new, path = args[:3]
    rounds = int(args[3]) if len(args) == 4 else 3
    times = {"old": [], "new": []}
    peaks = {"old": 0.0, "new": 0.0}
    same = True
    for r in range(rounds):
        order = [("old", old), ("new", new)] if r % 2 == 0 else [("new", new), ("old", old)]
        reports = {}
        for name, binary in order:
            secs, mib, rep = run(binary, path, extra)
            times[name].append(secs)
            peaks[name] = max(peaks[name], mib)
            reports[name] = rep
            print(f"round {r}: {name} {secs:.2f} s, peak {mib:.0f} MiB, exit {rep[0]}")
        if reports["old"] != reports["new"]:
            same = False
            print(f"round {r}: REPORTS DIFFER")
    for name in ("old", "new"):
        t = sorted(times[name])
        print(f"{name}: fastest {t[0]:.2f} s, median {t[len(t) // 2]:.2f} s, "
              f"peak {peaks[name]:.0f} MiB")
    print("reports equal (times aside)" if same else "reports differ")
    sys.exit(0 if same else 1)


if __name__ == "__main__":
    main()
