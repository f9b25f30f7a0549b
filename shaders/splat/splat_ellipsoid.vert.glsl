#version 430 core
// Ellipsoid impostors (Yu & Turk's anisotropic particles, sph/anisotropy.py): the quad of the
// ellipsoid's bounding sphere (common/sphere_quad.glsl; radius = the longest semi-axis), which
// holds its silhouette, plus u_margin for the coverage pass. The fragment stage intersects the
// ray with the ellipsoid { c + A u : |u| <= 1 } in the frame of its axes.

#include "common/sphere_quad.glsl"
#include "common/splat_particles.glsl"

uniform mat4 u_projection;
uniform float u_margin;     // pixels / focal length in pixels (0 for the depth splat)

out vec3 v_view_position;
flat out vec3 v_center;
flat out mat3 v_to_unit;    // view offsets -> unit-sphere coordinates: rows a_k / |a_k|^2
flat out vec2 v_temperature;   // kelvin, peak kelvin

void main() {
    uint particle = splat_particle();
    vec4 sphere;
    if (!splat_sphere(particle, sphere)) {
        gl_Position = SPLAT_CULLED;
        return;
    }
    vec3 corner = sphere_quad_corner(sphere.xyz, sphere.w, splat_corner(), u_margin);
    v_view_position = corner;
    v_center = sphere.xyz;
    vec3 a0 = splat_axis(particle, 0);
    vec3 a1 = splat_axis(particle, 1);
    vec3 a2 = splat_axis(particle, 2);
    // A has orthogonal columns, so A^-1 = diag(1 / |a_k|^2) A^T: its rows are a_k / |a_k|^2.
    v_to_unit = transpose(mat3(a0 / dot(a0, a0), a1 / dot(a1, a1), a2 / dot(a2, a2)));
    v_temperature = splat_kelvin(particle);
    gl_Position = u_projection * vec4(corner, 1.0);
}
