#version 330 core
// Separable depth smoothing (thesis §3.3) on a packed eye-depth image: texel (x, y) holds pixels
// 4x .. 4x+3 of row y in .xyzw (0 = background), so one fragment filters four horizontally
// adjacent pixels, one per component. Same filters and kernel rule as smooth_depth.frag.glsl
// (which does the 2-D kernels); packing only changes how often the image is read: 4x fewer
// fetches along columns, 16x fewer along rows (common/packed_taps.glsl). llvmpipe spends most
// of a 1-D pass on texel fetches, so this is where the time goes.
// Every tap is applied in the same order as in the unpacked filter (offset 1, 2, ... outwards,
// the mirror pair together), which the narrow-range filter's growing range depends on.

#define FILTER_GAUSSIAN 0
#define FILTER_BILATERAL 1
#define FILTER_NARROW_RANGE 2
#define FILTER 2
// 0: filter along rows (x), 1: along columns (y).
#define AXIS 0
#define KERNEL_SIZE_PROJECTED_RADIUS 0
#define KERNEL_SIZE_DEPTH_FALLOFF 1
#define KERNEL_SIZE 0
// 1: the variant passes/smooth.py draws where a kernel may reach past the image's ends (within
// kernel_max_px of them): there the kernel goes on one-sided and fits a line
// (image_border_taps.glsl); the same result as 0 wherever no kernel reaches that far.
#define IMAGE_BORDER 0
// 1: the narrow range's crease test (quality.crease_angle) is compiled in.
#define CREASE_TEST 0
// 1: the narrow range's normal guide (quality.normal_guide): a tap is weighed by its offset
// against the centre's one-sided limits (guide_limits.frag.glsl, u_guide_limits), and the
// result is a weighted line fit (image_border_taps.glsl).
#define NORMAL_GUIDE 0
// Those limits are at 1 / GUIDE_SCALE of the image's size (passes/smooth.py GUIDE_SCALE):
// texel (x, y) holds reduced pixels 4x .. 4x+3 of row y, in reduced pixels.
#define GUIDE_SCALE 4

// The depth is its own guide (common/packed_taps.glsl).
#define PACKED_VALUE 0

#include "common/depth_filter_params.glsl"
#include "common/gaussian_steps.glsl"
#include "common/packed_image.glsl"

uniform sampler2D u_packed_depth;
// The kernel's sigma times this: per pass, from quality.last_pass_sigma and quality.destreak
// (passes/smooth.py separable_passes); 1 for equal passes.
uniform float u_sigma_scale;
// The narrow range's pair limit (quality.narrow_range_pairs x r, scene units) on this pass;
// 3e38 where it is off (passes/smooth.py: always on the first pass).
uniform float u_nr_pair_limit;
// The crease test's turn limit on this pass: tan(quality.crease_angle); negative: off.
uniform float u_crease_limit;
#if NORMAL_GUIDE
uniform sampler2D u_guide_limits;  // packed (guide_limits.frag.glsl)
vec4 g_limit_plus;   // the lanes' limits along +AXIS and -AXIS, pixels
vec4 g_limit_minus;
vec4 g_inverse_centre;  // 1 / the centre's depth
#endif

layout(location = 0) out vec4 out_packed_depth;

// Per-pixel filter state; component i belongs to pixel 4x + i.
vec4 g_center;
vec4 g_reach;          // kernel radius in pixels; 0 for background pixels
vec4 g_sum;
vec4 g_weight_sum;
#if FILTER == FILTER_NARROW_RANGE
vec4 g_upper;
vec4 g_lower;
vec4 g_lower_clamp;
#if CREASE_TEST
vec4 g_run_start;      // offset where the current run of turning pairs began; -1: none
bvec4 g_crease;        // the kernel met a crease: no tap further out is taken
vec4 g_radius_px;      // the projected particle radius, per lane
#endif
#endif

#if FILTER == FILTER_NARROW_RANGE
// The narrow range averages inverse depth: over a plane 1/z is affine in the image, so a
// plane seen in perspective comes out of the filter unchanged, where an average of z would
// bend it by half its second derivative times sigma^2 (0.12 r on a slab seen from 0.3 units at
// 35 degrees) and tilt its normals where the kernel's size changes. Finite for background 0.
vec4 inverse_depth(vec4 z) {
    return 1.0 / max(z, vec4(1e-30));
}

