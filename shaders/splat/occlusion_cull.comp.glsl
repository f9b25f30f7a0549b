#version 430 core
// Device occlusion culling (passes/device_culling.py): geometry/occlusion.py's two-phase culling,
// per particle on the GPU, over the spheres the device prepare wrote. Three phases, one
// dispatch each (u_phase):
//   0  tile minima: the nearest eye depth per screen tile (tile = the rectangle's centre, as
//      occlusion.front_layer keys it), atomicMin on the float bits (non-negative floats order
//      as their bits);
//   1  front layer: FRONT for particles within u_band radii of their tile's nearest, and for
//      those without a rectangle; the splat draws them first;
//   2  after the front layer's depth became the max-depth pyramid (depth_pyramid.comp.glsl):
//      SECOND for the others that the front layer does not hide (nearest depth not behind the
//      largest depth over their rectangle), and with anti-aliasing COVER for the drawn ones
//      whose rectangle grown by the coverage need the front layer does not cover all over
//      (why that is all the coverage the shade pass reads: passes/splat.py COVERAGE_NEED_PX).
// The pyramid's blocks are aligned (not occlusion.DepthMaxTable's sparse table), so a rectangle
// is tested against the blocks that hold it (`largest_depth`): a superset of its pixels, which
// keeps the culling exact (it culls a little less).

layout(local_size_x = 256) in;

#include "common/sphere_bounds.glsl"

const uint FRONT = 1u;
const uint SECOND = 2u;
const uint COVER = 4u;

layout(std430, binding = 0) readonly buffer SplatSpheres { vec4 spheres[]; };
layout(std430, binding = 8) buffer Flags { uint flags[]; };
layout(std430, binding = 9) buffer Tiles { uint tiles[]; };
layout(std430, binding = 10) readonly buffer Pyramid { float pyramid[]; };
layout(std430, binding = 11) buffer Counts { uint drawn_front; uint drawn_second; } counts;

uniform int u_phase;
uniform uint u_first;
uniform uint u_count;
uniform dvec2 u_tan_half_fov;
uniform ivec2 u_size;          // image width, height
uniform float u_tile;          // tile side in pixels
uniform int u_tiles_x;         // tiles per row (int(width / tile) + 2, as on the CPU)
uniform float u_band;          // FRONT_BAND_RADII
uniform bool u_antialias;
uniform int u_coverage_need;   // COVERAGE_NEED_PX
uniform ivec4 u_box;           // x, y, width, height of the pyramid's level 0 (window pixels)
uniform int u_levels;          // levels in the pyramid
uniform int u_offsets[8];      // where each level starts in `pyramid`
uniform ivec2 u_dims[8];       // each level's width, height

float nearest_depth(vec4 sphere) {
    return float(-double(sphere.z) - double(abs(sphere.w)));
}

int tile_key(ivec4 rect) {
    vec2 centre = clamp(vec2(rect.xy + rect.zw) * 0.5, vec2(0.0), vec2(u_size));
    ivec2 t = ivec2(floor(centre / u_tile));
    return t.y * u_tiles_x + t.x;
}

// The largest front-layer depth over `rect` (+inf where no surface), or -1 when the rectangle
// leaves the pyramid or is longer than its last level's blocks (counted as visible). Tested at
// the level two below the first whose block holds the rectangle's longer side: at most 5 x 5
// blocks, a superset of the rectangle at most a block wider on each side (a quarter of it).
float largest_depth(ivec4 rect) {
    ivec4 r = rect - ivec4(u_box.xy, u_box.xy);
    if (r.x < 0 || r.y < 0 || r.z >= u_box.z || r.w >= u_box.w || r.z < r.x || r.w < r.y) {
        return -1.0;
    }
    int side = max(r.z - r.x, r.w - r.y) + 1;
    int fits = 0;
    while ((1 << fits) < side) {
        ++fits;
    }
    if (fits >= u_levels) {
        return -1.0;
    }
    int level = max(fits - 2, 0);
    ivec4 b = r >> level;
    int width = u_dims[level].x;
    int base = u_offsets[level];
    float largest = 0.0;
    for (int y = b.y; y <= b.w; ++y) {
        for (int x = b.x; x <= b.z; ++x) {
            largest = max(largest, pyramid[base + y * width + x]);
        }
    }
    return largest;
}

bool covered(ivec4 rect, int grow) {
    float largest = largest_depth(rect + ivec4(-grow, -grow, grow, grow));
    return largest >= 0.0 && !isinf(largest);
}

void main() {
    uint i = u_first + gl_GlobalInvocationID.x;
    if (i >= u_count) return;
    vec4 sphere = spheres[i];
    if (!(sphere.w > 0.0)) {  // culled, or an exact droplet (drawn later, never culled)
        if (u_phase == 1) flags[i] = 0u;
        return;
    }
    ivec4 rect;
    bool bounded = sphere_rectangle(sphere, u_tan_half_fov, u_size, rect);
    float near = nearest_depth(sphere);
    if (u_phase == 0) {
        if (bounded) atomicMin(tiles[tile_key(rect)], floatBitsToUint(max(near, 0.0)));
        return;
    }
    if (u_phase == 1) {
        bool front = !bounded
            || near <= uintBitsToFloat(tiles[tile_key(rect)]) + u_band * sphere.w;
        flags[i] = front ? FRONT : 0u;
        if (front) atomicAdd(counts.drawn_front, 1u);
        return;
    }
    uint flag = flags[i];
    bool drawn = (flag & FRONT) != 0u;
    if (!drawn) {
        float largest = bounded ? largest_depth(rect) : -1.0;
        bool hidden = largest >= 0.0 && near > largest;
        if (!hidden) {
            flag |= SECOND;
            drawn = true;
            atomicAdd(counts.drawn_second, 1u);
        }
    }
    if (drawn && u_antialias && !(bounded && covered(rect, u_coverage_need))) {
        flag |= COVER;
    }
    flags[i] = flag;
}
