#version 430 core
// Field grid build (passes/field_grid.py; layout in common/field_grid.glsl): a counting sort of
// the particle centres into hashed buckets (zeroed by the host's buffer clear), one dispatch
// per phase (u_phase):
//   0  rim blocks (u_cull): bit 1 of each block where one within +-RIM_REACH has bit 0;
//   1  count: for each source particle with a radius (w != 0; the device prepare writes 0 for
//      culled ones) whose support can reach a rim block (u_cull; common/rim_blocks.glsl), its
//      rank in its bucket by atomicAdd, appended with its index to `kept` (atomicAdd on
//      kept_count);
//   2  chunk sums: sums[c] = the counts of buckets [c * u_chunk, (c + 1) * u_chunk);
//   3  one invocation: sums become their exclusive prefix sum, and kept_count the work groups
//      of phase 5's indirect dispatch (x at most u_groups_x, then rows);
//   4  chunk scan: buckets[b] becomes the exclusive prefix sum of the counts (in place, each
//      chunk serially from its sum), buckets[u_buckets] = the total;
//   5  scatter, one invocation per kept particle (i, rank), an indirect dispatch over the
//      kept list: order[buckets[bucket(i)] + rank] = i. Over the kept particles, not every
//      source particle: on the 100k ball at 1280x720 24k of 102k are kept, the build 5.1 ->
//      4.5 ms on llvmpipe (the scatter 1.9 -> ~0.3, the count 1.8 -> 2.2);
//   6  the same dispatch again: each kept particle's place in its bucket by source index, the
//      count of the bucket's indices (phase 5 wrote them, `order`) below its own, and there
//      its centre: sorted[buckets[bucket(i)] + that count]. The ranks of phase 1 come in the
//      order the atomics ran, so without it a reader's sums, and the normals, would change in
//      their last bits from run to run (the service's frames must not; one invocation per
//      bucket sorting its run cost 2.6 ms on llvmpipe, this ~0.3).
//   7  cap, one invocation per bucket: raw[b] = its count, buckets[b] = min(count, FIELD_SLOTS);
//      phases 2-4 then scan both (the host swaps bindings 14 and 24), so a reader's runs hold
//      at most FIELD_SLOTS entries per bucket whatever the geometry;
//   8  crowd, one invocation per bucket of more than FIELD_SLOTS centres (coincident or
//      clustered particles): its centres merged per sub-cell of side h / 8 (64 per cell) into
//      the lowest-index one, weighted by how many of that cell it stands for (sorted .w; 1 for
//      uncrowded centres, 0 for an unused slot). Centres of another cell that share a crowded
//      bucket and a sub-cell index with a representative are left out.
// Phases 1, 5, 6 and 8 compute a particle's bucket with the same code of the same shader, so
// they agree bit for bit.

layout(local_size_x = 256) in;

#include "common/field_grid.glsl"
#include "common/rim_blocks.glsl"

layout(std430, binding = 12) readonly buffer Source { vec4 source[]; };
layout(std430, binding = 13) buffer Kept { uvec2 kept[]; };  // (source index, rank)
layout(std430, binding = 14) buffer Buckets { uint buckets[]; };
layout(std430, binding = 15) buffer Sums { uint sums[]; };
layout(std430, binding = 16) writeonly buffer Sorted { vec4 sorted_centres[]; };
layout(std430, binding = 23) buffer Order { uint order[]; };  // source indices, per bucket
layout(std430, binding = 24) buffer Raw { uint raw[]; };  // uncapped counts, then starts
layout(std430, binding = 20) buffer KeptCount { uint kept_count; uint groups_x; uint groups_y; uint groups_z; };

uniform int u_phase;
uniform uint u_first;    // first item of this dispatch (dispatches are split at 65535 groups)
uniform uint u_count;    // items of the phase: particles, buckets or chunks
uniform uint u_buckets;  // table size
uniform uint u_chunk;    // buckets per chunk (phases 2 and 4)
uniform bool u_cull;     // phase 1: only the particles near a flagged rim block
uniform vec2 u_tan_half_fov;  // (tan(fov_y / 2) * aspect, tan(fov_y / 2)), for the blocks
uniform ivec2 u_image;        // the image's size in pixels
uniform uint u_groups_x;      // phase 5: work groups per row of its dispatch

