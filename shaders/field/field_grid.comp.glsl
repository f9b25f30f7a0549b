#version 430 core
// Field grid build (passes/field_grid.py; layout in common/field_grid.glsl): a counting sort of
// the particle centres into hashed buckets (zeroed by the host's buffer clear), one dispatch
// per phase (u_phase):
//   1  count: for each source particle with a radius (w != 0; the device prepare writes 0 for
//      culled ones), its rank in its bucket by atomicAdd; ranks[i] = rank, or NO_RANK;
//   2  chunk sums: sums[c] = the counts of buckets [c * u_chunk, (c + 1) * u_chunk);
//   3  one invocation: sums become their exclusive prefix sum;
//   4  chunk scan: buckets[b] becomes the exclusive prefix sum of the counts (in place, each
//      chunk serially from its sum), buckets[u_buckets] = the total;
//   5  scatter: sorted[buckets[bucket(i)] + ranks[i]] = source particle i (centre, radius).
// Phases 1 and 5 compute a particle's bucket with the same code of the same shader, so they
// agree bit for bit.

layout(local_size_x = 256) in;

#include "common/field_grid.glsl"

const uint NO_RANK = 0xffffffffu;

layout(std430, binding = 12) readonly buffer Source { vec4 source[]; };
layout(std430, binding = 13) buffer Ranks { uint ranks[]; };
layout(std430, binding = 14) buffer Buckets { uint buckets[]; };
layout(std430, binding = 15) buffer Sums { uint sums[]; };
layout(std430, binding = 16) writeonly buffer Sorted { vec4 sorted_centres[]; };

uniform int u_phase;
uniform uint u_first;    // first item of this dispatch (dispatches are split at 65535 groups)
uniform uint u_count;    // items of the phase: particles, buckets or chunks
uniform uint u_buckets;  // table size
uniform uint u_chunk;    // buckets per chunk (phases 2 and 4)

void main() {
    uint i = u_first + gl_GlobalInvocationID.x;
    if (u_phase == 3) {
        if (i == 0u) {
            uint total = 0u;
            for (uint c = 0u; c < u_count; ++c) {
                uint s = sums[c];
                sums[c] = total;
                total += s;
            }
        }
        return;
    }
    if (i >= u_count) {
        return;
    }
    if (u_phase == 1) {
        vec4 s = source[i];
        ranks[i] = s.w != 0.0 ? atomicAdd(buckets[grid_bucket(grid_cell(s.xyz))], 1u) : NO_RANK;
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
    } else if (u_phase == 5) {
        uint rank = ranks[i];
        if (rank != NO_RANK) {
            vec4 s = source[i];
            sorted_centres[buckets[grid_bucket(grid_cell(s.xyz))] + rank] = s;
        }
    }
}
