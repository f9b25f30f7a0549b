#version 430 core
// Field normals, first part (passes/field_normals.py), by phase (u_phase):
//   0  one invocation per rim tile (passes/rim_tiles.py) of the box: a tile where some pixel
//      may lie within reach of a rim appends itself to `tiles` (the test below);
//   1  one invocation: the work groups of phase 2 for the listed tiles, as the arguments of an
//      indirect dispatch (x at most u_groups_x, then rows);
//   2  dispatched with them, one invocation per pixel of a listed tile (16 to a tile, 4 tiles
//      to a work group): a surface pixel of the box within reach of a rim is listed
//      (field/field_rims.glsl).
// The tile test (may_list), conservative for every pixel of the tile (depth zc between the
// tile's nearest and farthest, u_tile_extremes: background 3e38 in the farthest): such a pixel
// searches only when its tile's window (u_tiles: the extremes within +-8 px) holds a depth
// beyond the jump at zc, which is at least u_edge_jump; it finds a rim at distance d only
// within its limit = reach + 1, which is largest at the tile's nearest depth (the reach is
// projected radii), and only in a tile whose nearest pixel lies dm <= d from some pixel of this
// one, beyond a jump at least that at max(dm, 1) and the tile's nearest depth (the jump's
// footprint part grows with depth and distance): the same float comparisons as
// field/field_normals.glsl's on the extremes, so no listed pixel is ever missed. On the 100k
// ball at 1280x720: 2.7k of 57.6k tiles list themselves (4.5k with the window test alone,
// whose steep slopes inside a silhouette step by more than u_edge_jump over 8 px).

#define FIELD_LIST_GROUP 64

layout(local_size_x = FIELD_LIST_GROUP) in;

#include "common/depth_image.glsl"

uniform sampler2D u_depth;
uniform float u_edge_jump;
uniform float u_edge_jump_px;
uniform float u_focal_px;
uniform float u_particle_radius;
uniform int u_phase;
uniform uint u_groups_x;
uniform ivec4 u_tile_box;  // x, y, width, height, in tiles
uniform ivec4 u_box;       // x, y, width, height, in pixels: where the normals pass drew

#include "field/field_rims.glsl"

layout(std430, binding = 21) buffer Tiles { uint tile_list[]; };
layout(std430, binding = 22) buffer TileCount { uint tile_count; uint tiles_x; uint tiles_y; uint tiles_z; };

// Whether a pixel of `tile` may lie within reach of a rim (see the header).
bool may_list(ivec2 tile) {
    vec2 own = texelFetch(u_tile_extremes, tile, 0).rg;
    if (!(own.g < 3e38)) {
        return false;  // no surface
    }
    vec2 window = texelFetch(u_tiles, tile, 0).rg;
    if (!(window.r - own.g > u_edge_jump || own.r - window.g > u_edge_jump)) {
        return false;
    }
    float radius_px = u_particle_radius * u_focal_px / own.g;
    int limit = clamp(int(round(u_reach_radii * radius_px)), 1, FIELD_MAX_REACH) + 1;
    float footprint_jump = u_edge_jump_px * own.g / u_focal_px;
    ivec2 last = textureSize(u_tile_extremes, 0) - 1;
    for (int dy = -2; dy <= 2; ++dy) {
        for (int dx = -2; dx <= 2; ++dx) {
            ivec2 other = tile + ivec2(dx, dy);
            int dm = max(max(4 * abs(dx) - 3, 0) + max(4 * abs(dy) - 3, 0), 1);
            if (dm <= limit && all(greaterThanEqual(other, ivec2(0))) && all(lessThanEqual(other, last))) {
                float jump = max(u_edge_jump, footprint_jump * float(dm));
                vec2 e = texelFetch(u_tile_extremes, other, 0).rg;
                if (e.r - own.g > jump || own.r - e.g > jump) {
                    return true;
                }
            }
        }
    }
    return false;
}

void main() {
    uint i = gl_WorkGroupID.y * u_groups_x * uint(FIELD_LIST_GROUP) + gl_GlobalInvocationID.x;
    if (u_phase == 0) {
        if (i >= uint(u_tile_box.z * u_tile_box.w)) {
            return;
        }
        ivec2 tile = u_tile_box.xy + ivec2(int(i) % u_tile_box.z, int(i) / u_tile_box.z);
        if (may_list(tile)) {
            tile_list[atomicAdd(tile_count, 1u)] = uint(tile.x) | (uint(tile.y) << 16);
        }
        return;
    }
    if (u_phase == 1) {
        uint needed = (tile_count * 16u + uint(FIELD_LIST_GROUP) - 1u) / uint(FIELD_LIST_GROUP);
        uint x = min(needed, u_groups_x);
        tiles_x = x;
        tiles_y = x > 0u ? (needed + x - 1u) / x : 0u;
        tiles_z = 1u;
        return;
    }
    uint k = i / 16u;
    if (k >= tile_count) {
        return;
    }
    uint entry = tile_list[k];
    ivec2 p = ivec2(entry & 0xffffu, entry >> 16) * 4 + ivec2(int(i & 3u), int((i >> 2) & 3u));
    if (any(lessThan(p, u_box.xy)) || any(greaterThanEqual(p, u_box.xy + u_box.zw))) {
        return;
    }
    float zc = texelFetch(u_depth, p, 0).r;
    if (zc > 0.0) {
        list_rim(p, textureSize(u_depth, 0), zc);
    }
}
