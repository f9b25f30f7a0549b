#version 430 core
// Normals from the smoothed depth (thesis §3.2): view positions through the inverse projection,
// then per axis a difference of neighbouring positions, cross product, rotated to world space.
// Per axis:
// * wide central difference (quality.normal_stencil > 0): over +-s pixels, s = the stencil in
//   projected particle radii (capped at u_stencil_max_px), when every pixel of the stencil is
//   the same surface (no discontinuity, see below), blended with the 1-pixel difference below
//   by the kink test: its weight falls smoothly from 1 where the two one-sided slopes over s
//   pixels agree through 1/2 where they differ by u_kink times the larger (or than one pixel
//   footprint on a surface facing the camera: a crease, a rim or a junction differs by more)
//   to 0 at twice that. A central difference over s pixels is second-order accurate on a smooth
//   surface and averages the residual per-particle ripple of the smoothed depth, which the
//   1-pixel difference turns into normal noise (flicker); the smooth weight (which starts
//   quadratically, so smooth surfaces keep the central difference) leaves no switch for a
//   particle's small move to flip: the dam break's flicker 0.973 -> 0.959 deg at 960x540
//   (u_smooth_rules false, quality.normal_rules = "hard": the weight is 1 up to the limit, 0
//   beyond it: a plain switch);
// * otherwise the one-sided differences of the two neighbours, each weighted by the square of
//   the other's depth step, so the smaller step dominates (silhouettes do not smear) and a
//   ridge or a valley between equal steps averages them instead of flipping between them
//   ("hard" rules: the difference with the smaller step alone). A neighbour is never
//   differenced across a depth discontinuity (background, or a jump of more than u_edge_jump)
//   when the pixel has a neighbour of its own surface along the axis. Without one: toward the
//   single nearer neighbour, if exactly one (a surface seen edge-on behind it, see
//   one_sided_difference), else the depth is taken as constant along it.
// Output: world normal (xyz), eye depth (w); all zero where there is no surface.

#include "common/depth_image.glsl"

uniform sampler2D u_depth;
uniform vec2 u_tan_half_fov;     // (tan(fov_y / 2) * aspect, tan(fov_y / 2))
uniform mat3 u_view_to_world;
uniform float u_edge_jump;       // largest depth step between neighbours of one surface
uniform float u_edge_jump_px;    // ... per unit of pixel footprint (z / focal length)
uniform float u_focal_px;        // pixels per unit at eye depth 1
uniform float u_particle_radius; // scene units
uniform float u_stencil_radii;   // wide stencil half-width in projected radii; 0 = 1-pixel only
uniform int u_stencil_max_px;
uniform float u_kink;            // largest relative difference of the two one-sided slopes
uniform bool u_smooth_rules;     // quality.normal_rules: smooth (true) or hard (the header's
                                 // switches: the kink test cuts, the smaller step wins)

layout(location = 0) out vec4 out_normal_depth;

vec3 one_sided_difference(ivec2 center, vec3 position, float zc, ivec2 step, ivec2 size) {
    float z_plus = fetch_depth(u_depth, center + step);
    float z_minus = fetch_depth(u_depth, center - step);
    float jump = max(u_edge_jump, u_edge_jump_px * zc / u_focal_px);
    bool has_plus = z_plus > 0.0 && abs(z_plus - zc) <= jump;
    bool has_minus = z_minus > 0.0 && abs(z_minus - zc) <= jump;
    if (has_plus && has_minus && u_smooth_rules) {
        vec3 plus = view_position(center + step, size, u_tan_half_fov, z_plus) - position;
        vec3 minus = position - view_position(center - step, size, u_tan_half_fov, z_minus);
        float step_plus = (z_plus - zc) * (z_plus - zc);
        float step_minus = (zc - z_minus) * (zc - z_minus);
        float total = step_plus + step_minus;
        return total > 0.0 ? (step_minus * plus + step_plus * minus) / total : plus;
    }
    if (has_plus && (!has_minus || abs(z_plus - zc) <= abs(zc - z_minus))) {
        return view_position(center + step, size, u_tan_half_fov, z_plus) - position;
    }
    if (has_minus) {
        return position - view_position(center - step, size, u_tan_half_fov, z_minus);
    }
    // No neighbour of this surface along the axis. With exactly one neighbour nearer (the other
    // background or farther) the pixel is a surface seen edge-on behind it, the rim of what
    // runs away from that neighbour: difference toward it, a steep slope. Facing the camera
    // instead (the fallback below) mirrors what lies behind the camera: sparkles along rims.
    // A lone pixel, or one between two nearer neighbours (a slit): no depth change across it.
    bool near_plus = z_plus > 0.0 && z_plus < zc;
    bool near_minus = z_minus > 0.0 && z_minus < zc;
    if (near_plus && !near_minus) {
        return view_position(center + step, size, u_tan_half_fov, z_plus) - position;
    }
    if (near_minus && !near_plus) {
        return position - view_position(center - step, size, u_tan_half_fov, z_minus);
    }
    return view_position(center + step, size, u_tan_half_fov, zc) - position;
}

