/* SPH on a uniform grid: neighbour search (counting sort by cell + prefix sum, Green 2010),
 * density (thesis eq 2 with A = rho), colour field (eq 26), its gradient (eq 27), surface flags
 * (eq 28, corrected to |n| > t) and the dilated splat mask for surface-only splatting.
 *
 * Positions arrive split into an integer cell (int4, w unused) and a float32 offset inside that
 * cell (float4, xyz in [0, h); w: how many particles it stands for, 1 unless the host merged a
 * crowded cell, server/engine/sph/crowd.py; sums weigh each neighbour by it); the host computes both in float64 from positions relative to the
 * frame's minimum. The vector between two particles is (cell_j - cell_i) * h + (local_j -
 * local_i): the cell difference is a small exact integer, so float32 keeps full relative
 * precision however large the coordinates or the domain are.
 *
 * Grid modes (uniform for one frame, chosen by the host):
 *   dense  (nx > 0): bucket = x + nx * (y + ny * z); one bucket per cell, so the three cells
 *                    x-1..x+1 of a row are one contiguous range of the sorted arrays.
 *   hashed (nx == 0): bucket = hash(cell) & mask over a power-of-two table, for sparse or
 *                    unbounded domains; buckets may hold other cells too, so candidates are
 *                    checked against the wanted cell.
 *
 * Kernel: cubic spline with compact support h (q = r / h),
 *   W(q) = 8 / (pi h^3) * (6 (q^3 - q^2) + 1)  for q <= 1/2,  2 (1 - q)^3 for 1/2 < q <= 1.
 * grad_i W(x_i - x_j) = 8 / (pi h^3) / h^2 * (dW/dq / q) * (x_i - x_j), and dW/dq / q stays
 * finite at q = 0 (= -12), so coincident particles contribute an exact zero, never NaN.
 */

#define SIGMA_3D 2.546479089470325f /* 8 / pi */

inline float spline_w(float q)
{
    if (q <= 0.5f)
        return 6.0f * (q * q * q - q * q) + 1.0f;
    if (q <= 1.0f) {
        float t = 1.0f - q;
        return 2.0f * t * t * t;
    }
    return 0.0f;
}

/* (dW/dq) / q of the unnormalised spline; finite everywhere, zero beyond q = 1. */
inline float spline_dw_over_q(float q)
{
    if (q <= 0.5f)
        return 6.0f * (3.0f * q - 2.0f);
    if (q <= 1.0f) {
        float t = 1.0f - q;
        return -6.0f * t * t / q;
    }
    return 0.0f;
}

inline uint hashed_bucket(int x, int y, int z, uint mask)
{
    /* Teschner et al. 2003 primes. */
    return (((uint)x * 73856093u) ^ ((uint)y * 19349663u) ^ ((uint)z * 83492791u)) & mask;
}

inline uint dense_bucket(int x, int y, int z, int nx, int ny)
{
    return (uint)(x + nx * (y + ny * z));
}

inline uint bucket_of(int4 c, int nx, int ny, uint mask)
{
    return nx > 0 ? dense_bucket(c.x, c.y, c.z, nx, ny) : hashed_bucket(c.x, c.y, c.z, mask);
}

/* Arguments every neighbour loop needs, in this order. */
#define GRID_ARGS                                                                            \
    __global const int4 *sorted_cell, __global const float4 *sorted_local,                   \
        __global const uint *starts, const int nx, const int ny, const int nz, const uint mask, \
        const float h

/* Distance along one axis from a particle at offset o (in [0, h)) inside its cell to the cell
 * `delta` steps away: 0 for its own cell, o for the one below, h - o for the one above. */
inline float gap_to_cell(int delta, float o, float h)
{
    return delta == 0 ? 0.0f : (delta < 0 ? o : h - o);
}

