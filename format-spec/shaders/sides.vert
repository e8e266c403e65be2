// svpack reference sides vertex shader, GLSL ES 1.00, WebGL 1 + ANGLE_instanced_arrays.
// Source = "#define SVPK_K <k>\n" + "precision highp float;\n" + common.glsl + this file.
// One program per bucket k. Draw per side index s = 0..k-1:
//   uniform uSide = s; drawArraysInstancedANGLE(TRIANGLES, 0, 6, instances)
// Attributes: aVertexId (divisor 0, the 6-float buffer 0..5); aA, aB, aO0..aO{k-1}
// (divisor 1, stride 16*(2+k), offsets 0, 16, 32, ...).

attribute float aVertexId;
attribute vec4 aA;
attribute vec4 aB;
attribute vec4 aO0;
#if SVPK_K > 1
attribute vec4 aO1;
#endif
#if SVPK_K > 2
attribute vec4 aO2;
#endif
#if SVPK_K > 3
attribute vec4 aO3;
#endif
#if SVPK_K > 4
attribute vec4 aO4;
#endif
#if SVPK_K > 5
attribute vec4 aO5;
#endif
#if SVPK_K > 6
attribute vec4 aO6;
#endif
#if SVPK_K > 7
attribute vec4 aO7;
#endif
#if SVPK_K > 8
attribute vec4 aO8;
#endif
#if SVPK_K > 9
attribute vec4 aO9;
#endif
#if SVPK_K > 10
attribute vec4 aO10;
#endif
#if SVPK_K > 11
attribute vec4 aO11;
#endif
#if SVPK_K > 12
attribute vec4 aO12;
#endif

uniform mat4 uViewProj;  // record space -> clip (projection * view * model, spec 4.5), infinite far plane
uniform vec4 uLight;     // record space (spec 4.5); w = 1 point, w = 0 directional
uniform float uSide;     // side index s of this draw, 0 .. k-1

void main() {
    vec3 a = aA.xyz;
    vec3 b = aB.xyz;
    // Multiplicity: sum of per-opposite-vertex signs, in slot order.
    float m = svTriSign(a, b, aO0.xyz, uLight);
#if SVPK_K > 1
    m += svTriSign(a, b, aO1.xyz, uLight);
#endif
#if SVPK_K > 2
    m += svTriSign(a, b, aO2.xyz, uLight);
#endif
#if SVPK_K > 3
    m += svTriSign(a, b, aO3.xyz, uLight);
#endif
#if SVPK_K > 4
    m += svTriSign(a, b, aO4.xyz, uLight);
#endif
#if SVPK_K > 5
    m += svTriSign(a, b, aO5.xyz, uLight);
#endif
#if SVPK_K > 6
    m += svTriSign(a, b, aO6.xyz, uLight);
#endif
#if SVPK_K > 7
    m += svTriSign(a, b, aO7.xyz, uLight);
#endif
#if SVPK_K > 8
    m += svTriSign(a, b, aO8.xyz, uLight);
#endif
#if SVPK_K > 9
    m += svTriSign(a, b, aO9.xyz, uLight);
#endif
#if SVPK_K > 10
    m += svTriSign(a, b, aO10.xyz, uLight);
#endif
#if SVPK_K > 11
    m += svTriSign(a, b, aO11.xyz, uLight);
#endif
#if SVPK_K > 12
    m += svTriSign(a, b, aO12.xyz, uLight);
#endif
    // This draw emits the s-th copy of the quad only if s < |m|.
    if (uSide >= abs(m)) {
        gl_Position = vec4(0.0);
        return;
    }
    // Paper eq. 3-5: which quad corner (0 = A, 1 = B, 2 = A at infinity,
    // 3 = B at infinity) vertex v is. m > 0: triangles (2,1,0), (1,2,3);
    // m < 0: the same two triangles reversed, (0,1,2), (3,2,1).
    float v = floor(aVertexId + 0.5);
    float id;
    if (m > 0.0) {
        id = v > 2.0 ? v - 2.0 : 2.0 - v;
    } else {
        id = v > 2.0 ? 6.0 - v : v;
    }
    vec4 p;
    if (id < 0.5) {
        p = vec4(a, 1.0);
    } else if (id < 1.5) {
        p = vec4(b, 1.0);
    } else if (id < 2.5) {
        p = svToInfinity(a, uLight);
    } else {
        p = svToInfinity(b, uLight);
    }
    gl_Position = uViewProj * p;
}
