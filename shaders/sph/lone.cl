/* Lone particles (quality.droplet_lone_density): which particles' kernel density (thesis eq 2,
 * sph.cl's kernel and support h, self included) is below a limit. The same answer as
 * `density(...) < limit`, without the counting sort and without summing whole neighbourhoods:
 * inside a fluid the first neighbour or two lift a particle's sum past the limit (a lone
 * particle's sum is W(0) alone: 0.32 rest density at the default h = 4 r, a touching pair's
 * 0.40), so its walk stops there. What it costs is two passes over the particles and a
 * cleared count per bucket, where `density` pays the sort and every neighbourhood in full.
 *
 * Layout: positions are float32 xyz relative to the frame's minimum (the host keeps frames
 * whose extent is over LONE_MAX_CELLS h on the exact path, so the float32 offsets stay within
 * 2^-8 h of the float64 ones). A cell of side h is hashed (sph.cl's hash) into a power-of-two
 * table of `mask + 1` buckets; each bucket holds a count and up to LONE_SLOTS particle indices
 * (the order atomics hand out, so the order of a sum varies from run to run; the answer does
 * not, except for a sum within rounding of the limit: every term is >= 0).
 *
 * A bucket can hold particles of several cells (hash collisions): a reader visits each bucket
 * of its 27 cells once and tests every particle listed there by distance. A bucket with more
 * than LONE_SLOTS particles lost some of them: a particle whose sum is still below the limit
 * after every listed neighbour, and that saw such a bucket, is written LONE_UNDECIDED (the
 * host answers the frame with the exact density pass instead). At the default h a fluid's
 * cell holds ~8 particles and a bucket ~1.1 cells.
 */

#include "sph.cl"

#ifndef LONE_SLOTS
#define LONE_SLOTS 32
#endif
#define LONE_NOT 0
#define LONE_YES 1
#define LONE_UNDECIDED 2

inline int4 lone_cell(float3 p, float inv_h)
{
    return (int4)(convert_int3_rtn(p * inv_h), 0);
}

/* counts must be zero. */
__kernel void lone_insert(__global const float *positions, const uint n, const float inv_h,
                          const uint mask, __global uint *counts, __global uint *slots)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const int4 c = lone_cell(vload3(i, positions), inv_h);
    const uint b = hashed_bucket(c.x, c.y, c.z, mask);
    const uint s = atomic_inc(&counts[b]);
    if (s < LONE_SLOTS)
        slots[b * LONE_SLOTS + s] = i;
}

/* Adds the kernel weights of bucket b's particles within h of particle i to *sum, until it
 * reaches `limit`; returns whether the bucket lost particles (more than LONE_SLOTS). Every
 * particle listed is tested, whatever its cell: one from another cell that shares the bucket
 * is either within h (and belongs to the sum: the caller visits each bucket once) or not. */
inline bool lone_add_bucket(__global const float *positions, __global const uint *counts,
                            __global const uint *slots, uint i, float3 p, uint b, float h,
                            float inv_h, float limit, float *sum)
{
    const uint count = counts[b];
    const uint listed = min(count, (uint)LONE_SLOTS);
    for (uint s = 0; s < listed && *sum < limit; ++s) {
        const uint j = slots[b * LONE_SLOTS + s];
        const float3 d = vload3(j, positions) - p;
        const float r2 = dot(d, d);
        if (r2 < h * h && j != i)
            *sum += spline_w(sqrt(r2) * inv_h);
    }
    return count > LONE_SLOTS;
}

/* lone[i] = LONE_YES when sum_j W(|x_i - x_j| / h) (unnormalised spline, self included) <
 * limit, LONE_NOT when it is not, LONE_UNDECIDED when a bucket lost particles first. The
 * own cell first (where a fluid particle's nearest neighbours usually are), then the others
 * whose nearest point is closer than h, each bucket once (two cells of the 27 can share one). */
__kernel void lone_classify(__global const float *positions, const uint n, const float h,
                            const float inv_h, const uint mask, const float limit,
                            __global const uint *counts, __global const uint *slots,
                            __global uchar *lone)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const float3 p = vload3(i, positions);
    const int4 ci = lone_cell(p, inv_h);
    const float3 o = p - convert_float3(ci.xyz) * h; /* offset inside the cell, ~[0, h) */
    uint seen[27];
    uint visited = 0;
    float sum = 1.0f; /* W(0): the particle itself */
    seen[visited++] = hashed_bucket(ci.x, ci.y, ci.z, mask);
    bool lost = lone_add_bucket(positions, counts, slots, i, p, seen[0], h, inv_h, limit, &sum);
    for (int dz = -1; dz <= 1 && sum < limit; ++dz) {
        const float gz = gap_to_cell(dz, o.z, h);
        for (int dy = -1; dy <= 1 && sum < limit; ++dy) {
            const float gy = gap_to_cell(dy, o.y, h);
            for (int dx = -1; dx <= 1 && sum < limit; ++dx) {
                const float gx = gap_to_cell(dx, o.x, h);
                if (gx * gx + gy * gy + gz * gz >= h * h)
                    continue;
                const uint b = hashed_bucket(ci.x + dx, ci.y + dy, ci.z + dz, mask);
                bool again = false;
                for (uint k = 0; k < visited; ++k)
                    again |= seen[k] == b;
                if (again)
                    continue; /* the own cell, or a cell sharing a visited bucket */
                seen[visited++] = b;
                lost |= lone_add_bucket(positions, counts, slots, i, p, b, h, inv_h, limit, &sum);
            }
        }
    }
    lone[i] = sum >= limit ? LONE_NOT : (lost ? LONE_UNDECIDED : LONE_YES);
}
