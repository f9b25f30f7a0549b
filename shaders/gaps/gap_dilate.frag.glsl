#version 330 core
// The gap pass's tiles dilated (passes/gaps.py): per 4-pixel tile, over the tiles within
// +-GAP_DILATE along AXIS (run along x, then along y on the result), the nearest positive depth
// (r, 0: none) and the nearest jump front (g, 0: none). After both passes a tile holds those of the
// (2 GAP_DILATE + 1)^2 tiles around it: every pixel within +-4 GAP_DILATE = 16 pixels of any of
// its pixels, the walks' longest reach (close_gaps.frag.glsl).

#define AXIS 0
#define GAP_DILATE 4

uniform sampler2D u_tiles;

layout(location = 0) out vec4 out_tile;

void main() {
    ivec2 center = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(u_tiles, 0);
    ivec2 step = AXIS == 0 ? ivec2(1, 0) : ivec2(0, 1);
    float nearest = 0.0;
    float front = 0.0;
    for (int k = -GAP_DILATE; k <= GAP_DILATE; ++k) {
        ivec2 t = center + k * step;
        if (any(lessThan(t, ivec2(0))) || any(greaterThanEqual(t, size))) {
            continue;
        }
        vec2 tile = texelFetch(u_tiles, t, 0).rg;
        if (tile.r > 0.0 && (nearest == 0.0 || tile.r < nearest)) {
            nearest = tile.r;
        }
        if (tile.g > 0.0 && (front == 0.0 || tile.g < front)) {
            front = tile.g;
        }
    }
    out_tile = vec4(nearest, front, 0.0, 0.0);
}
