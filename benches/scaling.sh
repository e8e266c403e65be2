#!/usr/bin/env bash
# Build-time scaling on generated scenes (examples/scene.rs): for each
# triangle count, generate the scene, run `svpack build --json` once and print
# a markdown table of triangles, the build's own `time_ms` (load to written
# file, as the CLI reports it) and ns per triangle. Prints only; asserts
# nothing. Usage: bash benches/scaling.sh [N ...]  (default 10000 100000
# 1000000 5000000). Honours CARGO_TARGET_DIR; scenes go to a temp directory
# that is removed at exit.
set -euo pipefail
cd "$(dirname "$0")/.."
counts=("$@")
[ ${#counts[@]} -gt 0 ] || counts=(10000 100000 1000000 5000000)
target="${CARGO_TARGET_DIR:-target}"
cargo build --release --quiet --bin svpack --example scene
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
echo "| triangles | time_ms | ns/triangle |"
echo "|---:|---:|---:|"
for n in "${counts[@]}"; do
  "$target/release/examples/scene" "$n" "$work/scene_$n.obj" 2>/dev/null
  "$target/release/svpack" build "$work/scene_$n.obj" -o "$work/x.svpk" --json >"$work/out.json"
  ms="$(sed -n 's/^ *"time_ms": *\([0-9.eE+-]*\).*/\1/p' "$work/out.json" | head -n 1)"
  awk -v n="$n" -v ms="$ms" 'BEGIN { printf "| %d | %.1f | %.1f |\n", n, ms, ms * 1e6 / n }'
  rm -f "$work/scene_$n.obj" "$work/x.svpk"
done
