// The 1-D kernels of smooth_depth_separable.frag.glsl at the image's ends, included there in
// place of its tap_pair when IMAGE_BORDER is 1. A tap past the image's end is no background.
// The narrow range dropped it with its mirror, as a background tap is dropped, which left the
// pixels at the image's edge unsmoothed (the particles' bumps: 48 deg of normal error on the
// last rows of a slab that fills the image); the Gaussian and bilateral filters dropped it
// alone, and their one-sided mean lay off any slope (23 deg there). Here the kernel goes on
// one-sided, and the result is the intercept at the pixel of the weighted least-squares line
// v = a + b k through the values the kernel took: inverse depths u = 1/z for the narrow range
// (exact on a plane), depths for the others (as they average), kept within the values taken.
// passes/smooth.py draws this variant only within kernel_max_px of the image's ends; wherever
// no tap crosses an end it adds what the packed walk's tap_pair adds, bit for bit.
// With the narrow range's normal guide (NORMAL_GUIDE) every draw uses it: the guide's one-sided
// limits weigh the two taps of a pair apart, and the same line fit keeps a face flat where they
// leave the kernel one-sided.

#include "common/border_fit.glsl"

vec4 g_room_ahead;   // pixels between each lane's pixel and the image's end along +AXIS
vec4 g_room_behind;  // ... and along -AXIS
vec4 g_k_sum;        // sum of w k over the samples taken (signed offsets)
vec4 g_kk_sum;       // sum of w k^2
vec4 g_kd_sum;       // sum of w k (v - v_centre)
#if FILTER != FILTER_NARROW_RANGE
bvec4 g_crossed;     // a tap in reach lay past an end
vec4 g_min_taken;    // the range of the depths taken
vec4 g_max_taken;
#endif

// Sets the lanes' room to the image's ends and zeroes the fit's sums.
void start_image_border(ivec2 texel) {
    image_end_room(texel, g_room_ahead, g_room_behind);
    g_k_sum = vec4(0.0);
    g_kk_sum = vec4(0.0);
    g_kd_sum = vec4(0.0);
#if FILTER != FILTER_NARROW_RANGE
    g_crossed = bvec4(false);
    g_min_taken = g_center;
    g_max_taken = g_center;
#endif
}

#if FILTER == FILTER_NARROW_RANGE && NORMAL_GUIDE && !IMAGE_BORDER
// The guide's one-sided limits away from the image's ends: the pair is taken as the packed
// walk's tap_pair takes it (no tap lies past an end), each side weighed by its limit, and the
// fit's sums added (the same sums as the general one below, fewer operations).
void tap_pair(int k, vec4 za, vec4 zb, vec4 value_a, vec4 value_b) {
    vec4 w = gaussian_next();
    float kf = float(k);
    bvec4 in_reach = lessThanEqual(vec4(kf), g_reach);
    bvec4 valid_a = both(greaterThan(za, vec4(0.0)), lessThanEqual(za, g_upper));
    bvec4 valid_b = both(greaterThan(zb, vec4(0.0)), lessThanEqual(zb, g_upper));
    bvec4 accept = both(both(in_reach, both(valid_a, valid_b)), pair_kept(za, zb, kf));
    za = narrow_range_sample(za, accept);
    zb = narrow_range_sample(zb, accept);
    vec4 wa = mix(vec4(0.0), w * clamp(g_limit_plus - (kf - 0.5), 0.0, 1.0), accept);
    vec4 wb = mix(vec4(0.0), w * clamp(g_limit_minus - (kf - 0.5), 0.0, 1.0), accept);
    vec4 ua = inverse_depth(za);
    vec4 ub = inverse_depth(zb);
    g_sum += wa * ua + wb * ub;
    vec4 da = ua - g_inverse_centre;
    vec4 db = ub - g_inverse_centre;
    g_weight_sum += wa + wb;
    g_k_sum += kf * (wa - wb);
    g_kk_sum += kf * kf * (wa + wb);
    g_kd_sum += kf * (wa * da - wb * db);
}

#elif FILTER == FILTER_NARROW_RANGE
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
    // the pair test where both taps lie inside the image (a side alone has no midpoint)
    bvec4 kept = either(pair_test(za, zb), either(out_a, out_b));
