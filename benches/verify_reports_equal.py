#!/usr/bin/env python3
"""Checks that two svpack binaries' `verify` reports agree on every model in
../shared/meshes: a change to `verify` that should only make it faster.

Usage: python3 benches/verify_reports_equal.py OLD_BINARY NEW_BINARY [SEEDS]

Each OBJ and glTF model under ../shared/meshes (relative to the repository)
is built once with OLD_BINARY, with f32 and with unorm16 positions (inputs
it refuses are skipped), and each output is verified by both binaries with
seeds 1..SEEDS (default 3): 12 generated lights and 128 samples (6 and 64
for outputs of 500,000 triangles or more). The JSON reports are compared
with every `time_ms` field removed, and so are the exit statuses. Prints
each difference and a total; exits 1 if any report differs.
"""
import json
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
MESHES = ROOT.parent / "shared" / "meshes"


def untimed(value):
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items() if k != "time_ms"}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


def report(binary, path, args):
    p = subprocess.run([binary, "verify", str(path), "--json", "-q"] + args,
                       capture_output=True, text=True)
    return p.returncode, untimed(json.loads(p.stdout))


def main():
    if len(sys.argv) not in (3, 4):
        sys.exit(__doc__)
    old, new = sys.argv[1], sys.argv[2]
    seeds = int(sys.argv[3]) if len(sys.argv) == 4 else 3
    inputs = sorted(p for p in MESHES.rglob("*")
                    if p.suffix in (".obj", ".gltf", ".glb") and "malformed" not in p.parts)
    compared = differ = 0
    with tempfile.TemporaryDirectory() as tmp:
        for src in inputs:
            for positions in ("f32", "unorm16"):
                out = pathlib.Path(tmp) / f"{src.name}.{positions}.svpk"
                built = subprocess.run(
                    [old, "build", str(src), "-o", str(out), "-q", "--json",
                     "--positions", positions], capture_output=True, text=True)
                if built.returncode != 0:
                    continue
                triangles = json.loads(built.stdout).get("triangles", 0)
                big = triangles >= 500_000
                for seed in range(1, seeds + 1):
                    args = ["--seed", str(seed), "--lights", "6" if big else "12",
                            "--samples", "64" if big else "128"]
                    compared += 1
                    if report(old, out, args) != report(new, out, args):
                        differ += 1
                        print(f"differ: {src.relative_to(MESHES)} {positions} seed {seed}")
    print(f"{compared} reports compared, {differ} differ")
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
