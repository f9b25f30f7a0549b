#version 400 core
// The farthest and the nearest depth per 4 x 4 block of the eye-depth image
// (passes/rim_tiles.py), with background counted as farther than any surface (3e38) and left
// out of the nearest (3e38 when a block has no surface); pixels outside the image are left
// out. RIM_DILATE 1: instead, the farthest and the nearest of these tiles within +-2 along AXIS
// (run along x, then along y: a tile then holds the extremes within +-8 pixels of any of its
// pixels, more than either reader's reach). silhouette_normals.frag.glsl skips a pixel whose
// tile holds nothing farther than its own depth + u_edge_jump (no silhouette within reach),
// field/field_normals.glsl one whose tile holds nothing beyond the jump either way.

#define RIM_DILATE 0
#define AXIS 0

uniform sampler2D u_depth;  // R32F eye depth (0 = no surface), or the tiles to dilate

layout(location = 0) out vec4 out_tile;

void main() {
    ivec2 size = textureSize(u_depth, 0);
    float farthest = 0.0;
    float nearest = 3e38;
#if RIM_DILATE
    ivec2 center = ivec2(gl_FragCoord.xy);
    ivec2 step = AXIS == 0 ? ivec2(1, 0) : ivec2(0, 1);
    for (int k = -2; k <= 2; ++k) {
        ivec2 t = center + k * step;
        if (all(greaterThanEqual(t, ivec2(0))) && all(lessThan(t, size))) {
            vec2 tile = texelFetch(u_depth, t, 0).rg;
            farthest = max(farthest, tile.r);
            nearest = min(nearest, tile.g);
        }
    }
#else
    // Four 2 x 2 gathers; past the image's edge the texture clamps to it, which repeats this
    // block's own edge pixels (the extremes are the same).
    vec2 texel = 1.0 / vec2(size);
    vec2 origin = vec2(ivec2(gl_FragCoord.xy) * 4);
    for (int y = 1; y < 4; y += 2) {
        for (int x = 1; x < 4; x += 2) {
            vec4 z = textureGather(u_depth, (origin + vec2(x, y)) * texel);
            // Background is the farthest of all, and no candidate for the nearest.
            vec4 v = mix(z, vec4(3e38), lessThanEqual(z, vec4(0.0)));
            farthest = max(farthest, max(max(v.x, v.y), max(v.z, v.w)));
            nearest = min(nearest, min(min(v.x, v.y), min(v.z, v.w)));
        }
    }
#endif
    out_tile = vec4(farthest, nearest, 0.0, 0.0);
}
