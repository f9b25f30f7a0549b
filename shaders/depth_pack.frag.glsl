#version 330 core
// Eye depth (R32F, one pixel per texel) -> packed (RGBA32F): texel (x, y) holds pixels
// 4x .. 4x+3 of row y; pixels beyond the image's right edge are background (0).

#include "common/depth_image.glsl"

uniform sampler2D u_depth;

layout(location = 0) out vec4 out_packed_depth;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    ivec2 first = ivec2(4 * texel.x, texel.y);
    out_packed_depth = vec4(
        fetch_depth(u_depth, first),
        fetch_depth(u_depth, first + ivec2(1, 0)),
        fetch_depth(u_depth, first + ivec2(2, 0)),
        fetch_depth(u_depth, first + ivec2(3, 0))
    );
}