// Whether a mirrored pair (za at +k, zb at -k) stays on the centre's surface: its midpoint in
// inverse depth departs from the centre's by at most the pair limit, as a depth difference
// (d(1/z) x z^2). A plane's pair never departs (1/z is affine in the image over a plane, at
// any slope and kernel length); a pair whose taps both lie on a surface h behind (a blob
// narrower than the kernel, in front of a pool) departs by about h, a pair across one step
// of h by h / 2.
bvec4 pair_test(vec4 za, vec4 zb) {
    vec4 mid = 0.5 * (inverse_depth(za) + inverse_depth(zb)) - inverse_depth(g_center);
    return lessThanEqual(abs(mid) * g_center * g_center, vec4(u_nr_pair_limit));
}
#if CREASE_TEST
// A crease (two flat faces meeting at an edge) turns the surface by a large angle within the
// kernel, a sphere of radius R by the kernel's length over R only. Where the chords from the
// centre to the pair's two taps turn by more than crease_angle for a projected radius of taps
// in a row (the relief between particles turns them for a tap or two), no further tap is taken:
// the faces are not averaged across the edge. Taps off the centre's surface never count.
// Called once per pair, in order from the centre outwards.
bvec4 crease_met(vec4 za, vec4 zb, float k) {
    // within the narrow range's band: neither behind it (dropped) nor in front (clamped)
    bvec4 on_surface = both(both(greaterThanEqual(za, g_lower), lessThanEqual(za, g_upper)),
                            both(greaterThanEqual(zb, g_lower), lessThanEqual(zb, g_upper)));
    // the chords' slopes da / step, db / step turn by more than L where
    // |da - db| step > tan(L) (step^2 + da db): tan of their angle's difference, without atan
    // (and always where step^2 + da db <= 0: a turn of 90 degrees or more)
    vec4 step = k * g_center / u_px_per_unit;  // the taps' lateral offset, scene units
    vec4 da = za - g_center;
    vec4 db = g_center - zb;
    vec4 turn_excess = abs(da - db) * step - u_crease_limit * (step * step + da * db);
    bvec4 over = both(on_surface, greaterThan(turn_excess, vec4(0.0)));
    over = both(over, bvec4(u_crease_limit >= 0.0));
    vec4 started = mix(g_run_start, vec4(k), lessThan(g_run_start, vec4(0.0)));
    g_run_start = mix(vec4(-1.0), started, over);
    g_crease = either(g_crease, both(over, greaterThanEqual(vec4(k) - g_run_start, g_radius_px)));
    return g_crease;
}
#endif

// pair_test and the crease test together: whether the pair at +-k is taken.
bvec4 pair_kept(vec4 za, vec4 zb, float k) {
#if CREASE_TEST
    return both(pair_test(za, zb), not(crease_met(za, zb, k)));
#else
    return pair_test(za, zb);
#endif
}

// One sample `z` of the narrow range: clamped to z_centre - mu r when in front by more than
// lambda r, else (when `use`d) it grows the accepted range around itself; returns the value
// the sample adds.
vec4 narrow_range_sample(vec4 z, bvec4 use) {
    bvec4 in_front = lessThan(z, g_lower);
    z = mix(z, g_lower_clamp, in_front);
    bvec4 grow = both(use, not(in_front));
    g_upper = mix(g_upper, max(g_upper, z + u_nr_threshold), grow);
    g_lower = mix(g_lower, min(g_lower, z - u_nr_threshold), grow);
    return z;
}
#endif

#if FILTER != FILTER_NARROW_RANGE
// The Gaussian's or the bilateral's taps at +-k of spatial weight w: added to the sums; which
// were taken in use_a, use_b (not: no surface, or past the image's end, which reads 0), their
// weights in wa, wb (0 where not taken). Shared with image_border_taps.glsl, so both add the
// same bits.
void spatial_taps(vec4 w, bvec4 in_reach, vec4 za, vec4 zb, out vec4 wa, out vec4 wb,
                  out bvec4 use_a, out bvec4 use_b) {
    use_a = both(in_reach, greaterThan(za, vec4(0.0)));
    use_b = both(in_reach, greaterThan(zb, vec4(0.0)));
    wa = w;
    wb = w;
#if FILTER == FILTER_BILATERAL
    float inv_two_range2 = 1.0 / (2.0 * u_range_sigma * u_range_sigma);
    vec4 da = za - g_center;
    vec4 db = zb - g_center;
    wa *= exp(-da * da * inv_two_range2);
    wb *= exp(-db * db * inv_two_range2);
#endif
    g_sum += mix(vec4(0.0), wa * za, use_a) + mix(vec4(0.0), wb * zb, use_b);
    g_weight_sum += mix(vec4(0.0), wa, use_a) + mix(vec4(0.0), wb, use_b);
    wa = mix(vec4(0.0), wa, use_a);
    wb = mix(vec4(0.0), wb, use_b);
}
#endif

#include "common/border_fit.glsl"

#if NORMAL_GUIDE
// The guide's weight of the taps at signed offset k: 1 within the lanes' limit on that side,
// falling to 0 over the pixel past it (guide_limits.frag.glsl).
vec4 guide_limit_weight(float signed_k) {
    vec4 limit = signed_k > 0.0 ? g_limit_plus : g_limit_minus;
    return clamp(limit - abs(signed_k) + 0.5, 0.0, 1.0);
}
#endif

