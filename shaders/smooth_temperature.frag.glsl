#version 330 core
// Separable, depth-aware Gaussian blur of the splatted temperature image (run once along x, once
// along y, inside the shade stage). The splat stores the temperature of the front-most sphere
// per pixel, a mosaic of discs; the smoothed depth surface needs a field as smooth as itself.
// Sigma follows the projected particle radius like the depth filter's; samples farther than
// u_depth_range (scene units) from the centre's depth, or off the surface, are ignored, so a hot
// bead does not bleed onto the plate behind it.

#include "common/depth_image.glsl"

uniform sampler2D u_temperature;
uniform sampler2D u_depth;          // smoothed eye depth (0 = no surface)
uniform ivec2 u_direction;
uniform float u_radius_px_at_unit_depth;  // particle radius * px_per_unit
uniform float u_sigma_radii;        // sigma in projected particle radii
uniform int u_max_reach_px;
uniform float u_depth_range;

layout(location = 0) out float out_temperature;

void main() {
    ivec2 center = ivec2(gl_FragCoord.xy);
    float zc = fetch_depth(u_depth, center);
    float tc = texelFetch(u_temperature, center, 0).r;
    if (zc <= 0.0) {
        out_temperature = 0.0;
        return;
    }
    float sigma = max(u_sigma_radii * u_radius_px_at_unit_depth / zc, 0.5);
    int reach = min(int(ceil(3.0 * sigma)), u_max_reach_px);
    sigma = min(sigma, max(float(reach), 1.0) / 3.0);
    float inv_two_sigma2 = 1.0 / (2.0 * sigma * sigma);
    float sum = tc;
    float weight = 1.0;
    for (int k = -reach; k <= reach; ++k) {
        if (k == 0) {
            continue;
        }
        ivec2 p = center + k * u_direction;
        float z = fetch_depth(u_depth, p);
        if (z <= 0.0 || abs(z - zc) > u_depth_range) {
            continue;
        }
        float w = exp(-float(k * k) * inv_two_sigma2);
        sum += w * texelFetch(u_temperature, p, 0).r;
        weight += w;
    }
    out_temperature = sum / weight;
}
