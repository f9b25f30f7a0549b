#version 330 core
// The farthest depth per 8 x 8 block of the normal + depth image (passes/silhouette.py), with
// background counted as farther than any surface (3e38); pixels outside the image are left
// out. silhouette_normals.frag.glsl skips a pixel whose 3 x 3 blocks (+-8 pixels, more than
// its window's reach) hold nothing farther than its own depth + u_edge_jump: no silhouette.

#include "common/depth_image.glsl"

uniform sampler2D u_normal_depth;

layout(location = 0) out vec4 out_tile;

void main() {
    ivec2 origin = ivec2(gl_FragCoord.xy) * 8;
    ivec2 size = textureSize(u_normal_depth, 0);
    float farthest = 0.0;
    for (int y = 0; y < 8; ++y) {
        for (int x = 0; x < 8; ++x) {
            ivec2 p = origin + ivec2(x, y);
            if (any(greaterThanEqual(p, size))) {
                continue;
            }
            float z = texelFetch(u_normal_depth, p, 0).w;
            farthest = max(farthest, z > 0.0 ? z : 3e38);
        }
    }
    out_tile = vec4(farthest, 0.0, 0.0, 0.0);
}