#if CREASE_TEST
    // past a crease no tap is taken, one-sided or not; a tap past the end is no surface to it
    bvec4 creased = crease_met(mix(za, vec4(0.0), out_a), mix(zb, vec4(0.0), out_b), kf);
    kept = both(kept, not(creased));
#endif
    use_a = both(use_a, kept);
    use_b = both(use_b, kept);
    za = narrow_range_sample(za, use_a);
    zb = narrow_range_sample(zb, use_b);
#if NORMAL_GUIDE
    vec4 wa = mix(vec4(0.0), w * guide_limit_weight(kf), use_a);
    vec4 wb = mix(vec4(0.0), w * guide_limit_weight(-kf), use_b);
    vec4 ua = inverse_depth(za);
    vec4 ub = inverse_depth(zb);
    g_sum += wa * ua + wb * ub;
    g_weight_sum += wa + wb;
#else
    vec4 wa = mix(vec4(0.0), w, use_a);
    vec4 wb = mix(vec4(0.0), w, use_b);
    // A pair adds what tap_pair adds, bit for bit.
    bvec4 pair = both(use_a, use_b);
    vec4 ua = inverse_depth(za);
    vec4 ub = inverse_depth(zb);
    g_sum += mix(wa * ua + wb * ub, w * (ua + ub), pair);
    g_weight_sum += mix(wa + wb, 2.0 * w, pair);
#endif
    g_k_sum += kf * (wa - wb);
    g_kk_sum += kf * kf * (wa + wb);
    vec4 uc = inverse_depth(g_center);
    g_kd_sum += kf * (wa * (ua - uc) - wb * (ub - uc));
}

#else
// The Gaussian's and the bilateral's tap_pair where a tap may lie past an end: the same sums
// (a tap past the end reads 0, so it is skipped like background), and the fit's.
void tap_pair(int k, vec4 za, vec4 zb, vec4 value_a, vec4 value_b) {
    vec4 w = gaussian_next();
    float kf = float(k);
    bvec4 in_reach = lessThanEqual(vec4(kf), g_reach);
    vec4 ta;
    vec4 tb;
    bvec4 use_a;
    bvec4 use_b;
    spatial_taps(w, in_reach, za, zb, ta, tb, use_a, use_b);
    bvec4 out_a = lessThan(g_room_ahead, vec4(kf));
    bvec4 out_b = lessThan(g_room_behind, vec4(kf));
    g_crossed = either(g_crossed, both(in_reach, either(out_a, out_b)));
    g_k_sum += kf * (ta - tb);
    g_kk_sum += kf * kf * (ta + tb);
    g_kd_sum += kf * (ta * (za - g_center) - tb * (zb - g_center));
    g_min_taken = min(g_min_taken, mix(g_min_taken, za, use_a));
    g_min_taken = min(g_min_taken, mix(g_min_taken, zb, use_b));
    g_max_taken = max(g_max_taken, mix(g_max_taken, za, use_a));
    g_max_taken = max(g_max_taken, mix(g_max_taken, zb, use_b));
}
#endif

// The weighted mean `mean` of the values (narrow range: inverse depths), or where the kernel
// went one-sided at an image end the line fit's intercept, kept within the values the kernel
// can have taken.
vec4 image_border_fit(vec4 mean) {
#if FILTER == FILTER_NARROW_RANGE
    vec4 centre = inverse_depth(g_center);
    vec4 low = inverse_depth(g_upper);
    vec4 high = inverse_depth(min(g_lower, g_lower_clamp));
#if NORMAL_GUIDE
    bvec4 one_sided = bvec4(true);  // the guide's weights are seldom symmetric
#else
    bvec4 one_sided = notEqual(g_k_sum, vec4(0.0));  // only an image end unpairs a tap
#endif
#else
    vec4 centre = g_center;
    vec4 low = 2.0 * g_min_taken - g_max_taken;  // the range taken, widened by its width:
    vec4 high = 2.0 * g_max_taken - g_min_taken; // a curved surface's end may lie beyond it
    bvec4 one_sided = g_crossed;  // background unpairs taps too: not fitted (as inside)
#endif
    return border_line_fit(mean, centre, g_weight_sum, g_k_sum, g_kk_sum, g_kd_sum, low, high,
                           one_sided);
}
