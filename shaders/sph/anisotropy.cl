/* Anisotropic particles (Yu & Turk 2013, "Reconstructing surfaces of particle-based fluids
 * using anisotropic kernels", section 4): per particle, the weighted covariance of its
 * neighbourhood within R, its eigen-decomposition, and an ellipsoid of the particle's volume
 * stretched along the neighbourhood's principal axes; plus the smoothed (Laplacian-like)
 * centre. Shares the grid and its walk with sph.cl (the host builds the grid with cell side R,
 * so `h` below, the walk's radius, IS R).
 *
 * Per particle i, over j with |x_j - x_i| < R, i itself included (w_ii = 1):
 *   w_ij   = 1 - (|x_j - x_i| / R)^3
 *   m_i    = sum_j w_ij (x_j - x_i) / sum_j w_ij            (x^w_i - x_i, in units of R)
 *   C_i    = sum_j w_ij (x_j - x_i)(x_j - x_i)^T / sum_j w_ij - m_i m_i^T
 *          = sum_j w_ij (x_j - x^w_i)(x_j - x^w_i)^T / sum_j w_ij
 * Offsets from x_i are small float32 vectors (cell part exact, see sph.cl), so C at 1e5 equals
 * C near the origin; C is formed in units of R^2 (entries <= 1) and rescaled by its largest
 * entry before the eigen-solver, so neither tiny nor huge scenes under- or overflow.
 *
 * Shape (dimensionless, det = 1): eigenvalues s_1 >= s_2 >= s_3 of C, clamped s_k >=
 * s_1 / max_ratio (Yu & Turk's k_r), normalised by their geometric mean g, so that
 *   axis_k = r (s_k / g)^t,  prod_k axis_k = r^3  (the ellipsoid keeps the sphere's volume).
 * As Yu & Turk, the axis lengths follow the eigenvalues (variances), not their square roots.
 * t in [0, 1] ramps anisotropy in with the neighbour count n (j != i): t = 0 for n < N_eps
 * (the particle is EXACTLY a sphere: shape = identity, no shift; a lone droplet keeps radius r
 * and does not move), t = min(1, (n - N_eps + 1) / ramp) above, so a particle crossing N_eps
 * between frames changes shape continuously instead of popping. The centre moves by
 * lambda t m_i R (so sparse particles barely move). A degenerate neighbourhood (largest
 * eigenvalue below DEGENERATE_VARIANCE R^2, e.g. all neighbours on top of i) is a sphere too.
 */

#include "sph.cl"

/* Jacobi sweeps over the three off-diagonal pairs. Cyclic Jacobi converges quadratically once
 * the off-diagonal part is small. Measured on 40,000 random and near-repeated (1, 1.0001, 2)
 * float32 matrices: after 2 sweeps eigenvalues still err by up to 8e-3 ||A||, after 3 they are
 * at rounding level (5 u ||A||, u = 2^-24) and stay there; 6 doubles that for margin (the
 * rotations cost nothing next to the neighbour walk). A -D JACOBI_SWEEPS=k build overrides. */
#ifndef JACOBI_SWEEPS
#define JACOBI_SWEEPS 6
#endif
/* Largest eigenvalue of C (units of R^2) below which the neighbourhood counts as one point. */
#define DEGENERATE_VARIANCE 1e-6f

/* One Jacobi rotation zeroing a[p][q] (p < q) of the symmetric a, accumulated into v's columns
 * (Golub & Van Loan 8.5.2: the smaller root t keeps the rotation angle <= pi/4, which makes
 * the sweep stable for equal diagonal entries and repeated eigenvalues). */
