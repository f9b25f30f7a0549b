#version 430 core
// Sphere impostors (thesis §3.1) as quads, so a sprite may be any size (point sprites are capped
// at 255 px by llvmpipe). Each quad is perpendicular to the ray from the eye to the sphere centre
// and just large enough to contain the sphere's silhouette cone: half-size
// s = r d / sqrt(d^2 - r^2), d = |centre| (common/sphere_quad.glsl). The particle comes from the
// storage buffers (common/splat_particles.glsl); culled particles leave the clip volume.

#include "common/sphere_quad.glsl"
#include "common/splat_particles.glsl"

uniform mat4 u_projection;

out vec3 v_view_position;   // point on the quad, view space; interpolated perspective-correctly
flat out vec4 v_sphere;     // view-space centre and radius
flat out vec2 v_temperature;   // kelvin, peak kelvin

void main() {
    uint particle = splat_particle();
    vec4 sphere;
    if (!splat_sphere(particle, sphere)) {
        gl_Position = SPLAT_CULLED;
        return;
    }
    vec3 corner = sphere_quad_corner(sphere.xyz, sphere.w, splat_corner(), 0.0);
    v_view_position = corner;
    v_sphere = sphere;
    v_temperature = splat_kelvin(particle);
    gl_Position = u_projection * vec4(corner, 1.0);
}
