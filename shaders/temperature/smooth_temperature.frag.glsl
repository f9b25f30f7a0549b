#version 330 core
// Depth-aware separable Gaussian blur of the splatted temperature, on packed images (four pixels
// per texel, common/packed_image.glsl); run once along x (AXIS 0) and once along y (AXIS 1)
// inside the shade stage. The splat stores the temperature of the front-most sphere per pixel, a
// mosaic of discs; the smoothed depth surface needs a field as smooth as itself. Sigma follows
// the projected particle radius like the depth filter's; samples farther than u_depth_range
// (scene units) from the centre's depth, or off the surface, are ignored, so a hot bead does not
// bleed onto the plate behind it.

// 0: along rows (x), 1: along columns (y).
#define AXIS 0
// 1: the variant passes/temperature.py draws within u_max_reach_px of the image's ends: a tap
// past the end is skipped as before, but where one was, the kernel's one-sided mean becomes
// the intercept of a line fit through the temperatures taken (common/border_fit.glsl), so a
// gradient running out of the image is not shifted. Elsewhere the same bits as 0.
#define IMAGE_BORDER 0
// The smoothed depth guides, the temperature is filtered (common/packed_taps.glsl).
#define PACKED_VALUE 1

#include "common/gaussian_steps.glsl"
#include "common/packed_image.glsl"

uniform sampler2D u_packed_temperature;
uniform sampler2D u_packed_depth;          // smoothed eye depth (0 = no surface)
uniform float u_radius_px_at_unit_depth;   // particle radius * px_per_unit
uniform float u_sigma_radii;               // sigma in projected particle radii
uniform int u_max_reach_px;
uniform float u_depth_range;

layout(location = 0) out vec4 out_packed_temperature;

vec4 g_center;
vec4 g_reach;
vec4 g_sum;
vec4 g_weight_sum;
#if IMAGE_BORDER
#include "common/border_fit.glsl"
vec4 g_room_ahead;   // pixels between each lane's pixel and the image's end along +AXIS
vec4 g_room_behind;  // ... and along -AXIS
bvec4 g_crossed;     // a tap in reach lay past an end
vec4 g_t_center;
vec4 g_k_sum;        // sums of w k, w k^2, w k (t - t_centre) over the samples taken
vec4 g_kk_sum;
vec4 g_kd_sum;
vec4 g_t_min;        // the range of the temperatures taken
vec4 g_t_max;

void start_image_border(ivec2 texel, vec4 tc) {
    image_end_room(texel, g_room_ahead, g_room_behind);
    g_crossed = bvec4(false);
    g_t_center = tc;
    g_k_sum = vec4(0.0);
    g_kk_sum = vec4(0.0);
    g_kd_sum = vec4(0.0);
    g_t_min = tc;
    g_t_max = tc;
}

// The line fit's sums of the taps tap_pair took at +-k (weights wa, wb; 0 when skipped).
void border_taps(float k, vec4 wa, vec4 wb, vec4 ta, vec4 tb, bvec4 in_reach) {
    bvec4 out_a = lessThan(g_room_ahead, vec4(k));
    bvec4 out_b = lessThan(g_room_behind, vec4(k));
    g_crossed = either(g_crossed, both(in_reach, either(out_a, out_b)));
    g_k_sum += k * (wa - wb);
    g_kk_sum += k * k * (wa + wb);
    g_kd_sum += k * (wa * (ta - g_t_center) - wb * (tb - g_t_center));
    g_t_min = min(g_t_min, min(mix(g_t_min, ta, greaterThan(wa, vec4(0.0))),
                               mix(g_t_min, tb, greaterThan(wb, vec4(0.0)))));
    g_t_max = max(g_t_max, max(mix(g_t_max, ta, greaterThan(wa, vec4(0.0))),
                               mix(g_t_max, tb, greaterThan(wb, vec4(0.0)))));
}
#endif

void tap_pair(int k, vec4 za, vec4 zb, vec4 ta, vec4 tb) {
    vec4 w = gaussian_next();
    bvec4 in_reach = lessThanEqual(vec4(float(k)), g_reach);
    bvec4 use_a = both(
        in_reach,
        both(greaterThan(za, vec4(0.0)), lessThanEqual(abs(za - g_center), vec4(u_depth_range)))
    );
    bvec4 use_b = both(
        in_reach,
        both(greaterThan(zb, vec4(0.0)), lessThanEqual(abs(zb - g_center), vec4(u_depth_range)))
    );
    g_sum += mix(vec4(0.0), w * ta, use_a) + mix(vec4(0.0), w * tb, use_b);
    g_weight_sum += mix(vec4(0.0), w, use_a) + mix(vec4(0.0), w, use_b);
#if IMAGE_BORDER
    border_taps(float(k), mix(vec4(0.0), w, use_a), mix(vec4(0.0), w, use_b), ta, tb, in_reach);
#endif
}

#include "common/packed_taps.glsl"

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 zc = fetch_packed(u_packed_depth, texel);
    bvec4 surface = greaterThan(zc, vec4(0.0));
    if (!any(surface)) {
        out_packed_temperature = vec4(0.0);
        return;
    }
    vec4 tc = fetch_packed(u_packed_temperature, texel);
    vec4 z = mix(vec4(1.0), zc, surface);  // background lanes get harmless values, reach 0
    vec4 sigma = max(u_sigma_radii * u_radius_px_at_unit_depth / z, vec4(0.5));
    vec4 reach = min(ceil(3.0 * sigma), vec4(float(u_max_reach_px)));
    sigma = min(sigma, max(reach, vec4(1.0)) / 3.0);
    g_center = zc;
    g_reach = mix(vec4(0.0), reach, surface);
    gaussian_start(sigma);
    g_sum = tc;
    g_weight_sum = vec4(1.0);
    int radius = int(max(max(g_reach.x, g_reach.y), max(g_reach.z, g_reach.w)));
#if IMAGE_BORDER
    start_image_border(texel, tc);
#endif
    walk_packed_taps(u_packed_depth, u_packed_temperature, texel, zc, tc, radius);
    vec4 blurred = g_sum / g_weight_sum;
#if IMAGE_BORDER
    vec4 span = g_t_max - g_t_min;  // kept within the range taken, widened by its width
    blurred = border_line_fit(blurred, g_t_center, g_weight_sum, g_k_sum, g_kk_sum, g_kd_sum,
                              g_t_min - span, g_t_max + span, g_crossed);
#endif
    out_packed_temperature = mix(vec4(0.0), blurred, surface);
}
