#version 330 core
// Sphere impostors (thesis §3.1) as instanced quads, so a sprite may be any size (point sprites
// are capped at 255 px by llvmpipe). Each quad is perpendicular to the ray from the eye to the
// sphere centre and just large enough to contain the sphere's silhouette cone:
// half-size s = r d / sqrt(d^2 - r^2), d = |centre| (common/sphere_quad.glsl). The CPU culls
// spheres that contain the eye.

#include "common/sphere_quad.glsl"

in vec2 in_corner;          // per vertex: (+-1, +-1)
in vec4 in_center_radius;   // per particle, on each of its 4 corners: view-space centre (float32 after float64 subtraction), radius
in float in_temperature;    // per particle, kelvin; not bound (constant 0) when the frame has none

uniform mat4 u_projection;

out vec3 v_view_position;   // point on the quad, view space; interpolated perspective-correctly
flat out vec4 v_sphere;     // view-space centre and radius
flat out float v_temperature;

void main() {
    vec3 corner = sphere_quad_corner(in_center_radius.xyz, in_center_radius.w, in_corner, 0.0);
    v_view_position = corner;
    v_sphere = in_center_radius;
    v_temperature = in_temperature;
    gl_Position = u_projection * vec4(corner, 1.0);
}