/* Runs BODY for every particle j (sorted index) with |x_j - x_i| < h, including i itself.
 * In BODY: j, d (float3, x_j - x_i) and r2 (|d|^2) are defined.
 * Cells whose nearest point is h or farther away are skipped (whole rows of three cells, and
 * the x-1 / x+1 cells of a row): on average 20.6 of the 27 cells remain (-24% candidates). */
#define FOR_EACH_NEIGHBOUR(ci, li, BODY)                                                     \
    for (int dz = -1; dz <= 1; ++dz) {                                                       \
        const float gz_ = gap_to_cell(dz, (li).z, h);                                        \
        for (int dy = -1; dy <= 1; ++dy) {                                                   \
            const float gy_ = gap_to_cell(dy, (li).y, h);                                    \
            const float row2_ = gy_ * gy_ + gz_ * gz_;                                       \
            const int y_ = (ci).y + dy, z_ = (ci).z + dz;                                    \
            if (row2_ >= h * h || (nx > 0 && (y_ < 0 || y_ >= ny || z_ < 0 || z_ >= nz)))    \
                continue;                                                                    \
            const float above_ = h - (li).x;                                                 \
            const int lo_ = (li).x * (li).x + row2_ < h * h ? -1 : 0;                        \
            const int hi_ = above_ * above_ + row2_ < h * h ? 1 : 0;                         \
            const int first_ = nx > 0 ? 0 : lo_, last_ = nx > 0 ? 0 : hi_;                   \
            for (int s_ = first_; s_ <= last_; ++s_) {                                       \
                uint begin_, end_;                                                           \
                const int x_ = (ci).x + s_;                                                  \
                if (nx > 0) {                                                                \
                    const int x0_ = max((ci).x + lo_, 0), x1_ = min((ci).x + hi_, nx - 1);   \
                    begin_ = starts[dense_bucket(x0_, y_, z_, nx, ny)];                      \
                    end_ = starts[dense_bucket(x1_, y_, z_, nx, ny) + 1];                    \
                } else {                                                                     \
                    const uint b_ = hashed_bucket(x_, y_, z_, mask);                         \
                    begin_ = starts[b_];                                                     \
                    end_ = starts[b_ + 1];                                                   \
                }                                                                            \
                for (uint j = begin_; j < end_; ++j) {                                       \
                    const int4 cj_ = sorted_cell[j];                                         \
                    if (nx == 0 && (cj_.x != x_ || cj_.y != y_ || cj_.z != z_))              \
                        continue;                                                            \
                    const float3 d = convert_float3(cj_.xyz - (ci).xyz) * h                  \
                                     + (sorted_local[j].xyz - (li).xyz);                     \
                    const float r2 = dot(d, d);                                              \
                    if (r2 < h * h) {                                                        \
                        BODY                                                                 \
                    }                                                                        \
                }                                                                            \
            }                                                                                \
        }                                                                                    \
    }

/* --- counting sort -------------------------------------------------------------------- */

/* counts must be zero; rank = position of the particle inside its bucket (atomic order; see
   stable_rank). */
__kernel void count_buckets(__global const int4 *cell, const uint n, const int nx, const int ny,
                            const uint mask, __global uint *bucket, __global uint *rank,
                            __global uint *counts)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const uint b = bucket_of(cell[i], nx, ny, mask);
    bucket[i] = b;
    rank[i] = atomic_inc(&counts[b]);
}

/* The atomic ranks follow the order the work-items ran, which changes from run to run, and
   with it the order of every neighbour sum (the same frame's densities and anisotropy differed
   in their last bits). scatter_index puts each particle's index at its atomic slot; stable_rank
   then ranks a particle by the indices below its own in its bucket: the order of the frame's
   arrays, the same every run. Work per particle: its bucket's size (a few particles; the
   neighbour loops already visit 27 buckets each). */
__kernel void scatter_index(__global const uint *bucket, __global const uint *rank,
                            __global const uint *starts, const uint n, __global uint *slots)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    slots[starts[bucket[i]] + rank[i]] = i;
}

