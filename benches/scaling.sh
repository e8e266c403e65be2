#!/usr/bin/env bash
# Build-time scaling on generated scenes (examples/scene.rs) and, when
# benches/fetch_dragon.sh has fetched it, the full Stanford dragon. For each
# input, runs `svpack build --timings --json` with 1 and with 2 threads
# (fastest of REPS runs each, default 3; outputs go to fresh paths and are
# compared byte for byte) and prints a markdown table:
#   triangles, whole build (1 thread), ns per triangle, the stages after
#   parsing (weld + topology + layout + write) in ns per triangle, the same
#   with 2 threads, and the 2-thread speed-ups of both;
# then a second table, the stages after parsing in ns per triangle in the
# 1-thread run fastest after parsing (weld, topology, layout, write): which
# stage a bend in the curve comes from. With one thread the topology stage
# also fills and writes the caps, and the side records its edges have
# made, as it goes (the write stage has the rest).
# Prints only; asserts nothing except identical outputs.
# With SVG=PATH, also draws the same figures as a curve of ns per triangle
# against triangles into PATH (examples/scaling_svg.rs; docs/scaling.svg is
# one).
# Usage: bash benches/scaling.sh [N ...]  (default 10000 100000 1000000
# 5000000). Honours CARGO_TARGET_DIR, REPS and SVG; scenes go to a temp
# directory removed at exit.
set -euo pipefail
cd "$(dirname "$0")/.."
counts=("$@")
[ ${#counts[@]} -gt 0 ] || counts=(10000 100000 1000000 5000000)
reps="${REPS:-3}"
target="${CARGO_TARGET_DIR:-target}"
cargo build --release --quiet --bin svpack --example scene --example scaling_svg
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# fastest THREADS INPUT -> "total_ms after_parse_ms weld topology layout write"
# (the minimum of the first two over REPS; the stages of the run fastest
# after parsing)
fastest() {
  local best_total="" best_after="" best_stages="" i
  for i in $(seq "$reps"); do
    rm -f "$work/out_$1.svpk"
    "$target/release/svpack" build "$2" -o "$work/out_$1.svpk" --threads "$1" --timings --json -q \
      >"$work/t.json"
    read -r total after stages < <(python3 -c '
import json, sys
t = json.load(open(sys.argv[1]))["timings_ms"]
stages = [t[s] for s in ("weld", "topology", "layout", "write")]
print(t["total"], sum(stages), *stages)' "$work/t.json")
    best_total=$(python3 -c "print(min(float('$total'), float('${best_total:-inf}')))")
    if python3 -c "import sys; sys.exit(not float('$after') < float('${best_after:-inf}'))"; then
      best_after=$after
      best_stages=$stages
    fi
  done
  echo "$best_total $best_after $best_stages"
}

row() { # NAME TRIANGLES INPUT
  read -r t1 a1 w1 p1 l1 r1 < <(fastest 1 "$3")
  read -r t2 a2 _ < <(fastest 2 "$3")
  cmp -s "$work/out_1.svpk" "$work/out_2.svpk" || { echo "$1: outputs differ between 1 and 2 threads" >&2; exit 1; }
  python3 -c '
import sys
name, n, t1, a1, t2, a2 = sys.argv[1], int(sys.argv[2]), *map(float, sys.argv[3:])
print(f"| {name} | {n:,} | {t1:.1f} ms | {t1 * 1e6 / n:.0f} | {a1 * 1e6 / n:.0f} | {a2 * 1e6 / n:.0f} | {t1 / t2:.2f}x | {a1 / a2:.2f}x |")' \
    "$1" "$2" "$t1" "$a1" "$t2" "$a2"
  echo "$1,$2,$t1,$a1,$t2,$a2" >>"$work/rows.csv"
  python3 -c '
import sys
name, n, *ms = sys.argv[1], int(sys.argv[2]), *map(float, sys.argv[3:])
print(f"| {name} | {n:,} | " + " | ".join(f"{m * 1e6 / n:.0f}" for m in ms) + " |")' \
    "$1" "$2" "$w1" "$p1" "$l1" "$r1" "$a1" >>"$work/stages.md"
}

echo "| input | triangles | build, 1 thread | ns/tri | after parsing, ns/tri (1 thread) | after parsing, ns/tri (2 threads) | 2-thread speed-up, whole | 2-thread speed-up, after parsing |"
echo "|---|---:|---:|---:|---:|---:|---:|---:|"
for n in "${counts[@]}"; do
  "$target/release/examples/scene" "$n" "$work/scene_$n.obj" 2>/dev/null
  row "scene" "$n" "$work/scene_$n.obj"
  rm -f "$work/scene_$n.obj"
done
if [ -s target/dragon/dragon.obj ]; then
  row "Stanford dragon" 871414 target/dragon/dragon.obj
fi
echo
echo "Stages after parsing, ns per triangle, 1 thread (the run fastest after parsing):"
echo
echo "| input | triangles | weld | topology | layout | write | after parsing |"
echo "|---|---:|---:|---:|---:|---:|---:|"
cat "$work/stages.md"
if [ -n "${SVG:-}" ]; then
  "$target/release/examples/scaling_svg" "$work/rows.csv" "$SVG"
  echo "curve: $SVG" >&2
fi
