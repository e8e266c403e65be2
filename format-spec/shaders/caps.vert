// svpack reference caps vertex shader, GLSL ES 1.00, WebGL 1 + ANGLE_instanced_arrays.
// Source = "precision highp float;\n" + common.glsl + this file.
// One draw: drawArraysInstancedANGLE(TRIANGLES, 0, 6, triangles)
// Attributes: aVertexId (divisor 0, the 6-float buffer 0..5); aP0, aP1, aP2
// (divisor 1, stride 48, offsets 0, 16, 32).

attribute float aVertexId;
attribute vec4 aP0;
attribute vec4 aP1;
attribute vec4 aP2;

uniform mat4 uViewProj;  // record space -> clip (projection * view * model, spec 4.5), infinite far plane
uniform vec4 uLight;     // record space (spec 4.5); w = 1 point, w = 0 directional

void main() {
    vec3 p0 = aP0.xyz;
    vec3 p1 = aP1.xyz;
    vec3 p2 = aP2.xyz;
    // Same expression as every side of this triangle (reference edge).
    float s = svTriSign(p0, p1, p2, uLight);
    if (s == 0.0) {
        gl_Position = vec4(0.0);
        return;
    }
    if (s < 0.0) {
        vec3 t = p0;
        p0 = p1;
        p1 = t;
    }
    float v = floor(aVertexId + 0.5);
    if (v < 2.5) {
        // Front cap (p0, p1, p2), pushed to the far plane: z = w.
        vec3 p = v < 0.5 ? p0 : (v < 1.5 ? p1 : p2);
        vec4 c = uViewProj * vec4(p, 1.0);
        gl_Position = vec4(c.x, c.y, c.w, c.w);
    } else {
        // Back cap at infinity, reversed: (p2, p1, p0).
        vec3 p = v < 3.5 ? p2 : (v < 4.5 ? p1 : p0);
        gl_Position = uViewProj * svToInfinity(p, uLight);
    }
}
