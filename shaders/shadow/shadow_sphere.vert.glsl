#version 430 core
// Sphere impostors seen from a light, for its shadow map (passes/shadow.py). The particle is
// pulled from a storage buffer: centre relative to the frame's centre (float64 on the host, then
// float32, so 1e5 coordinates keep their millimetres) and radius. u_cube: one face of a cube map
// around the light (90 degree frustum looking along -z of `u_face`); otherwise an orthographic
// map looking along +z of `u_face` from the plane z = 0 through `u_origin`. (A uniform, not a
// define: the program cache applies defines to the fragment stage only.)

#include "common/sphere_quad.glsl"

layout(std430, binding = 25) readonly buffer ShadowSpheres { vec4 shadow_spheres[]; };

uniform vec3 u_origin;      // cube: the light; ortho: the map's near-plane centre (frame-relative)
uniform mat3 u_face;        // frame axes -> map axes
uniform vec2 u_half_extent; // ortho: half width and height of the map, scene units
uniform vec2 u_near_far;    // cube: clip planes of the face's frustum
uniform bool u_cube;

out vec3 v_position;        // point on the quad, map axes
flat out vec4 v_sphere;     // centre (map axes) and radius

const vec4 CULLED = vec4(2.0, 2.0, 2.0, 1.0);

// A face of the cube: a sphere wholly behind the face, or one holding the light (it would hide
// everything and has no silhouette from inside), casts nothing on it.
vec4 cube_corner(vec3 c, float r, vec2 corner) {
    if (r <= 0.0 || c.z > r || dot(c, c) <= r * r) {
        return CULLED;
    }
    vec3 p = sphere_quad_corner(c, r, corner, 0.0);
    float n = u_near_far.x;
    float f = u_near_far.y;
    v_position = p;
    return vec4(p.xy, (-(f + n) * p.z - 2.0 * f * n) / (f - n), -p.z);
}

vec4 ortho_corner(vec3 c, float r, vec2 corner) {
    if (r <= 0.0) {
        return CULLED;
    }
    vec3 p = c + vec3(corner * r, 0.0);
    v_position = p;
    return vec4(p.xy / u_half_extent, 0.0, 1.0);
}

void main() {
    uint particle = uint(gl_VertexID) >> 2;
    int v = gl_VertexID & 3;
    vec2 corner = vec2((v & 1) != 0 ? 1.0 : -1.0, (v & 2) != 0 ? 1.0 : -1.0);
    vec4 s = shadow_spheres[particle];
    vec3 c = u_face * (s.xyz - u_origin);
    v_sphere = vec4(c, s.w);
    v_position = c;
    gl_Position = u_cube ? cube_corner(c, s.w, corner) : ortho_corner(c, s.w, corner);
}
