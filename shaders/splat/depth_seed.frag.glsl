#version 330 core
// Seeds the droplet splat (passes/splat.py, exact droplets): copies the smoothed eye depth into
// the composite target and writes the matching linear gl_FragDepth (eye depth / far, as
// splat_sphere.frag.glsl does), so the droplets drawn next are depth-tested against the
// smoothed surface. Background pixels write nothing (the depth buffer stays cleared to 1).

#include "common/depth_image.glsl"

uniform sampler2D u_depth;
uniform float u_far;

layout(location = 0) out float out_eye_depth;

void main() {
    float z = fetch_depth(u_depth, ivec2(gl_FragCoord.xy));
    if (z <= 0.0) {
        discard;
    }
    out_eye_depth = z;
    gl_FragDepth = clamp(z / u_far, 0.0, 1.0);
}
