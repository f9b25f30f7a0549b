/* Which particles' kernel density (thesis eq 2, sph.cl's kernel and support h, self included)
 * is below a limit: the same answer as `density(...) < limit`, without the counting sort and
 * without summing whole neighbourhoods. What asks it: the droplet split on frames without
 * usable densities (a droplet is below quality.droplet_density, 0.45 rest) and the lone rule
 * on frames with them (quality.droplet_lone_density, 0.36: a simulator's densities may count
 * walls the frame does not hold).
 * Inside a fluid the first neighbour or two lift a particle's sum past such a limit (a lone
 * particle's sum is W(0) alone: 0.32 rest density at the default h = 4 r, a touching pair's
 * 0.40, the fluid's ~1), so its walk stops there: two passes over the particles and a cleared
 * count per bucket, where `density` pays the sort and every neighbourhood in full.
 *
 * Layout: positions are float32 xyz relative to the frame's minimum (the host keeps frames
 * whose extent is over BELOW_MAX_CELLS h on the exact path, so the float32 offsets stay within
 * 2^-8 h of the float64 ones). A cell of side h is hashed (sph.cl's hash) into a power-of-two
 * table of `mask + 1` buckets; each bucket holds a count and up to BELOW_SLOTS particle
 * indices (the order atomics hand out, so the order of a sum varies from run to run; the
 * answer does not, except for a sum within rounding of the limit: every term is >= 0).
 *
 * A bucket can hold particles of several cells (hash collisions): a reader visits each bucket
 * of its 27 cells once and tests every particle listed there by distance. Particles past a
 * bucket's BELOW_SLOTS go to one overflow list of indices, up to `overflow_cap`; a particle
 * still below the limit after its buckets' lists, one of which overflowed, scans that list.
 * Only when the list itself was full is such a particle written BELOW_UNDECIDED (the host
 * then answers the frame with the exact density pass). At the default h a fluid's cell holds ~8 particles and a bucket ~1.1 cells;
 * three full cells in one bucket are rare but certain in a large frame.
 */

#include "sph.cl"

#ifndef BELOW_SLOTS
#define BELOW_SLOTS 32
#endif
#define BELOW_NOT 0
#define BELOW_YES 1
#define BELOW_UNDECIDED 2

inline int4 below_cell(float3 p, float inv_h)
{
    return (int4)(convert_int3_rtn(p * inv_h), 0);
}

/* counts and overflow_count must be zero. */
__kernel void below_insert(__global const float *positions, const uint n, const float inv_h,
                           const uint mask, __global uint *counts, __global uint *slots,
                           const uint overflow_cap, __global uint *overflow_count,
                           __global uint *overflow)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const int4 c = below_cell(vload3(i, positions), inv_h);
    const uint b = hashed_bucket(c.x, c.y, c.z, mask);
    const uint s = atomic_inc(&counts[b]);
    if (s < BELOW_SLOTS) {
        slots[b * BELOW_SLOTS + s] = i;
        return;
    }
    const uint k = atomic_inc(overflow_count);
    if (k < overflow_cap)
        overflow[k] = i;
}

/* Adds W(|x_j - x_i| / h) of a candidate j to *sum when j is another particle within h. */
inline void below_add(__global const float *positions, uint i, uint j, float3 p, float h,
                      float inv_h, float *sum)
{
    const float3 d = vload3(j, positions) - p;
    const float r2 = dot(d, d);
    if (r2 < h * h && j != i)
        *sum += spline_w(sqrt(r2) * inv_h);
}

/* Adds the weights of bucket b's listed particles to *sum, until it reaches `limit`; returns
 * whether the bucket has more than it lists (the rest are on the overflow list). Every
 * particle listed is tested, whatever its cell: one from another cell that shares the bucket
 * is either within h (and belongs to the sum: the caller visits each bucket once) or not. */
inline bool below_add_bucket(__global const float *positions, __global const uint *counts,
                             __global const uint *slots, uint i, float3 p, uint b, float h,
                             float inv_h, float limit, float *sum)
{
    const uint count = counts[b];
    const uint listed = min(count, (uint)BELOW_SLOTS);
    for (uint s = 0; s < listed && *sum < limit; ++s)
        below_add(positions, i, slots[b * BELOW_SLOTS + s], p, h, inv_h, sum);
    return count > BELOW_SLOTS;
}

/* out[i] = BELOW_YES when sum_j W(|x_i - x_j| / h) (unnormalised spline, self included) <
 * limit, BELOW_NOT when it is not, BELOW_UNDECIDED when the overflow list was too short to
 * tell. The own cell first (where a fluid particle's nearest neighbours usually are), then the
 * others whose nearest point is closer than h, each bucket once (two cells of the 27 can
 * share one); then, if one of them overflowed, the overflow list: it holds no listed particle,
 * so each of its entries within h is a neighbour not yet counted, whichever bucket it left. */
__kernel void below_classify(__global const float *positions, const uint n, const float h,
                             const float inv_h, const uint mask, const float limit,
                             __global const uint *counts, __global const uint *slots,
                             const uint overflow_cap, __global const uint *overflow_count,
                             __global const uint *overflow, __global uchar *out)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const float3 p = vload3(i, positions);
    const int4 ci = below_cell(p, inv_h);
    const float3 o = p - convert_float3(ci.xyz) * h; /* offset inside the cell, ~[0, h) */
    uint seen[27];
    uint visited = 1;
    bool full = false;
    float sum = 1.0f; /* W(0): the particle itself */
    seen[0] = hashed_bucket(ci.x, ci.y, ci.z, mask);
    full |= below_add_bucket(positions, counts, slots, i, p, seen[0], h, inv_h, limit, &sum);
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
                full |= below_add_bucket(positions, counts, slots, i, p, b, h, inv_h, limit, &sum);
            }
        }
    }
    if (sum < limit && full) {
        const uint total = *overflow_count;
        if (total > overflow_cap) {
            out[i] = BELOW_UNDECIDED;
            return;
        }
        for (uint e = 0; e < total && sum < limit; ++e)
            below_add(positions, i, overflow[e], p, h, inv_h, &sum);
    }
    out[i] = sum >= limit ? BELOW_NOT : BELOW_YES;
}
