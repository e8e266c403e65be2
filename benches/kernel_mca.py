#!/usr/bin/env python3
"""Static throughput of the evaluator's caps kernels and the build's
side-record fill, by llvm-mca.

Usage: python3 benches/kernel_mca.py BINARY [MCPU]

BINARY must be built with `-C symbol-mangling-version=v0` (so that each
monomorphised copy of `evaluate_indexed::avx512vl` is named with its
generic arguments); `bash benches/kernel_mca.sh` builds one and runs this.
MCPU is llvm-mca's CPU model (default `icelake-server`, the Intel Xeon of
the rounds since the fifty-first; llvm 14, Debian's here, has no Zen 4
model, and its `znver3` has no AVX-512, so it models the one-light copy
only).

The fill (`layout::fill_sides`) is read on its path for an edge of two
triangles, the record of every edge of a closed mesh: the loop the
backward branch of that path closes, one edge per iteration.

Why: this guest exposes no hardware counters (`perf stat` reports cycles
and instructions as "not supported"), so where a kernel's time goes cannot
be counted. llvm-mca reads each inner loop and gives, from the CPU model,
the cycles per iteration its ports allow and which ports bound it.
Measured time above that bound is waiting (cache misses, the front end);
at it, only fewer instructions on the busiest ports make the loop faster.

Per loop: its instructions and micro-ops, its loads (instructions with a
memory source, the prefetches included; in brackets those that reload a
value from the stack, one the registers could not hold), llvm-mca's
cycles per iteration over 200 iterations and its throughput bound, the
three busiest ports, and the cycles per unit (per triangle, per triangle
and light for a group of four, per edge for the fill).
"""

import re
import subprocess
import sys


def does_products(body):
    """A caps kernel's block loop: the contract's products (`vmulps`)."""
    return any(t.startswith("vmulps") for t in body)


def writes_a_record(body):
    """The fill's k = 2 path: the prefetches of the edge 64 on and the
    record's four 16-byte stores (`put_rows`)."""
    stores = sum(1 for t in body if re.match(r"movups\s+XMMWORD PTR \[", t))
    return any(t.startswith("prefetcht0") for t in body) and stores >= 4


# (label, function, what its loop's body holds, units per iteration,
# unit). The caps kernels are the copies timed by `stage_probe --
# evaluate` (its `auto` row: point lights, no light on a corner): one
# light into bytes, four into the group's pairs; generic arguments TEST,
# POINT, lights, sink. Their loop is a block of 8 triangles.
KERNELS = [
    ("caps, one light", "svpack::evaluate_indexed::avx512vl::<false, true, 1, svpack::evaluate_indexed::Bytes<1>>", does_products, 8, "triangle"),
    ("caps, four lights at once", "svpack::evaluate_indexed::avx512vl::<false, true, 4, svpack::evaluate_indexed::Pairs>", does_products, 32, "triangle and light"),
    ("sides' fill, k = 2", "svpack::layout::fill_sides", writes_a_record, 1, "edge"),
]


def symbols(binary):
    """(address, demangled name) of every text symbol, by address."""
    out = subprocess.run(["nm", "-C", "--defined-only", "-n", binary], capture_output=True, text=True, check=True).stdout
    syms = []
    for line in out.splitlines():
        parts = line.split(" ", 2)
        if len(parts) == 3 and parts[1] in "tTwW":
            syms.append((int(parts[0], 16), parts[2]))
    return syms


def disassemble(binary, start, stop):
    """[(address, instruction text)] of [start, stop), Intel syntax."""
    out = subprocess.run(
        ["objdump", "-d", "--no-show-raw-insn", "-M", "intel", f"--start-address={start}", f"--stop-address={stop}", binary],
        capture_output=True, text=True, check=True,
    ).stdout
    code = []
    for line in out.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(.*)$", line)
        if m:
            code.append((int(m.group(1), 16), m.group(2).strip()))
    return code


