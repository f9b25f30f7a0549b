#version 330 core
// The gap pass's tiles dilated (passes/gaps.py), in two 1-D passes over the 4-pixel tiles of
// gap_tiles.frag.glsl (nearest depth, nearest jump front): +-GAP_DILATE tiles along x, then
// along y on the result. A depth here is the nearest positive one of a window (0: none).
// AXIS 0 writes, per tile, over the tiles [-GAP_DILATE, +GAP_DILATE] along x: (nearest depth,
// nearest front), and the nearest front over [-GAP_DILATE, 0] (x-) and [0, +GAP_DILATE] (x+).
// AXIS 1 writes three targets, dilating that along y:
// * out_tile: (nearest depth, nearest front) of the (2 GAP_DILATE + 1)^2 tiles around: every
//   pixel within +-4 GAP_DILATE = 16 pixels of any of the tile's pixels, the walks' longest
//   reach (close_gaps.frag.glsl);
// * out_axes: the nearest front on each side of the tile along its row and its column
//   (x-, x+, y+, y-; the tile's own included): a walk from any pixel of the tile along
//   (+-1, 0) or (0, +-1) only reaches pixels there;
// * out_diagonals: the nearest front of the four quadrants (x+ y+, x- y-, x+ y-, x- y+), which
//   hold every pixel a walk along (1, 1), (-1, -1), (1, -1), (-1, 1) reaches;
// * out_tile.b: 1 where some pixel of the tile may be closed: close_gaps.frag.glsl's tests
//   passed at the tile's most permissive depths (a background pixel of it, and its farthest
//   surface: "nearer than zc" only admits more as zc grows), so the close pass draws only
//   those tiles (passes/gaps.py) and copies the rest.
// A walk can only stop on a jump front nearer than the pixel it starts from, so these bound
// the directions a pixel can be enclosed along.

#define AXIS 0
#define GAP_DILATE 4

uniform sampler2D u_tiles;  // AXIS 0: gap_tiles' output; AXIS 1: this shader's AXIS 0 output
#if AXIS == 1
uniform sampler2D u_raw;    // gap_tiles' output (the column's own fronts, the tile's own depths)
uniform float u_edge_jump;  // as close_gaps.frag.glsl's
layout(location = 1) out vec4 out_axes;
layout(location = 2) out vec4 out_diagonals;
#endif
layout(location = 0) out vec4 out_tile;

const float NONE = 3.0e38;  // inside this shader "none" is a huge depth, so min() merges

vec4 read_tile(sampler2D tiles, ivec2 t) {
    vec4 tile = texelFetch(tiles, t, 0);
    return mix(tile, vec4(NONE), lessThanEqual(tile, vec4(0.0)));
}

vec4 written(vec4 nearest) {
    return mix(nearest, vec4(0.0), greaterThanEqual(nearest, vec4(NONE)));
}

#if AXIS == 1
bool nearer(float z, float zc) {
    return z > 0.0 && (zc <= 0.0 || z < zc - u_edge_jump);
}

// close_gaps.frag.glsl's tests for a pixel of depth zc (0: background) that needs `need`
// enclosing directions: a nearer front around, and on both sides along `need` directions.
bool may_close(float front, vec4 axes, vec4 diagonals, float zc, int need) {
    int directions = int(nearer(axes.r, zc) && nearer(axes.g, zc))
        + int(nearer(axes.b, zc) && nearer(axes.a, zc))
        + int(nearer(diagonals.r, zc) && nearer(diagonals.g, zc))
        + int(nearer(diagonals.b, zc) && nearer(diagonals.a, zc));
    return nearer(front, zc) && directions >= need;
}
#endif

void main() {
    ivec2 center = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(u_tiles, 0);
    ivec2 step = AXIS == 0 ? ivec2(1, 0) : ivec2(0, 1);
    vec4 all_of = vec4(NONE);    // the whole window, per input channel
    vec4 negative = vec4(NONE);  // offsets <= 0
    vec4 positive = vec4(NONE);  // offsets >= 0
#if AXIS == 1
    vec2 raw = vec2(NONE);       // the raw front over offsets <= 0, >= 0
#endif
    for (int k = -GAP_DILATE; k <= GAP_DILATE; ++k) {
        ivec2 t = center + k * step;
        if (any(lessThan(t, ivec2(0))) || any(greaterThanEqual(t, size))) {
            continue;
        }
        vec4 tile = read_tile(u_tiles, t);
        all_of = min(all_of, tile);
#if AXIS == 1
        float raw_front = read_tile(u_raw, t).g;
#endif
        if (k <= 0) {
            negative = min(negative, tile);
#if AXIS == 1
            raw.x = min(raw.x, raw_front);
#endif
        }
        if (k >= 0) {
            positive = min(positive, tile);
#if AXIS == 1
            raw.y = min(raw.y, raw_front);
#endif
        }
    }
#if AXIS == 0
    out_tile = written(vec4(all_of.r, all_of.g, negative.g, positive.g));
#else
    vec4 own = read_tile(u_tiles, center);
    vec4 tile = written(vec4(all_of.r, all_of.g, NONE, NONE));
    out_axes = written(vec4(own.b, own.a, raw.y, raw.x));
    out_diagonals = written(vec4(positive.a, negative.b, negative.a, positive.b));
    vec4 depths = texelFetch(u_raw, center, 0);  // b: farthest depth, a: has background
    bool any_closes = (depths.a > 0.0 && may_close(tile.g, out_axes, out_diagonals, 0.0, 2))
        || (depths.b > 0.0 && may_close(tile.g, out_axes, out_diagonals, depths.b, 1));
    out_tile = vec4(tile.r, tile.g, any_closes ? 1.0 : 0.0, 0.0);
#endif
}
