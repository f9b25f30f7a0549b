#version 330 core
// The sphere quads of splat_sphere.vert.glsl grown by u_margin (about 1.5 pixels), so the
// coverage pass reaches the pixels just outside each silhouette.

#include "common/sphere_quad.glsl"

in vec2 in_corner;
in vec4 in_center_radius;   // view-space centre and radius, as for the splat

uniform mat4 u_projection;
uniform float u_margin;     // pixels / focal length in pixels

out vec3 v_view_position;
flat out vec4 v_sphere;

void main() {
    vec3 corner = sphere_quad_corner(in_center_radius.xyz, in_center_radius.w, in_corner, u_margin);
    v_view_position = corner;
    v_sphere = in_center_radius;
    gl_Position = u_projection * vec4(corner, 1.0);
}