// The pixels whose centre rays can pass within u_support of c, along one axis (the tangent
// lines of the circle of radius r at (lateral, depth), common/sphere_bounds.glsl's formula in
// float), widened by two pixels for float rounding; `depth` > 1.01 r.
ivec2 reach_interval(float lateral, float depth, float r, float tan_half, int size) {
    float d2_r2 = (depth - r) * (depth + r);
    float spread = r * sqrt(lateral * lateral + d2_r2);
    float scale = 0.5 * float(size) / tan_half;
    float centre = 0.5 * float(size);
    float lo = clamp((lateral * depth - spread) / d2_r2 * scale + centre, -1.0, float(size));
    float hi = clamp((lateral * depth + spread) / d2_r2 * scale + centre, -1.0, float(size));
    return ivec2(int(floor(lo)) - 2, int(ceil(hi)) + 2);
}

// Whether the support sphere of the view-space centre c can reach a listed pixel: a listed
// block inside its screen rectangle (conservative: kept when near or behind the eye plane).
// A rectangle of at most 2 RIM_REACH + 1 blocks per axis lies within RIM_REACH of its middle
// block, whose bit 1 answers at once; a larger one (a near particle) looks at every block.
bool near_a_rim(vec3 c) {
    float r = u_support;
    float depth = -c.z;
    if (!(depth > 1.01 * r)) {
        return true;
    }
    ivec2 x = reach_interval(c.x, depth, r, u_tan_half_fov.x, u_image.x);
    ivec2 y = reach_interval(c.y, depth, r, u_tan_half_fov.y, u_image.y);
    if (x.y < 0 || y.y < 0 || x.x >= u_image.x || y.x >= u_image.y) {
        return false;  // off the image: no listed pixel there
    }
    ivec2 low = clamp(ivec2(x.x, y.x), ivec2(0), u_image - 1) / RIM_BLOCK;
    ivec2 high = clamp(ivec2(x.y, y.y), ivec2(0), u_image - 1) / RIM_BLOCK;
    if (all(lessThanEqual(high - low, ivec2(2 * RIM_REACH)))) {
        ivec2 middle = (low + high) / 2;
        return (rim_blocks[middle.y * u_rim_blocks.x + middle.x] & 2u) != 0u;
    }
    for (int by = low.y; by <= high.y; ++by) {
        for (int bx = low.x; bx <= high.x; ++bx) {
            if ((rim_blocks[by * u_rim_blocks.x + bx] & 1u) != 0u) {
                return true;
            }
        }
    }
    return false;
}

// The sub-cell (0 .. 63) of a centre inside its cell, FIELD_SLOT_SIDE sub-cells per axis.
uint sub_cell(vec3 p, ivec3 cell) {
    float side = grid_cell_side();
    vec3 local = (p - vec3(cell) * side) / side * float(FIELD_SLOT_SIDE);
    uvec3 s = uvec3(clamp(ivec3(floor(local)), ivec3(0), ivec3(FIELD_SLOT_SIDE - 1)));
    return s.x + FIELD_SLOT_SIDE * (s.y + FIELD_SLOT_SIDE * s.z);
}

// Phase 8: bucket b's centres (order[raw[b] .. raw[b + 1]]) as FIELD_SLOTS weighted slots.
void merge_crowd(uint b) {
    uint first = raw[b];
    uint end = raw[b + 1u];
    if (end - first <= FIELD_SLOTS) {
        return;
    }
    uint rep[FIELD_SLOTS];
    uint weight[FIELD_SLOTS];
    for (uint k = 0u; k < FIELD_SLOTS; ++k) {
        rep[k] = 0xffffffffu;
        weight[k] = 0u;
    }
    for (uint j = first; j < end; ++j) {
        uint index = order[j];
        vec3 p = source[index].xyz;
        uint slot = sub_cell(p, grid_cell(p));
        rep[slot] = min(rep[slot], index);
    }
    for (uint j = first; j < end; ++j) {
        vec3 p = source[order[j]].xyz;
        ivec3 cell = grid_cell(p);
        uint slot = sub_cell(p, cell);
        weight[slot] += all(equal(cell, grid_cell(source[rep[slot]].xyz))) ? 1u : 0u;
    }
    uint out_first = buckets[b];
    for (uint k = 0u; k < FIELD_SLOTS; ++k) {
        vec4 slot = vec4(3.0e38, 3.0e38, 3.0e38, 0.0);  // unused: beyond every support
        if (weight[k] > 0u) {
            slot = vec4(source[rep[k]].xyz, float(weight[k]));
        }
        sorted_centres[out_first + k] = slot;
    }
}

