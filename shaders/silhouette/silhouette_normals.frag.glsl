#version 330 core
// Silhouette normals (passes/silhouette.py; numpy reference in tests/reference_silhouette.py).
// Near a silhouette the true normal is nearly perpendicular to the view ray and its screen
// direction is the outward normal of the silhouette curve; the depth-differenced normal there
// follows the per-particle beads of the rim and flips sideways. Per surface pixel p (eye depth
// zc from the normals pass's w, projected particle radius r_px = r f / zc):
// * coverage moments over a Gaussian window, sigma = u_rim_radii r_px / 2 (at most
//   RIM_MAX_SIGMA_PX), taps within 2.5 sigma, every pixel (sigma < 2 px) or every other one:
//   C = sum w s / sum w, m = sum w s (q - p) / sum w,
//   s = 1 where q has a surface not farther than zc + u_edge_jump (the same surface or one in
//   front: a surface occluded by a nearer one has no silhouette there), else 0;
// * the rim direction o = -m / |m| (screen space, outward); the distance inside the rim of a
//   straight edge under that window, d = sigma Phi^-1(C), and the rim weight
//   t = clamp(1 - d / (2 sigma), 0, 1) (1 on the rim, 0 from 2 sigma = u_rim_radii r_px in);
// * the normal keeps its angle to the view ray but no less tilted than RIM_TILT t (sine), and
//   turns its screen direction to o: n' = sqrt(1 - c^2) o_perp + c (-ray), c = min(n.(-ray),
//   sqrt(1 - (RIM_TILT t)^2)), o_perp = o made perpendicular to the ray; the result is
//   normalize(mix(n, n', t)).
// Taps outside the image are left out (the image border is no silhouette).
// Unchanged: pixels with no surface, and pixels where C > 0.999 or |m| < 1e-3 px (no edge to
// speak of); the tiles of rim_tiles.frag.glsl find most of them without the window.

#define RIM_MAX_SIGMA_PX 3.0
#define RIM_TILT 0.8
// Taps per half-axis of the window, at most (reach 2.5 RIM_MAX_SIGMA_PX over the stride).
#define RIM_MAX_TAPS 4

#include "common/depth_image.glsl"

uniform sampler2D u_normal_depth;  // world normal (xyz), eye depth (w; 0 = no surface)
uniform sampler2D u_tiles;         // farthest depth within 8 px, per 4 x 4 (rim_tiles.frag.glsl)
uniform vec2 u_tan_half_fov;       // (tan(fov_y / 2) * aspect, tan(fov_y / 2))
uniform mat3 u_view_to_world;
uniform float u_focal_px;          // pixels per unit at eye depth 1
uniform float u_particle_radius;   // scene units
uniform float u_rim_radii;         // rho, the rim's reach in projected particle radii
uniform float u_edge_jump;         // a surface farther by more than this is behind

layout(location = 0) out vec4 out_normal_depth;

// Eye depth at p; -1 outside the image (not a silhouette: those taps are left out).
float depth_at(ivec2 p, ivec2 size) {
    if (any(lessThan(p, ivec2(0))) || any(greaterThanEqual(p, size))) {
        return -1.0;
    }
    return texelFetch(u_normal_depth, p, 0).w;
}

