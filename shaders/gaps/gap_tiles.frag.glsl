#version 330 core
// Tiles for the gap pass's bounds (passes/gaps.py): one fragment per 4 x 4 block of the
// eye-depth image, r = the smallest positive depth in it (0: none; it bounds the walks' reach),
// g = the smallest depth of its jump fronts (0: none): pixels with a surface that some
// 8-neighbour (outside the image: background) has none, or is farther than by more than
// u_edge_jump. A walk of close_gaps.frag.glsl can only stop on such a pixel (it arrives there
// from its neighbour by a jump), so a pixel with no jump front nearer than itself within reach
// has nothing to close. gap_dilate.frag.glsl spreads both over +-16 pixels. b = the farthest
// depth in the block (0: none), a = 1 where the block has a pixel without surface: with them
// the dilation tells whether any of the block's pixels can be closed at all.

#include "common/depth_image.glsl"

uniform sampler2D u_source;
uniform float u_edge_jump;

layout(location = 0) out vec4 out_tile;

float nearest_positive(float a, float b) {
    return b > 0.0 && (a == 0.0 || b < a) ? b : a;
}

void main() {
    ivec2 origin = ivec2(gl_FragCoord.xy) * 4;
    ivec2 size = textureSize(u_source, 0);
    // The block and a one-pixel ring: every depth the 16 pixels' neighbour tests read.
    float z[36];
    for (int y = 0; y < 6; ++y) {
        for (int x = 0; x < 6; ++x) {
            z[y * 6 + x] = fetch_depth(u_source, origin + ivec2(x - 1, y - 1));
        }
    }
    float nearest = 0.0;
    float front = 0.0;
    float farthest = 0.0;
    float background = 0.0;
    for (int y = 1; y <= 4; ++y) {
        for (int x = 1; x <= 4; ++x) {
            if (any(greaterThanEqual(origin + ivec2(x - 1, y - 1), size))) {
                continue;
            }
            float zq = z[y * 6 + x];
            if (zq <= 0.0) {
                background = 1.0;
                continue;
            }
            nearest = nearest_positive(nearest, zq);
            farthest = max(farthest, zq);
            bool jump = false;
            for (int dy = -1; dy <= 1; ++dy) {
                for (int dx = -1; dx <= 1; ++dx) {
                    float zn = z[(y + dy) * 6 + x + dx];
                    jump = jump || zn <= 0.0 || zq < zn - u_edge_jump;
                }
            }
            if (jump) {
                front = nearest_positive(front, zq);
            }
        }
    }
    out_tile = vec4(nearest, front, farthest, background);
}
