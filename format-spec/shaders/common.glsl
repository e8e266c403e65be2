// svpack reference GLSL ES 1.00 — shared multiplicity code (format-spec/multiplicity.md).
// Normative: the CPU evaluator (src/multiplicity.rs) performs the same f32
// operations in the same order. Do not "simplify" with the cross, dot or sign builtins:
// their internal evaluation order is unspecified.

// Strict lexicographic order on (x, y, z). Files contain no -0.0 and no NaN.
bool svLess(vec3 a, vec3 b) {
    if (a.x != b.x) return a.x < b.x;
    if (a.y != b.y) return a.y < b.y;
    return a.z < b.z;
}

// Sign of ((r2 - r0) x (L.xyz - r0 * L.w)) . (r1 - r0) for sorted r0 < r1 < r2.
float svRefSign(vec3 r0, vec3 r1, vec3 r2, vec4 L) {
    // A point light exactly on a corner: in the plane, exactly 0.
    if (L.w == 1.0) {
        if (r0.x == L.x && r0.y == L.y && r0.z == L.z) return 0.0;
        if (r1.x == L.x && r1.y == L.y && r1.z == L.z) return 0.0;
        if (r2.x == L.x && r2.y == L.y && r2.z == L.z) return 0.0;
    }
    vec3 x = r2 - r0;
    vec3 y = vec3(L.x - r0.x * L.w, L.y - r0.y * L.w, L.z - r0.z * L.w);
    vec3 d = r1 - r0;
    float nx = x.y * y.z - x.z * y.y;
    float ny = x.z * y.x - x.x * y.z;
    float nz = x.x * y.y - x.y * y.x;
    float s = (nx * d.x + ny * d.y) + nz * d.z;
    if (s > 0.0) return 1.0;
    if (s < 0.0) return -1.0;
    return 0.0;
}

// Orientation of the ordered triangle (p0, p1, p2) towards the light, through
// the reference edge: sort the corners with a 3-comparator network, flip the
// sign for every swap.
float svTriSign(vec3 p0, vec3 p1, vec3 p2, vec4 L) {
    float parity = 1.0;
    vec3 t;
    if (svLess(p1, p0)) { t = p0; p0 = p1; p1 = t; parity = -parity; }
    if (svLess(p2, p1)) { t = p1; p1 = p2; p2 = t; parity = -parity; }
    if (svLess(p1, p0)) { t = p0; p0 = p1; p1 = t; parity = -parity; }
    return parity * svRefSign(p0, p1, p2, L);
}

// Extrusion to infinity away from the light: (p * L.w - L.xyz, 0).
vec4 svToInfinity(vec3 p, vec4 L) {
    return vec4(p.x * L.w - L.x, p.y * L.w - L.y, p.z * L.w - L.z, 0.0);
}
