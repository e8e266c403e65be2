#!/usr/bin/env python3
"""Checks that two svpack binaries write the same bytes for every model in
../shared/meshes: a change to `build` that should only make it faster or
lighter.

Usage: python3 benches/outputs_equal.py OLD_BINARY NEW_BINARY [INPUT...]

Each OBJ and glTF model under ../shared/meshes (relative to the repository;
or each INPUT given) is built by both binaries with 1 and 2 threads, f32
and unorm16 positions, plain and `--compress`d. Outputs are compared byte
for byte, and so are the exit statuses of inputs either binary refuses
(the malformed models). Prints each difference and a total; exits 1 if any
output or status differs.
"""
import filecmp
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
MESHES = ROOT.parent / "shared" / "meshes"


def build(binary, src, out, threads, extra):
    out.unlink(missing_ok=True)
    p = subprocess.run([binary, "build", str(src), "-o", str(out), "-q",
                        "--threads", str(threads)] + extra,
                       capture_output=True, text=True)
    return p.returncode


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    old, new = sys.argv[1], sys.argv[2]
    if len(sys.argv) > 3:
        inputs = [pathlib.Path(a) for a in sys.argv[3:]]
    else:
        inputs = sorted(p for p in MESHES.rglob("*")
                        if p.suffix in (".obj", ".gltf", ".glb"))
    compared = refused = differ = 0
    with tempfile.TemporaryDirectory() as tmp:
        a, b = pathlib.Path(tmp) / "old.svpk", pathlib.Path(tmp) / "new.svpk"
        for src in inputs:
            for threads in (1, 2):
                for extra in ([], ["--positions", "unorm16"], ["--compress"]):
                    what = f"{src} threads {threads} {' '.join(extra)}".strip()
                    ra, rb = build(old, src, a, threads, extra), build(new, src, b, threads, extra)
                    if ra != rb:
                        differ += 1
                        print(f"differ: {what}: exit {ra} against {rb}")
                    elif ra != 0:
                        refused += 1
                    else:
                        compared += 1
                        if not filecmp.cmp(a, b, shallow=False):
                            differ += 1
                            print(f"differ: {what}")
    print(f"{compared} outputs compared, {refused} refused by both, {differ} differ")
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