__kernel void stable_rank(__global const uint *bucket, __global const uint *starts,
                          __global const uint *slots, const uint n, __global uint *rank)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const uint b = bucket[i];
    uint below = 0;
    for (uint k = starts[b]; k < starts[b + 1]; ++k)
        below += slots[k] < i ? 1u : 0u;
    rank[i] = below;
}

__kernel void scatter_sorted(__global const int4 *cell, __global const float4 *in_cell,
                             __global const uint *bucket, __global const uint *rank,
                             __global const uint *starts, const uint n,
                             __global int4 *sorted_cell, __global float4 *sorted_local,
                             __global uint *sorted_to_original)
{
    const uint i = get_global_id(0);
    if (i >= n)
        return;
    const uint k = starts[bucket[i]] + rank[i];
    sorted_cell[k] = cell[i];
    sorted_local[k] = in_cell[i];
    sorted_to_original[k] = i;
}

/* --- exclusive prefix sum of m counts into m + 1 starts (three passes) ------------------ */

__kernel void chunk_sums(__global const uint *counts, const uint m, const uint chunk,
                         __global uint *sums)
{
    const uint c = get_global_id(0);
    const uint begin = c * chunk;
    if (begin >= m)
        return;
    const uint end = min(begin + chunk, m);
    uint total = 0;
    for (uint i = begin; i < end; ++i)
        total += counts[i];
    sums[c] = total;
}

/* One work-item: exclusive scan of the chunk sums in place; sums[chunks] = grand total. */
__kernel void scan_chunk_sums(__global uint *sums, const uint chunks)
{
    if (get_global_id(0) != 0)
        return;
    uint running = 0;
    for (uint c = 0; c < chunks; ++c) {
        const uint value = sums[c];
        sums[c] = running;
        running += value;
    }
    sums[chunks] = running;
}

__kernel void chunk_scan(__global const uint *counts, const uint m, const uint chunk,
                         const uint chunks, __global const uint *sums, __global uint *starts)
{
    const uint c = get_global_id(0);
    const uint begin = c * chunk;
    if (begin >= m)
        return;
    const uint end = min(begin + chunk, m);
    uint running = sums[c];
    for (uint i = begin; i < end; ++i) {
        starts[i] = running;
        running += counts[i];
    }
    if (c == chunks - 1)
        starts[m] = running;
}

/* --- neighbour lists (tests, diagnostics) ------------------------------------------------ */

/* Number of neighbours j != i with |x_j - x_i| < h, written at the original index. */
__kernel void count_neighbours(GRID_ARGS, __global const uint *sorted_to_original, const uint n,
                               __global uint *count_out)
{
    const uint k = get_global_id(0);
    if (k >= n)
        return;
    const int4 ci = sorted_cell[k];
    const float4 li = sorted_local[k];
    uint count = 0;
    FOR_EACH_NEIGHBOUR(ci, li, if (j != k) ++count;)
    count_out[sorted_to_original[k]] = count;
}

__kernel void list_neighbours(GRID_ARGS, __global const uint *sorted_to_original, const uint n,
                              __global const uint *offsets, __global uint *neighbours)
{
    const uint k = get_global_id(0);
    if (k >= n)
        return;
    const int4 ci = sorted_cell[k];
    const float4 li = sorted_local[k];
    uint write = offsets[sorted_to_original[k]];
    FOR_EACH_NEIGHBOUR(ci, li, if (j != k) neighbours[write++] = sorted_to_original[j];)
}

/* --- SPH quantities ---------------------------------------------------------------------- */

/* Eq 2 with A = rho: rho_i = sum_j m W(x_i - x_j, h), self included. Also writes the volume
 * m / rho in sorted order for the colour field (a multiply per neighbour instead of a divide). */