def inner_loop(code, holds):
    """The body of the largest loop a backward conditional jump closes
    whose body `holds`."""
    best = None
    for i, (addr, text) in enumerate(code):
        m = re.match(r"j\w+\s+([0-9a-f]+)\b", text)
        if not m or text.startswith("jmp"):
            continue
        target = int(m.group(1), 16)
        if target >= addr:
            continue
        body = [t for a, t in code[: i + 1] if a >= target]
        if holds(body) and (best is None or len(body) > len(best)):
            best = body
    if best is None:
        sys.exit(f"no loop that {holds.__name__} found")
    # The closing jump names an address, which llvm-mca cannot resolve.
    return [re.sub(r"\s*<[^>]*>", "", t) for t in best[:-1]]


def mca(body, mcpu):
    asm = ".intel_syntax noprefix\n" + "\n".join(body) + "\n"
    out = subprocess.run(
        ["llvm-mca", f"-mcpu={mcpu}", "-iterations=200", "-all-stats=false"],
        input=asm, capture_output=True, text=True,
    )
    if "not a recognized processor" in out.stderr:
        sys.exit(f"llvm-mca: {out.stderr.strip().splitlines()[0]}")
    if out.returncode != 0:
        # A model without the copy's instructions (AVX-512 on znver3).
        return None, out.stderr.strip().splitlines()[-1]
    return out.stdout, None


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    binary = sys.argv[1]
    mcpu = sys.argv[2] if len(sys.argv) > 2 else "icelake-server"
    syms = symbols(binary)
    names = [n for _, n in syms]
    for _, name, *_ in KERNELS:
        if name not in names:
            sys.exit(f"{name}: not in {binary} (built with -C symbol-mangling-version=v0?)")
    mca(["nop"], mcpu)  # exits on a CPU llvm-mca does not know
    print(f"llvm-mca -mcpu={mcpu}")
    print("| loop | units per iteration | instructions | micro-ops | loads (from the stack) | cycles per iteration | bound | busiest ports | cycles per unit |")
    print("|---|---|---:|---:|---:|---:|---:|---|---:|")
    for label, name, holds, units, unit in KERNELS:
        i = names.index(name)
        start, stop = syms[i][0], syms[i + 1][0]
        body = inner_loop(disassemble(binary, start, stop), holds)
        report, error = mca(body, mcpu)
        if report is None:
            print(f"| {label} | {units} | {len(body)} | not modelled: {error} |")
            continue
        iterations = int(re.search(r"Iterations:\s+(\d+)", report).group(1))
        cycles = int(re.search(r"Total Cycles:\s+(\d+)", report).group(1)) / iterations
        uops = int(re.search(r"Total uOps:\s+(\d+)", report).group(1)) / iterations
        bound = float(re.search(r"Block RThroughput:\s+([\d.]+)", report).group(1))
        # Resource names, then the pressure per iteration on each.
        # (the ids of a resource with several units: [12.0], [12.1]).
        head, tail = report.split("Resource pressure per iteration:")
        resources = dict(re.findall(r"\[([\d.]+)\]\s*-\s*(\S+)", head))
        ids = re.findall(r"\[([\d.]+)\]", tail.splitlines()[1])
        values = tail.splitlines()[2].split()
        ports = sorted(
            ((float(v), resources[k] + (f"[{k}]" if "." in k else "")) for k, v in zip(ids, values) if v != "-"),
            reverse=True,
        )
        load_list = [t for t in body if re.search(r"PTR \[", t) and not re.match(r"(v?mov\w*)\s+(XMM|YMM|ZMM|Q|D)WORD PTR", t)]
        loads, reloads = len(load_list), sum(1 for t in load_list if "[rsp" in t)
        busiest = ", ".join(f"{p} {v:.1f}" for v, p in ports[:3])
        per_unit = cycles / units
        print(f"| {label} | {units} ({unit}) | {len(body)} | {uops:.0f} | {loads} ({reloads}) | {cycles:.1f} | {bound:.1f} | {busiest} | {per_unit:.2f} |")


if __name__ == "__main__":
    main()