#if IMAGE_BORDER || NORMAL_GUIDE
#include "image_border_taps.glsl"
#else
// The taps at offsets +k (za) and -k (zb) of the four pixels (the value arguments repeat them).
void tap_pair(int k, vec4 za, vec4 zb, vec4 value_a, vec4 value_b) {
    vec4 w = gaussian_next();
    bvec4 in_reach = lessThanEqual(vec4(float(k)), g_reach);
#if FILTER == FILTER_NARROW_RANGE
    // Truong & Yuksel 2018: samples behind the centre by more than lambda*r are dropped, with
    // their mirror sample (no one-sided bias); samples in front by more than lambda*r are
    // clamped to z - mu*r; the accepted range grows around every accepted sample.
    bvec4 valid_a = both(greaterThan(za, vec4(0.0)), lessThanEqual(za, g_upper));
    bvec4 valid_b = both(greaterThan(zb, vec4(0.0)), lessThanEqual(zb, g_upper));
    bvec4 accept = both(both(in_reach, both(valid_a, valid_b)), pair_kept(za, zb, float(k)));
    za = narrow_range_sample(za, accept);
    zb = narrow_range_sample(zb, accept);
    g_sum += mix(vec4(0.0), w * (inverse_depth(za) + inverse_depth(zb)), accept);
    g_weight_sum += mix(vec4(0.0), 2.0 * w, accept);
#else
    vec4 wa;
    vec4 wb;
    bvec4 use_a;
    bvec4 use_b;
    spatial_taps(w, in_reach, za, zb, wa, wb, use_a, use_b);
#endif
}
#endif

#include "common/packed_taps.glsl"

// The lanes' kernel radii in pixels for the wanted `sigma`, and the texel's tap spacing past
// the cap: 3 sigma within [kernel_min_px, kernel_max_px x kernel_max_stride]. A kernel takes
// every pixel out to kernel_max_px; close-ups, whose 3 sigma lies past it, go on with every
// stride-th pixel (each tap standing for `stride` pixels) out to 3 sigma, stride =
// ceil(reach / kernel_max_px): fewer than 2 kernel_max_px taps, and sigma stays kernel_scale
// radii where a hard cap would shrink it and leave the particles' ripple. Spread taps only
// where the Gaussian's tail lies: near the centre they would alias the detail finer than the
// stride (spread from the first tap on: 3.2 deg on the spatter pool at stride 2, against 1.3
// capped). The stride follows the texel's smallest surface lane; the other lanes are cut to
// kernel_max_px x it (a lane at a discontinuity keeps that kernel). Spread taps never reach
// past the image's ends (the border variant's one-sided fit is the cap's): a kernel ends at
// the lane's room to them, which shrinks it continuously to the cap as a lane nears an end.
vec4 kernel_reach(ivec2 texel, vec4 sigma, bvec4 surface, out int stride) {
    float cap = float(u_kernel_max_px);
    vec4 limit = vec4(cap * float(u_kernel_max_stride));
#if IMAGE_BORDER
    limit = vec4(cap);
#else
    vec4 room_ahead;
    vec4 room_behind;
    image_end_room(texel, room_ahead, room_behind);
    limit = min(limit, max(vec4(cap), min(room_ahead, room_behind)));
#endif
    vec4 reach = min(max(ceil(3.0 * sigma), vec4(float(u_kernel_min_px))), limit);  // clamp
    vec4 lane_stride = ceil(reach / cap);
    vec4 smallest = mix(vec4(float(u_kernel_max_stride)), lane_stride, surface);
    stride = int(max(min(min(smallest.x, smallest.y), min(smallest.z, smallest.w)), 1.0));
    return min(reach, vec4(cap * float(stride)));
}

#if NORMAL_GUIDE
// The limits of reduced pixel `reduced` (clamped to the reduced image) in full pixels, each
// measured from the full pixel `offset` pixels past its block's centre along +AXIS.
void reduced_limits(ivec2 reduced, float offset, out float plus, out float minus) {
    ivec2 size = ivec2((u_image_size_px + GUIDE_SCALE - 1) / GUIDE_SCALE);
    reduced = clamp(reduced, ivec2(0), size - 1);
    float code = texelFetch(u_guide_limits, ivec2(reduced.x >> 2, reduced.y), 0)[reduced.x & 3];
    float code_plus = floor(code / 4096.0);
    float code_minus = code - code_plus * 4096.0;
    float scale = float(GUIDE_SCALE) / 8.0;
    plus = code_plus >= 4095.0 ? 3e4 : code_plus * scale - offset;
    minus = code_minus >= 4095.0 ? 3e4 : code_minus * scale + offset;
}