__kernel void density(GRID_ARGS, __global const uint *sorted_to_original, const uint n,
                      const float mass, __global float *sorted_volume, __global float *density_out)
{
    const uint k = get_global_id(0);
    if (k >= n)
        return;
    const int4 ci = sorted_cell[k];
    const float4 li = sorted_local[k];
    float sum = 0.0f;
    FOR_EACH_NEIGHBOUR(ci, li, sum += sorted_local[j].w * spline_w(sqrt(r2) / h);)
    const float rho = mass * SIGMA_3D / (h * h * h) * sum;
    sorted_volume[k] = mass / rho;
    density_out[sorted_to_original[k]] = rho;
}

/* Client densities (original order) -> volumes m / rho in sorted order. */
__kernel void gather_volumes(__global const float *density, __global const uint *sorted_to_original,
                             const uint n, const float mass, __global float *sorted_volume)
{
    const uint k = get_global_id(0);
    if (k >= n)
        return;
    sorted_volume[k] = mass / density[sorted_to_original[k]];
}

/* Eq 26 c_i = sum_j (m / rho_j) W, eq 27 n_i = sum_j (m / rho_j) grad_i W(x_i - x_j), eq 28
 * surface = |n| > threshold. sorted_flag (for the splat mask) marks surface particles and
 * sparse ones: kernel density sum_j m W (eq 2 from positions alone, whatever densities the
 * client sent) below sparse_density. Isolated droplets and thin sheets have no gradient (their
 * neighbourhood is symmetric) but are visible, so surface-only splatting must keep them; the
 * colour field cannot tell them apart, it is ~1 for an isolated particle too. */
__kernel void color_field(GRID_ARGS, __global const uint *sorted_to_original, const uint n,
                          const float mass, __global const float *sorted_volume,
                          const float threshold, const float sparse_density,
                          __global float *color_out, __global float4 *gradient_out,
                          __global uchar *surface_out, __global uchar *sorted_flag)
{
    const uint k = get_global_id(0);
    if (k >= n)
        return;
    const int4 ci = sorted_cell[k];
    const float4 li = sorted_local[k];
    float color = 0.0f;
    float kernel_sum = 0.0f;
    float3 gradient = (float3)(0.0f);
    FOR_EACH_NEIGHBOUR(ci, li, {
        const float q = sqrt(r2) / h;
        const float weight = sorted_local[j].w;
        const float volume = sorted_volume[j] * weight;
        const float w = spline_w(q);
        kernel_sum += weight * w;
        color += volume * w;
        /* x_i - x_j = -d */
        gradient -= (volume * spline_dw_over_q(q)) * d;
    })
    const float sigma = SIGMA_3D / (h * h * h);
    color *= sigma;
    gradient *= sigma / (h * h);
    const uint i = sorted_to_original[k];
    color_out[i] = color;
    gradient_out[i] = (float4)(gradient, 0.0f);
    const uchar surface = length(gradient) > threshold ? 1 : 0;
    surface_out[i] = surface;
    sorted_flag[k] = (surface || mass * sigma * kernel_sum < sparse_density) ? 1 : 0;
}

/* keep_i = flag_i or some flagged particle within `reach` (< h): the surface shell plus a
 * safety layer, everything else (hidden interior) is not splatted. */
__kernel void dilate_flags(GRID_ARGS, __global const uint *sorted_to_original, const uint n,
                           __global const uchar *sorted_flag, const float reach,
                           __global uchar *keep_out)
{
    const uint k = get_global_id(0);
    if (k >= n)
        return;
    const int4 ci = sorted_cell[k];
    const float4 li = sorted_local[k];
    uchar keep = sorted_flag[k];
    const float reach2 = reach * reach;
    if (!keep) {
        FOR_EACH_NEIGHBOUR(ci, li, if (!keep && r2 <= reach2 && sorted_flag[j]) keep = 1;)
    }
    keep_out[sorted_to_original[k]] = keep;
}
