#version 330 core
// Normals from the smoothed depth (thesis §3.2): view positions through the inverse projection,
// then per axis the one-sided difference with the smaller depth change (so silhouettes do not
// smear), cross product, rotated to world space. A neighbour is never differenced across a
// depth discontinuity: background, or a jump of more than u_edge_jump (a farther or nearer
// surface); with no usable neighbour along an axis the depth is taken as constant along it.
// Output: world normal (xyz), eye depth (w); all zero where there is no surface.

#include "common/depth_image.glsl"

uniform sampler2D u_depth;
uniform vec2 u_tan_half_fov;     // (tan(fov_y / 2) * aspect, tan(fov_y / 2))
uniform mat3 u_view_to_world;
uniform float u_edge_jump;       // largest depth step between neighbours of one surface
uniform float u_edge_jump_px;    // ... per unit of pixel footprint (z / focal length)
uniform float u_focal_px;        // pixels per unit at eye depth 1

layout(location = 0) out vec4 out_normal_depth;

vec3 one_sided_difference(ivec2 center, vec3 position, float zc, ivec2 step, ivec2 size) {
    float z_plus = fetch_depth(u_depth, center + step);
    float z_minus = fetch_depth(u_depth, center - step);
    float jump = max(u_edge_jump, u_edge_jump_px * zc / u_focal_px);
    bool has_plus = z_plus > 0.0 && abs(z_plus - zc) <= jump;
    bool has_minus = z_minus > 0.0 && abs(z_minus - zc) <= jump;
    if (has_plus && (!has_minus || abs(z_plus - zc) <= abs(zc - z_minus))) {
        return view_position(center + step, size, u_tan_half_fov, z_plus) - position;
    }
    if (has_minus) {
        return position - view_position(center - step, size, u_tan_half_fov, z_minus);
    }
    // Isolated in this direction: assume no depth change across the pixel.
    return view_position(center + step, size, u_tan_half_fov, zc) - position;
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
    vec3 ddx = one_sided_difference(center, position, zc, ivec2(1, 0), size);
    vec3 ddy = one_sided_difference(center, position, zc, ivec2(0, 1), size);
    vec3 normal = cross(ddx, ddy);
    float len = length(normal);
    normal = len > 0.0 ? normal / len : -normalize(position);
    if (dot(normal, position) > 0.0) {
        normal = -normal;  // face the camera
    }
    out_normal_depth = vec4(normalize(u_view_to_world * normal), zc);
}