// Two limits' blend by `f`, each taken at most `far` (past the kernel's reach, where a limit
// cuts nothing): a crease's limit fades out over the line past its end, with no step.
float blend_limits(float a, float b, float f, float far) {
    return mix(min(a, far), min(b, far), f);
}

// g_limit_plus / g_limit_minus from the reduced limits: along AXIS the lane's own block, its
// offset from the block's centre taken off; across AXIS blended between the two nearest
// reduced rows (AXIS 0) or columns (AXIS 1), so a slanted crease does not step every block.
void guide_limits_scaled(ivec2 texel) {
    for (int i = 0; i < 4; ++i) {
        ivec2 pixel = ivec2(4 * texel.x + i, texel.y);
        int along = AXIS == 0 ? pixel.x : pixel.y;
        float across = (float(AXIS == 0 ? pixel.y : pixel.x) + 0.5) / float(GUIDE_SCALE) - 0.5;
        float offset = float(along - (along / GUIDE_SCALE) * GUIDE_SCALE)
                       + 0.5 - 0.5 * float(GUIDE_SCALE);
        int first = int(floor(across));
        float f = across - float(first);
        ivec2 a = AXIS == 0 ? ivec2(along / GUIDE_SCALE, first) : ivec2(first, along / GUIDE_SCALE);
        ivec2 b = a + (AXIS == 0 ? ivec2(0, 1) : ivec2(1, 0));
        float plus_a;
        float minus_a;
        float plus_b;
        float minus_b;
        reduced_limits(a, offset, plus_a, minus_a);
        reduced_limits(b, offset, plus_b, minus_b);
        float far = g_reach[i] + 0.5;
        g_limit_plus[i] = blend_limits(plus_a, plus_b, f, far);
        g_limit_minus[i] = blend_limits(minus_a, minus_b, f, far);
    }
}
#endif

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 zc = fetch_packed(u_packed_depth, texel);
    bvec4 surface = greaterThan(zc, vec4(0.0));
    if (!any(surface)) {
        out_packed_depth = vec4(0.0);
        return;
    }
    vec4 z = mix(vec4(1.0), zc, surface);  // background lanes get harmless values, reach 0
#if KERNEL_SIZE == KERNEL_SIZE_PROJECTED_RADIUS
    vec4 sigma = u_kernel_scale * (u_particle_radius * u_px_per_unit / z);
#else
    // Thesis eq 25, read as a continuous decline (see smooth_depth.frag.glsl).
    vec4 sigma = u_falloff_sigma_px - max(z - u_falloff_depth, 0.0) * u_falloff_rate / 3.0;
#endif
    sigma *= u_sigma_scale;
    int stride;
    vec4 reach = kernel_reach(texel, sigma, surface, stride);
    sigma = max(min(sigma, reach / 3.0), 1e-3);
    g_center = zc;
    g_reach = mix(vec4(0.0), reach, surface);
    gaussian_start(sigma);
#if FILTER == FILTER_NARROW_RANGE
    g_sum = inverse_depth(z);
#else
    g_sum = zc;
#endif
    g_weight_sum = vec4(1.0);
#if FILTER == FILTER_NARROW_RANGE
    g_upper = zc + u_nr_threshold;
    g_lower = zc - u_nr_threshold;
    g_lower_clamp = zc - u_nr_clamp;
#if CREASE_TEST
    g_run_start = vec4(-1.0);
    g_crease = bvec4(false);
    g_radius_px = u_particle_radius * u_px_per_unit / z;
#endif
#endif
    int radius = int(max(max(g_reach.x, g_reach.y), max(g_reach.z, g_reach.w)));

#if IMAGE_BORDER || NORMAL_GUIDE
    start_image_border(texel);
#endif
    int dense = min(radius, u_kernel_max_px);
#if NORMAL_GUIDE
    guide_limits_scaled(texel);
    g_inverse_centre = inverse_depth(g_center);
#endif
    walk_packed_taps(u_packed_depth, u_packed_depth, texel, zc, zc, dense);
    // every pixel out to the cap (along rows, whole texels: to the next multiple of 4), then
    // the spread taps (close-ups; kernel_reach)
    int dense_end = AXIS == 0 ? (dense + 3) / 4 * 4 : dense;
    if (radius > dense_end) {
        gaussian_spread(sigma, float(dense_end), float(stride));
        walk_strided_taps(u_packed_depth, texel, dense_end + stride, radius, stride);
    }
    vec4 smoothed = g_sum / g_weight_sum;
#if IMAGE_BORDER || NORMAL_GUIDE
    smoothed = image_border_fit(smoothed);
#endif
#if FILTER == FILTER_NARROW_RANGE
    smoothed = 1.0 / smoothed;
#endif
    out_packed_depth = mix(vec4(0.0), smoothed, surface);
}
