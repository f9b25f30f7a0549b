// The narrow-range kernel of smooth_depth_separable.frag.glsl at the image's ends, included
// there in place of its tap_pair when IMAGE_BORDER is 1. A tap past the image's end is no
// background: dropping it with its mirror, as a background tap is dropped, leaves the pixels
// at the image's edge unsmoothed (the particles' bumps: 48 deg of normal error on the last rows
// of a slab that fills the image). Here the kernel goes on one-sided instead: the tap inside
// the image counts alone, and the result is the intercept at the pixel of the weighted
// least-squares line u = a + b k through the inverse depths u = 1/z the kernel took (exact on
// a plane, where a one-sided mean would lie off it). passes/smooth.py draws this variant only
// within kernel_max_px of the image's ends; wherever no tap crosses an end it adds what the
// packed walk's tap_pair adds, bit for bit.

uniform ivec2 u_image_size_px;  // the unpacked image (the packed texture's last texel may pad)

vec4 g_room_ahead;   // pixels between each lane's pixel and the image's end along +AXIS
vec4 g_room_behind;  // ... and along -AXIS
vec4 g_k_sum;        // sum of w k over the samples taken (signed offsets)
vec4 g_kk_sum;       // sum of w k^2
vec4 g_kd_sum;       // sum of w k (u - u_centre)

// Sets the lanes' room to the image's ends and zeroes the fit's sums.
void start_image_border(ivec2 texel) {
#if AXIS == 0
    vec4 position = vec4(float(4 * texel.x)) + vec4(0.0, 1.0, 2.0, 3.0);
    g_room_ahead = vec4(float(u_image_size_px.x - 1)) - position;
#else
    vec4 position = vec4(float(texel.y));
    g_room_ahead = vec4(float(u_image_size_px.y - 1)) - position;
#endif
    g_room_behind = position;
    g_k_sum = vec4(0.0);
    g_kk_sum = vec4(0.0);
    g_kd_sum = vec4(0.0);
}

// The narrow range's tap_pair (smooth_depth_separable.frag.glsl) where the pair may straddle an
// image end: a side is taken with its mirror as there, or alone when the mirror lies past the
// end. Walked by common/packed_taps.glsl like the other (the value arguments are unused).
void tap_pair(int k, vec4 za, vec4 zb, vec4 value_a, vec4 value_b) {
    vec4 w = gaussian_next();
    float kf = float(k);
    bvec4 in_reach = lessThanEqual(vec4(kf), g_reach);
    bvec4 out_a = lessThan(g_room_ahead, vec4(kf));
    bvec4 out_b = lessThan(g_room_behind, vec4(kf));
    bvec4 valid_a = both(greaterThan(za, vec4(0.0)), lessThanEqual(za, g_upper));
    bvec4 valid_b = both(greaterThan(zb, vec4(0.0)), lessThanEqual(zb, g_upper));
    bvec4 use_a = both(both(in_reach, not(out_a)), both(valid_a, either(valid_b, out_b)));
    bvec4 use_b = both(both(in_reach, not(out_b)), both(valid_b, either(valid_a, out_a)));
#if (KEEP_FEATURES & 1) != 0
    // A pair wholly past the image's ends rejects nothing.
    bvec4 rejected = both(both(in_reach, not(both(out_a, out_b))), not(either(use_a, use_b)));
    use_a = both(use_a, g_open);
    use_b = both(use_b, g_open);
    g_open = both(g_open, not(rejected));
#endif
#if (KEEP_FEATURES & 2) != 0
    g_all_weight_sum += mix(vec4(0.0), w, both(in_reach, not(out_a))) +
                        mix(vec4(0.0), w, both(in_reach, not(out_b)));
#endif
    za = narrow_range_sample(za, use_a);
    zb = narrow_range_sample(zb, use_b);
    vec4 wa = mix(vec4(0.0), w, use_a);
    vec4 wb = mix(vec4(0.0), w, use_b);
    // A pair adds what tap_pair adds, bit for bit.
    bvec4 pair = both(use_a, use_b);
    vec4 ua = inverse_depth(za);
    vec4 ub = inverse_depth(zb);
    g_sum += mix(wa * ua + wb * ub, w * (ua + ub), pair);
    g_weight_sum += mix(wa + wb, 2.0 * w, pair);
    g_k_sum += kf * (wa - wb);
    g_kk_sum += kf * kf * (wa + wb);
    vec4 uc = inverse_depth(g_center);
    g_kd_sum += kf * (wa * (ua - uc) - wb * (ub - uc));
}

// The weighted mean `mean` of the inverse depths, or where the kernel went one-sided
// (g_k_sum != 0) the intercept a = mean - b k_mean of the weighted least-squares line through
// the samples taken (the variance floor keeps a lone near sample finite), kept within the
// inverse depths the kernel can have taken.
vec4 image_border_fit(vec4 mean) {
    vec4 k_mean = g_k_sum / g_weight_sum;
    vec4 variance = g_kk_sum / g_weight_sum - k_mean * k_mean;
    vec4 covariance = g_kd_sum / g_weight_sum - k_mean * (mean - inverse_depth(g_center));
    vec4 slope = covariance / max(variance, 1e-6);
    vec4 nearest = min(g_lower, g_lower_clamp);
    vec4 fit = clamp(mean - slope * k_mean, inverse_depth(g_upper), inverse_depth(nearest));
    return mix(mean, fit, notEqual(g_k_sum, vec4(0.0)));
}