void main() {
    uint i = u_first + gl_GlobalInvocationID.x;
    if (u_phase == 0) {
        ivec2 blocks = u_rim_blocks;
        if (i >= uint(blocks.x * blocks.y)) {
            return;
        }
        ivec2 b = ivec2(int(i) % blocks.x, int(i) / blocks.x);
        ivec2 low = max(b - RIM_REACH, ivec2(0));
        ivec2 high = min(b + RIM_REACH, blocks - 1);
        bool near = false;
        for (int by = low.y; by <= high.y; ++by) {
            for (int bx = low.x; bx <= high.x; ++bx) {
                near = near || (rim_blocks[by * blocks.x + bx] & 1u) != 0u;
            }
        }
        rim_blocks[i] = (rim_blocks[i] & 1u) | (near ? 2u : 0u);  // bit 0 unchanged
        return;
    }
    if (u_phase == 3) {
        if (i == 0u) {
            uint total = 0u;
            for (uint c = 0u; c < u_count; ++c) {
                uint s = sums[c];
                sums[c] = total;
                total += s;
            }
            uint needed = (kept_count + gl_WorkGroupSize.x - 1u) / gl_WorkGroupSize.x;
            uint x = min(needed, u_groups_x);
            groups_x = x;
            groups_y = x > 0u ? (needed + x - 1u) / x : 0u;
            groups_z = 1u;
        }
        return;
    }
    if (u_phase == 5 || u_phase == 6) {
        uint k = gl_WorkGroupID.y * u_groups_x * gl_WorkGroupSize.x + gl_GlobalInvocationID.x;
        if (k < kept_count) {
            uvec2 entry = kept[k];
            vec4 s = source[entry.x];
            uint bucket = grid_bucket(grid_cell(s.xyz));
            uint first = raw[bucket];
            uint end = raw[bucket + 1u];
            if (u_phase == 5) {
                order[first + entry.y] = entry.x;
            } else if (end - first <= FIELD_SLOTS) {  // crowded buckets: phase 8
                uint below = 0u;
                for (uint j = first; j < end; ++j) {
                    below += order[j] < entry.x ? 1u : 0u;
                }
                sorted_centres[buckets[bucket] + below] = vec4(s.xyz, 1.0);
            }
        }
        return;
    }
    if (i >= u_count) {
        return;
    }
    if (u_phase == 1) {
        vec4 s = source[i];
        if (s.w != 0.0 && (!u_cull || near_a_rim(s.xyz))) {
            uint rank = atomicAdd(buckets[grid_bucket(grid_cell(s.xyz))], 1u);
            kept[atomicAdd(kept_count, 1u)] = uvec2(i, rank);
        }
    } else if (u_phase == 2) {
        uint first = i * u_chunk;
        uint last = min(first + u_chunk, u_buckets);
        uint total = 0u;
        for (uint b = first; b < last; ++b) {
            total += buckets[b];
        }
        sums[i] = total;
    } else if (u_phase == 4) {
        uint first = i * u_chunk;
        uint last = min(first + u_chunk, u_buckets);
        uint running = sums[i];
        for (uint b = first; b < last; ++b) {
            uint count = buckets[b];
            buckets[b] = running;
            running += count;
        }
        if (last == u_buckets) {
            buckets[u_buckets] = running;
        }
    } else if (u_phase == 7) {
        uint count = buckets[i];
        raw[i] = count;
        buckets[i] = min(count, FIELD_SLOTS);
    } else if (u_phase == 8) {
        merge_crowd(i);
    }
}
