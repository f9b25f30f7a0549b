#version 430 core
// The field gradient by tiles (benchmarks/bench_field_gradient.py): a work group of TILE x TILE
// pixels takes the cells around all its needing points (their cells' bounding box grown by
// m = FIELD_CELLS_PER_SUPPORT), loads their centres into shared memory TILE^2 at a time, and
// every invocation sums over each batch (the same address in every invocation: a broadcast,
// no gather). The usual GPU remedy for a gather per invocation, more terms per point in
// exchange (boxes of more than MAX_TILE_CELLS cells: field_gradient per invocation). The same
// terms as field_gradient in another order (centres outside h add nothing).

#define TILE 8
// A box of more cells (needing points far apart in depth: a droplet before the pool) falls
// back to field_gradient per invocation.
#define MAX_TILE_CELLS 216

layout(local_size_x = TILE, local_size_y = TILE) in;

#include "studies/field_gradient_io.glsl"

shared int s_low[3];
shared int s_high[3];
shared int s_needed;
shared vec3 s_centres[TILE * TILE];

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    uint lane = gl_LocalInvocationIndex;
    if (lane == 0u) {
        s_low[0] = s_low[1] = s_low[2] = 0x7fffffff;
        s_high[0] = s_high[1] = s_high[2] = -0x7fffffff;
        s_needed = 0;
    }
    barrier();
    bool inside = all(lessThan(p, imageSize(u_points)));
    vec4 point = inside ? imageLoad(u_points, p) : vec4(0.0);
    bool needed = point.w != 0.0;
    if (needed) {
        ivec3 c = grid_cell(point.xyz);
        atomicMin(s_low[0], c.x);
        atomicMin(s_low[1], c.y);
        atomicMin(s_low[2], c.z);
        atomicMax(s_high[0], c.x);
        atomicMax(s_high[1], c.y);
        atomicMax(s_high[2], c.z);
        s_needed = 1;
    }
    barrier();
    if (s_needed == 0) {
        if (inside) {
            imageStore(u_gradient, p, vec4(0.0));
        }
        return;
    }
    ivec3 low = ivec3(s_low[0], s_low[1], s_low[2]) - FIELD_CELLS_PER_SUPPORT;
    ivec3 high = ivec3(s_high[0], s_high[1], s_high[2]) + FIELD_CELLS_PER_SUPPORT;
    ivec3 cells = high - low + 1;
    if (cells.x * cells.y * cells.z > MAX_TILE_CELLS) {
        if (inside) {
            imageStore(u_gradient, p, needed ? field_gradient(point.xyz) : vec4(0.0));
        }
        return;
    }
    float h = u_support;
    vec3 outward = vec3(0.0);
    float scale = 0.0;
    for (int z = low.z; z <= high.z; ++z) {
        for (int y = low.y; y <= high.y; ++y) {
            // The row's cells low.x .. high.x are one run of buckets (common/field_grid.glsl);
            // a centre counts only in its own cell's row (runs of the box's rows may overlap).
            uint first = grid_bucket(ivec3(low.x, y, z));
            uint count = uint(high.x - low.x + 1);
            for (uint b = 0u; b < count; ++b) {
                uint bucket = (first + b) & u_bucket_mask;
                uint end = starts[bucket + 1u];
                for (uint run = starts[bucket]; run < end; run += uint(TILE * TILE)) {
                    uint j = run + lane;
                    vec3 c = vec3(3e38);  // not this box's: beyond every support
                    if (j < end) {
                        vec3 centre = sorted_centres[j].xyz;
                        ivec3 own = grid_cell(centre);
                        if (own.y == y && own.z == z && own.x >= low.x && own.x <= high.x) {
                            c = centre;
                        }
                    }
                    s_centres[lane] = c;
                    barrier();
                    uint batch = min(uint(TILE * TILE), end - run);
                    for (uint k = 0u; k < batch; ++k) {
                        vec3 d = point.xyz - s_centres[k];
                        float q = length(d) / h;
                        if (q < 1.0) {
                            vec3 term = -spline_dw_over_q(q) * d;
                            outward += term;
                            scale += length(term);
                        }
                    }
                    barrier();
                }
            }
        }
    }
    if (inside) {
        imageStore(u_gradient, p, needed ? vec4(outward, scale) : vec4(0.0));
    }
}
