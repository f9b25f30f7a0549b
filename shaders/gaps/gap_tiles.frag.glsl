#version 330 core
// Tiles for the gap pass's bounds (passes/gaps.py): one fragment per 4 x 4 block of the
// eye-depth image, r = the smallest positive depth in it (0: none), g = 1 where it holds an
// edge, else 0: a pixel whose right or upper neighbour (outside the image: background) differs
// from it by more than u_edge_jump / 2, or one of the two is background (a jump of u_edge_jump
// along a diagonal step has a jump of at least half of it along one of its two axis steps).
// gap_dilate.frag.glsl spreads them over +-16 pixels for close_gaps.frag.glsl.

#include "common/depth_image.glsl"

uniform sampler2D u_source;
uniform float u_edge_jump;

layout(location = 0) out vec4 out_tile;

bool differs(float a, float b) {
    return (a > 0.0) != (b > 0.0) || abs(a - b) > 0.5 * u_edge_jump;
}

void main() {
    ivec2 origin = ivec2(gl_FragCoord.xy) * 4;
    ivec2 size = textureSize(u_source, 0);
    float nearest = 0.0;
    float edge = 0.0;
    for (int y = 0; y < 4; ++y) {
        for (int x = 0; x < 4; ++x) {
            ivec2 p = origin + ivec2(x, y);
            if (any(greaterThanEqual(p, size))) {
                continue;
            }
            float z = texelFetch(u_source, p, 0).r;
            if (differs(z, fetch_depth(u_source, p + ivec2(1, 0)))
                || differs(z, fetch_depth(u_source, p + ivec2(0, 1)))) {
                edge = 1.0;
            }
            if (z > 0.0 && (nearest == 0.0 || z < nearest)) {
                nearest = z;
            }
        }
    }
    out_tile = vec4(nearest, edge, 0.0, 0.0);
}
