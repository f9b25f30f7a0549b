#version 330 core
// Depth smoothing (thesis §3.3) of an eye-depth image with one 2-D kernel (the separable
// kernels are in smooth_depth_separable.frag.glsl, on a packed image). Background (0) is never read into the
// surface and stays background. By default (KERNEL_SIZE_PROJECTED_RADIUS) the kernel follows the
// projected particle radius:
//   r_px(z) = r * px_per_unit / z,  sigma = kernel_scale * r_px,  reach = clamp(ceil(3 sigma),
//   min, max)  and sigma is reduced to reach / 3 when the cap bites, so the truncated kernel
//   stays a Gaussian (a kernel cut at less than 3 sigma degenerates towards a box).
// Spatial weights are computed in pixels throughout (the unit mix-up of public narrow-range
// ports, which turns the Gaussian into a box filter, is tested against numpy).

#define FILTER_GAUSSIAN 0
#define FILTER_BILATERAL 1
#define FILTER_NARROW_RANGE 2
#define FILTER 2
#define KERNEL_SIZE_PROJECTED_RADIUS 0
#define KERNEL_SIZE_EQ25 1
#define KERNEL_SIZE 0

#include "common/depth_image.glsl"
#include "common/depth_filter_params.glsl"

uniform sampler2D u_depth;

layout(location = 0) out float out_eye_depth;

void main() {
    ivec2 center = ivec2(gl_FragCoord.xy);
    float zc = fetch_depth(u_depth, center);
    if (zc <= 0.0) {
        out_eye_depth = 0.0;
        return;
    }
#if KERNEL_SIZE == KERNEL_SIZE_PROJECTED_RADIUS
    float r_px = u_particle_radius * u_px_per_unit / zc;
    float sigma = u_kernel_scale * r_px;
#else
    // Thesis eq 25, read as a continuous decline: ks = 3 sigma up to the threshold distance, then
    // 3 sigma - (d - threshold) k (as printed, "- d k" would jump by threshold * k).
    float sigma = u_eq25_sigma_px - max(zc - u_eq25_threshold, 0.0) * u_eq25_decline / 3.0;
#endif
    float reach = clamp(ceil(3.0 * sigma), float(u_kernel_min_px), float(u_kernel_max_px));
    sigma = max(min(sigma, reach / 3.0), 1e-3);
    float inv_two_sigma2 = 1.0 / (2.0 * sigma * sigma);
    int radius = int(reach);

    float sum = zc;
    float weight_sum = 1.0;

#if FILTER == FILTER_NARROW_RANGE
    // Truong & Yuksel 2018: samples behind the centre by more than lambda*r are dropped, with
    // their mirror sample (no one-sided bias); samples in front by more than lambda*r are clamped
    // to z - mu*r; the accepted range grows around every accepted sample, walking outwards.
    float upper = zc + u_nr_threshold;
    float lower = zc - u_nr_threshold;
    float lower_clamp = zc - u_nr_clamp;
    for (int k = 1; k <= radius; ++k) {
        int pairs_in_ring = 4 * k;
        for (int i = 0; i < pairs_in_ring; ++i) {
            // Half of the square ring at Chebyshev distance k; the other half is its mirror.
            ivec2 offset;
            if (i < 2 * k + 1) {
                offset = ivec2(i - k, k);
            } else if (i < 3 * k + 1) {
                offset = ivec2(k, i - (2 * k + 1));
            } else {
                offset = ivec2(-k, i - (3 * k + 1) + 1);
            }
            if (dot(vec2(offset), vec2(offset)) > reach * reach) {
                continue;
            }
            float d2 = dot(vec2(offset), vec2(offset));
            float w = exp(-d2 * inv_two_sigma2);
            float za = fetch_depth(u_depth, center + offset);
            float zb = fetch_depth(u_depth, center - offset);
            bool valid_a = za > 0.0 && za <= upper;
            bool valid_b = zb > 0.0 && zb <= upper;
            if (!(valid_a && valid_b)) {
                continue;  // as in the paper: a dropped sample drops its mirror (no one-sided bias)
            }
            if (za < lower) {
                za = lower_clamp;
            } else {
                upper = max(upper, za + u_nr_threshold);
                lower = min(lower, za - u_nr_threshold);
            }
            if (zb < lower) {
                zb = lower_clamp;
            } else {
                upper = max(upper, zb + u_nr_threshold);
                lower = min(lower, zb - u_nr_threshold);
            }
            sum += w * (za + zb);
            weight_sum += 2.0 * w;
        }
    }
#else
    float inv_two_range2 = 1.0 / (2.0 * u_range_sigma * u_range_sigma);
    for (int y = -radius; y <= radius; ++y) {
        for (int x = -radius; x <= radius; ++x) {
            ivec2 offset = ivec2(x, y);
            if (dot(vec2(offset), vec2(offset)) > reach * reach) {
                continue;
            }
            if (offset == ivec2(0)) {
                continue;
            }
            float z = fetch_depth(u_depth, center + offset);
            if (z <= 0.0) {
                continue;
            }
            float w = exp(-dot(vec2(offset), vec2(offset)) * inv_two_sigma2);
#if FILTER == FILTER_BILATERAL
            float dz = z - zc;
            w *= exp(-dz * dz * inv_two_range2);
#endif
            sum += w * z;
            weight_sum += w;
        }
    }
#endif
    out_eye_depth = sum / weight_sum;
}
