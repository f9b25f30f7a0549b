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
#define KERNEL_SIZE_DEPTH_FALLOFF 1
#define KERNEL_SIZE 0

#include "common/depth_image.glsl"
#include "common/depth_filter_params.glsl"

uniform sampler2D u_depth;

// Sums of the plane fit over the taps taken, offsets o in pixels and d = v - v_centre of the
// values v the filter averages (the narrow range: inverse depths u = 1/z; the others: z).
struct BorderFit {
    vec2 offset_sum;  // sum w o (0 while every tap is paired with its mirror)
    vec3 second;      // sum w (ox ox, ox oy, oy oy)
    vec2 depth;       // sum w o d
};

// The samples at +-o of weights summing to `w`, `wd` = the sum of w d with d's sign at -o
// flipped (the offset's sign cancels in the second moments).
void add_to_fit(inout BorderFit fit, ivec2 o, float w, float wd) {
    vec2 f = vec2(o);
    fit.second += w * vec3(f.x * f.x, f.x * f.y, f.y * f.y);
    fit.depth += wd * f;
}

// The weighted mean `mean` of the values, or where the kernel went one-sided at an image end
// the intercept at the pixel of the weighted least-squares plane v = a + b.o through the
// samples taken (ridge-damped by 1e-3 px^2, so samples along one line give that line's fit),
// kept within [v_min, v_max]; `vc` is the centre's value.
float image_border_fit(BorderFit fit, bool one_sided, float mean, float weight_sum, float vc,
                       float v_min, float v_max) {
    if (!one_sided) {
        return mean;
    }
    vec2 o_mean = fit.offset_sum / weight_sum;
    vec3 c = fit.second / weight_sum - vec3(o_mean.x * o_mean.x, o_mean.x * o_mean.y,
                                            o_mean.y * o_mean.y) + vec3(1e-3, 0.0, 1e-3);
    vec2 cd = fit.depth / weight_sum - o_mean * (mean - vc);
    float det = c.x * c.z - c.y * c.y;
    vec2 slope = vec2(c.z * cd.x - c.y * cd.y, c.x * cd.y - c.y * cd.x) / det;
    return clamp(mean - dot(slope, o_mean), v_min, v_max);
}

#if FILTER == FILTER_NARROW_RANGE
// The narrow range averages inverse depth (see smooth_depth_separable.frag.glsl): a plane in
// perspective is a fixed point of the filter. Finite for background 0.
float inverse_depth(float z) {
    return 1.0 / max(z, 1e-30);
}

// One sample of the narrow range: clamped to z_centre - mu r when in front by more than
// lambda r, else it grows the accepted range around itself; returns the value it adds.
float narrow_range_sample(float z, inout float upper, inout float lower, float lower_clamp) {
    if (z < lower) {
        return lower_clamp;
    }
    upper = max(upper, z + u_nr_threshold);
    lower = min(lower, z - u_nr_threshold);
    return z;
}
#endif

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
    float sigma = u_falloff_sigma_px - max(zc - u_falloff_depth, 0.0) * u_falloff_rate / 3.0;
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
    float uc = inverse_depth(zc);
    sum = uc;  // the narrow range averages inverse depths u = 1/z
    // A tap past the image's end is no background: the kernel goes on one-sided there (the
    // tap inside counts alone), and the result is the intercept at the pixel of the weighted
    // plane fit through the taps taken (image_border_fit), exact on a tilted plane, where a
    // one-sided mean would lie off it. The separable filter does the same per axis
    // (image_border_taps.glsl).
    ivec2 size = textureSize(u_depth, 0);
    BorderFit fit = BorderFit(vec2(0.0), vec3(0.0), vec2(0.0));
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
            ivec2 pa = center + offset;
            ivec2 pb = center - offset;
            bool out_a = any(lessThan(pa, ivec2(0))) || any(greaterThanEqual(pa, size));
            bool out_b = any(lessThan(pb, ivec2(0))) || any(greaterThanEqual(pb, size));
            float za = fetch_depth(u_depth, pa);
            float zb = fetch_depth(u_depth, pb);
            bool valid_a = za > 0.0 && za <= upper;
            bool valid_b = zb > 0.0 && zb <= upper;
            // as in the paper, a dropped sample drops its mirror (no one-sided bias); a
            // sample whose mirror lies past the image's end counts alone
            bool use_a = !out_a && valid_a && (valid_b || out_b);
            bool use_b = !out_b && valid_b && (valid_a || out_a);
            if (use_a) {
                za = narrow_range_sample(za, upper, lower, lower_clamp);
            }
            if (use_b) {
                zb = narrow_range_sample(zb, upper, lower, lower_clamp);
            }
            // branch-free (llvmpipe runs both sides of an if): a pair adds nothing to
            // offset_sum, a lone sample its offset
            float wa = use_a ? w : 0.0;
            float wb = use_b ? w : 0.0;
            float ua = inverse_depth(za);
            float ub = inverse_depth(zb);
            sum += wa * ua + wb * ub;
            weight_sum += wa + wb;
            fit.offset_sum += (wa - wb) * vec2(offset);
            add_to_fit(fit, offset, wa + wb, wa * (ua - uc) - wb * (ub - uc));
        }
    }
    float u_min = inverse_depth(upper);
    float u_max = inverse_depth(min(lower, lower_clamp));
    bool one_sided = fit.offset_sum != vec2(0.0);  // only an image end unpairs a tap
    sum = 1.0 / image_border_fit(fit, one_sided, sum / weight_sum, weight_sum, uc, u_min, u_max);
    weight_sum = 1.0;
#else
    float inv_two_range2 = 1.0 / (2.0 * u_range_sigma * u_range_sigma);
    ivec2 size = textureSize(u_depth, 0);
    BorderFit fit = BorderFit(vec2(0.0), vec3(0.0), vec2(0.0));
    bool crossed = false;
    float z_min = zc;
    float z_max = zc;
    for (int y = -radius; y <= radius; ++y) {
        for (int x = -radius; x <= radius; ++x) {
            ivec2 offset = ivec2(x, y);
            if (dot(vec2(offset), vec2(offset)) > reach * reach) {
                continue;
            }
            if (offset == ivec2(0)) {
                continue;
            }
            ivec2 p = center + offset;
            if (any(lessThan(p, ivec2(0))) || any(greaterThanEqual(p, size))) {
                crossed = true;
                continue;
            }
            float z = fetch_depth(u_depth, p);
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
            fit.offset_sum += w * vec2(offset);
            add_to_fit(fit, offset, w, w * (z - zc));
            z_min = min(z_min, z);
            z_max = max(z_max, z);
        }
    }
    // A tap past the image's end is skipped like background, but the kernel's one-sided mean
    // there lies off any slope: where one was skipped, the plane fit's intercept (background
    // unpairs taps too, and inside the image those stay the plain mean). The range taken is
    // widened by its width: the end of a curved surface may lie beyond it.
    sum = image_border_fit(fit, crossed, sum / weight_sum, weight_sum, zc, 2.0 * z_min - z_max,
                           2.0 * z_max - z_min);
    weight_sum = 1.0;
#endif
    out_eye_depth = sum / weight_sum;
}
