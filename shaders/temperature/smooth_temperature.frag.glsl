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
    walk_packed_taps(u_packed_depth, u_packed_temperature, texel, zc, tc, radius);
    out_packed_temperature = mix(vec4(0.0), g_sum / g_weight_sum, surface);
}