inline void jacobi_rotate(float a[3][3], float v[3][3], const int p, const int q)
{
    const float apq = a[p][q];
    if (fabs(apq) < 1e-30f)  /* entries are scaled to <= 1: this is an exact-zero test that */
        return;              /* also skips denormals a flush-to-zero device would mangle */
    const float theta = (a[q][q] - a[p][p]) / (2.0f * apq);
    const float at = fabs(theta);
    float t = 1.0f / (at + hypot(at, 1.0f)); /* hypot: no overflow for huge theta */
    t = theta < 0.0f ? -t : t;
    const float c = 1.0f / sqrt(t * t + 1.0f);
    const float s = t * c;
    a[p][p] -= t * apq;
    a[q][q] += t * apq;
    a[p][q] = 0.0f;
    a[q][p] = 0.0f;
    const int r = 3 - p - q; /* the third index */
    const float arp = a[r][p];
    const float arq = a[r][q];
    a[r][p] = c * arp - s * arq;
    a[p][r] = a[r][p];
    a[r][q] = s * arp + c * arq;
    a[q][r] = a[r][q];
    for (int k = 0; k < 3; ++k) {
        const float vkp = v[k][p];
        const float vkq = v[k][q];
        v[k][p] = c * vkp - s * vkq;
        v[k][q] = s * vkp + c * vkq;
    }
}

/* Eigen-decomposition of the symmetric a (destroyed): values[k] descending, v's column k the
 * unit eigenvector of values[k] (v a rotation: orthonormal, det +1; a = v diag(values) v^T). Scale-free: the
 * matrix is divided by its largest |entry| first and the values multiplied back. */
inline void eigen_sym3(float a[3][3], float values[3], float v[3][3])
{
    float scale = 0.0f;
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) {
            scale = fmax(scale, fabs(a[r][c]));
            v[r][c] = r == c ? 1.0f : 0.0f;
        }
    if (scale > 0.0f) {
        const float inv = 1.0f / scale;
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                a[r][c] *= inv;
        for (int sweep = 0; sweep < JACOBI_SWEEPS; ++sweep) {
            jacobi_rotate(a, v, 0, 1);
            jacobi_rotate(a, v, 0, 2);
            jacobi_rotate(a, v, 1, 2);
        }
    }
    for (int k = 0; k < 3; ++k)
        values[k] = a[k][k] * scale;
    /* sort descending, columns with them (three compare-swaps) */
    for (int pass = 0; pass < 3; ++pass) {
        const int i = pass == 1 ? 1 : 0;
        if (values[i] < values[i + 1]) {
            const float tv = values[i];
            values[i] = values[i + 1];
            values[i + 1] = tv;
            for (int r = 0; r < 3; ++r) {
                const float tc = v[r][i];
                v[r][i] = v[r][i + 1];
                v[r][i + 1] = tc;
            }
        }
    }
    /* a proper rotation (det +1), so A = v diag(axes) is rotation x scale for the splat */
    const float3 c0 = (float3)(v[0][0], v[1][0], v[2][0]);
    const float3 c1 = (float3)(v[0][1], v[1][1], v[2][1]);
    const float3 c2 = (float3)(v[0][2], v[1][2], v[2][2]);
    if (dot(cross(c0, c1), c2) < 0.0f)
        for (int r = 0; r < 3; ++r)
            v[r][2] = -v[r][2];
}

/* Test entry: m symmetric matrices as 6 floats (xx, yy, zz, xy, xz, yz) -> 3 values
 * (descending) and 9 floats (row-major v, columns the eigenvectors). */
__kernel void eigen_sym3_test(__global const float *matrices, const uint m, __global float *values,
                              __global float *vectors)
{
    const uint i = get_global_id(0);
    if (i >= m)
        return;
    __global const float *s = matrices + 6 * i;
    float a[3][3] = {{s[0], s[3], s[4]}, {s[3], s[1], s[5]}, {s[4], s[5], s[2]}};
    float lambda[3];
    float v[3][3];
    eigen_sym3(a, lambda, v);
    for (int k = 0; k < 3; ++k)
        values[3 * i + k] = lambda[k];
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            vectors[9 * i + 3 * r + c] = v[r][c];
}