// Giles (2010), "Approximating the erfinv function", single precision.
float erfinv(float x) {
    float w = -log((1.0 - x) * (1.0 + x));
    float p;
    if (w < 5.0) {
        w -= 2.5;
        p = 2.81022636e-08;
        p = 3.43273939e-07 + p * w;
        p = -3.5233877e-06 + p * w;
        p = -4.39150654e-06 + p * w;
        p = 0.00021858087 + p * w;
        p = -0.00125372503 + p * w;
        p = -0.00417768164 + p * w;
        p = 0.246640727 + p * w;
        p = 1.50140941 + p * w;
    } else {
        w = sqrt(w) - 3.0;
        p = -0.000200214257;
        p = 0.000100950558 + p * w;
        p = 0.00134934322 + p * w;
        p = -0.00367342844 + p * w;
        p = 0.00573950773 + p * w;
        p = -0.0076224613 + p * w;
        p = 0.00943887047 + p * w;
        p = 1.00167406 + p * w;
        p = 2.83297682 + p * w;
    }
    return p * x;
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(u_normal_depth, 0);
    vec4 nd = texelFetch(u_normal_depth, p, 0);
    out_normal_depth = nd;
    float zc = nd.w;
    if (zc <= 0.0) {
        return;
    }
    float r_px = u_particle_radius * u_focal_px / zc;
    float sigma = min(0.5 * u_rim_radii * r_px, RIM_MAX_SIGMA_PX);
    float reach = 2.5 * sigma;
    int k_max = int(floor(reach));
    if (k_max < 1) {
        return;
    }
    float limit = zc + u_edge_jump;
    // The dilated 4-pixel tile of rim_tiles.frag.glsl covers +-8 >= k_max pixels: nothing
    // farther than the limit (and no background) there means every tap is covered, C = 1.
    float farthest = texelFetch(u_tiles, p / 4, 0).r;
    if (farthest <= limit) {
        return;
    }
    // Taps every `stride` pixels (2 from sigma 2 px on: the window stays sampled at <= sigma),
    // Gaussian weights g(x) g(y) from a per-offset table.
    int stride = sigma >= 2.0 ? 2 : 1;
    int half_taps = k_max / stride;
    float g[RIM_MAX_TAPS + 1];
    float inv_two_sigma2 = 0.5 / (sigma * sigma);
    for (int i = 0; i <= half_taps; ++i) {
        float x = float(i * stride);
        g[i] = exp(-x * x * inv_two_sigma2);
    }
    float weight_sum = 0.0;
    float covered = 0.0;
    vec2 moment = vec2(0.0);
    float reach2 = reach * reach;
    for (int j = -half_taps; j <= half_taps; ++j) {
        for (int i = -half_taps; i <= half_taps; ++i) {
            ivec2 offset = ivec2(i, j) * stride;
            if (float(offset.x * offset.x + offset.y * offset.y) > reach2) {
                continue;
            }
            float z = depth_at(p + offset, size);
            if (z < 0.0) {
                continue;
            }
            float w = g[abs(i)] * g[abs(j)];
            weight_sum += w;
            if (z > 0.0 && z <= limit) {
                covered += w;
                moment += w * vec2(offset);
            }
        }
    }
    float c_share = covered / weight_sum;
    moment /= weight_sum;
    if (c_share > 0.999 || length(moment) < 1e-3) {
        return;
    }
    vec2 outward = -normalize(moment);
    float c_clamped = clamp(c_share, 1e-4, 1.0 - 1e-4);
    float inside = sigma * sqrt(2.0) * erfinv(2.0 * c_clamped - 1.0);
    // A straight edge at that distance has the first moment sigma phi(d / sigma); a blob
    // smaller than the window (a droplet) has much less: it is no edge to turn towards.
    float u = inside / sigma;
    float edge_moment = sigma * exp(-0.5 * u * u) * 0.3989422804;
    float edge_like = clamp(length(moment) / edge_moment, 0.0, 1.0);
    float t = clamp(1.0 - inside / (2.0 * sigma), 0.0, 1.0) * edge_like;
    if (t <= 0.0) {
        return;
    }
    vec3 ray = normalize(view_position(p, size, u_tan_half_fov, 1.0));
    vec3 n = transpose(u_view_to_world) * nd.xyz;
    vec3 o = vec3(outward, 0.0);
    o = normalize(o - dot(o, ray) * ray);
    float c = clamp(dot(n, -ray), 0.0, 1.0);
    c = min(c, sqrt(1.0 - RIM_TILT * RIM_TILT * t * t));
    vec3 turned = sqrt(max(1.0 - c * c, 0.0)) * o - c * ray;
    vec3 blended = normalize(mix(n, turned, t));
    out_normal_depth = vec4(normalize(u_view_to_world * blended), zc);
}