// The central difference over +-s pixels, blended with the one-sided one by the kink test, or
// the one-sided one alone where the stencil crosses a discontinuity (see the header).
vec3 axis_difference(ivec2 center, vec3 position, float zc, ivec2 step, ivec2 size, int s) {
    if (s >= 1) {
        float jump = max(u_edge_jump, u_edge_jump_px * zc / u_focal_px);
        bool same = true;
        float z_prev_plus = zc;
        float z_prev_minus = zc;
        for (int k = 1; k <= s; ++k) {
            float zp = fetch_depth(u_depth, center + k * step);
            float zm = fetch_depth(u_depth, center - k * step);
            same = same && zp > 0.0 && zm > 0.0 && abs(zp - z_prev_plus) <= jump
                && abs(zm - z_prev_minus) <= jump;
            z_prev_plus = zp;
            z_prev_minus = zm;
        }
        float d_plus = z_prev_plus - zc;
        float d_minus = zc - z_prev_minus;
        float floor_depth = float(s) * zc / u_focal_px;  // s pixel footprints
        float limit = u_kink * max(max(abs(d_plus), abs(d_minus)), floor_depth);
        float kink = abs(d_plus - d_minus) / limit;
        float hard = kink <= 1.0 ? 1.0 : 0.0;
        float wide = !same ? 0.0 : u_smooth_rules ? 1.0 - smoothstep(0.0, 2.0, kink) : hard;
        if (wide > 0.0) {
            vec3 a = view_position(center + s * step, size, u_tan_half_fov, z_prev_plus);
            vec3 b = view_position(center - s * step, size, u_tan_half_fov, z_prev_minus);
            vec3 central = (a - b) / (2.0 * float(s));
            if (wide >= 1.0) {
                return central;
            }
            return mix(one_sided_difference(center, position, zc, step, size), central, wide);
        }
    }
    return one_sided_difference(center, position, zc, step, size);
}

void main() {
    ivec2 center = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(u_depth, 0);
    float zc = fetch_depth(u_depth, center);
    if (zc <= 0.0) {
        out_normal_depth = vec4(0.0);
        return;
    }
    vec3 position = view_position(center, size, u_tan_half_fov, zc);
    float radius_px = u_particle_radius * u_focal_px / zc;
    int s = u_stencil_radii > 0.0
        ? clamp(int(round(u_stencil_radii * radius_px)), 1, max(u_stencil_max_px, 1)) : 0;
    vec3 ddx = axis_difference(center, position, zc, ivec2(1, 0), size, s);
    vec3 ddy = axis_difference(center, position, zc, ivec2(0, 1), size, s);
    vec3 normal = cross(ddx, ddy);
    float len = length(normal);
    normal = len > 0.0 ? normal / len : -normalize(position);
    if (dot(normal, position) > 0.0) {
        normal = -normal;  // face the camera
    }
    out_normal_depth = vec4(normalize(u_view_to_world * normal), zc);
}
