#version 330 core
// The spheres under a solid's discs (and the particles with no face): impostor quads as the
// splat's (common/sphere_quad.glsl), one per instance, view-space centres from the host.
#include "common/sphere_quad.glsl"

uniform mat4 u_projection;

in vec2 in_corner;
in vec4 in_sphere;           // per instance: view-space centre, radius
in vec2 in_temperature;  // kelvin, peak kelvin

out vec3 v_view_position;
flat out vec4 v_sphere;
flat out vec2 v_temperature;

void main() {
    vec3 corner = sphere_quad_corner(in_sphere.xyz, in_sphere.w, in_corner, 0.0);
    v_view_position = corner;
    v_sphere = in_sphere;
    v_temperature = in_temperature;
    gl_Position = u_projection * vec4(corner, 1.0);
}
