#version 330 core
// Ellipsoid impostors (Yu & Turk's anisotropic particles, sph/anisotropy.py): the quad of the
// ellipsoid's bounding sphere (common/sphere_quad.glsl; radius = the longest semi-axis), which
// holds its silhouette, plus u_margin for the coverage pass. The fragment stage intersects the
// ray with the ellipsoid { c + A u : |u| <= 1 } in the frame of its axes.

#include "common/sphere_quad.glsl"

in vec2 in_corner;          // per vertex: (+-1, +-1)
in vec4 in_center_radius;   // view-space centre (float32 after float64 subtraction), bounding radius
in vec3 in_axis0;           // view-space semi-axes (the columns of A), orthogonal
in vec3 in_axis1;
in vec3 in_axis2;
in float in_temperature;    // kelvin; not bound (constant 0) when the frame has none

uniform mat4 u_projection;
uniform float u_margin;     // pixels / focal length in pixels (0 for the depth splat)

out vec3 v_view_position;
flat out vec3 v_center;
flat out mat3 v_to_unit;    // view offsets -> unit-sphere coordinates: rows a_k / |a_k|^2
flat out float v_temperature;

void main() {
    vec3 corner = sphere_quad_corner(in_center_radius.xyz, in_center_radius.w, in_corner, u_margin);
    v_view_position = corner;
    v_center = in_center_radius.xyz;
    // A has orthogonal columns, so A^-1 = diag(1 / |a_k|^2) A^T: its rows are a_k / |a_k|^2.
    v_to_unit = transpose(mat3(in_axis0 / dot(in_axis0, in_axis0),
                               in_axis1 / dot(in_axis1, in_axis1),
                               in_axis2 / dot(in_axis2, in_axis2)));
    v_temperature = in_temperature;
    gl_Position = u_projection * vec4(corner, 1.0);
}