/* Per particle (written at its original index):
 *   shift_out  float4: lambda t m_i R, world units (centre = x_i + shift, added in float64)
 *   shape_out  9 floats, row-major: the dimensionless matrix whose columns are the unit-volume
 *              semi-axes; exactly the identity for spheres (the host multiplies by r)
 *   sphere_out 1 = sphere (n < N_eps or degenerate), shape and shift exact
 *   count_out  n, neighbours j != i within R */
__kernel void anisotropy(GRID_ARGS, __global const uint *sorted_to_original, const uint n,
                         const float max_ratio, const uint min_neighbours, const float ramp,
                         const float smoothing, __global float4 *shift_out,
                         __global float *shape_out, __global uchar *sphere_out,
                         __global uint *count_out)
{
    const uint k = get_global_id(0);
    if (k >= n)
        return;
    const int4 ci = sorted_cell[k];
    const float4 li = sorted_local[k];
    const float inv_r = 1.0f / h;
    float sw = 0.0f;
    float3 sd = (float3)(0.0f);
    float sxx = 0.0f;
    float syy = 0.0f;
    float szz = 0.0f;
    float sxy = 0.0f;
    float sxz = 0.0f;
    float syz = 0.0f;
    uint count = 0;
    FOR_EACH_NEIGHBOUR(ci, li, {
        const float3 e = d * inv_r; /* units of R: |e| < 1 */
        const float q2 = dot(e, e);
        const float weight = sorted_local[j].w; /* particles it stands for (crowd.py) */
        const float w = (1.0f - q2 * sqrt(q2)) * weight;
        sw += w;
        sd += w * e;
        sxx += w * e.x * e.x;
        syy += w * e.y * e.y;
        szz += w * e.z * e.z;
        sxy += w * e.x * e.y;
        sxz += w * e.x * e.z;
        syz += w * e.y * e.z;
        count += (uint)weight - (j == k ? 1u : 0u);
    })
    const uint i = sorted_to_original[k];
    count_out[i] = count;
    __global float *shape = shape_out + 9 * i;
    const float t = count < min_neighbours
                        ? 0.0f
                        : fmin(1.0f, (float)(count - min_neighbours + 1) / ramp);
    uchar sphere = 1;
    float3 shift = (float3)(0.0f);
    float out[3][3] = {{1.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}, {0.0f, 0.0f, 1.0f}};
    if (t > 0.0f) {
        const float inv_w = 1.0f / sw; /* sw >= 1: self */
        const float3 m = sd * inv_w;
        float a[3][3];
        a[0][0] = sxx * inv_w - m.x * m.x;
        a[1][1] = syy * inv_w - m.y * m.y;
        a[2][2] = szz * inv_w - m.z * m.z;
        a[0][1] = a[1][0] = sxy * inv_w - m.x * m.y;
        a[0][2] = a[2][0] = sxz * inv_w - m.x * m.z;
        a[1][2] = a[2][1] = syz * inv_w - m.y * m.z;
        float sigma[3];
        float v[3][3];
        eigen_sym3(a, sigma, v);
        /* C ~ 0 (R^2 units; float32 rounding of the entries is ~1e-7): the neighbourhood is
         * one point to within 1e-3 R, e.g. every neighbour on top of i; no direction to stretch */
        if (sigma[0] > DEGENERATE_VARIANCE) {
            sphere = 0;
            shift = (smoothing * t * h) * m;
            const float floor_ = sigma[0] / max_ratio;
            float s[3];
            for (int c = 0; c < 3; ++c)
                s[c] = fmax(sigma[c], floor_);
            /* log of the geometric mean: volume-preserving normalisation */
            const float log_g = (log(s[0]) + log(s[1]) + log(s[2])) / 3.0f;
            for (int c = 0; c < 3; ++c) {
                const float axis = exp(t * (log(s[c]) - log_g));
                for (int r = 0; r < 3; ++r)
                    out[r][c] = v[r][c] * axis;
            }
        }
    }
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            shape[3 * r + c] = out[r][c];
    shift_out[i] = (float4)(shift, 0.0f);
    sphere_out[i] = sphere;
}
