#version 430 core
// The sphere quads of splat_sphere.vert.glsl grown by u_margin (about 1.5 pixels), so the
// coverage pass reaches the pixels just outside each silhouette.

#include "common/sphere_quad.glsl"
#include "common/splat_particles.glsl"

uniform mat4 u_projection;
uniform float u_margin;     // pixels / focal length in pixels

out vec3 v_view_position;
flat out vec4 v_sphere;

void main() {
    vec4 sphere;
    if (!splat_sphere(splat_particle(), sphere)) {
        gl_Position = SPLAT_CULLED;
        return;
    }
    vec3 corner = sphere_quad_corner(sphere.xyz, sphere.w, splat_corner(), u_margin);
    v_view_position = corner;
    v_sphere = sphere;
    gl_Position = u_projection * vec4(corner, 1.0);
}
