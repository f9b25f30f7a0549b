#version 430 core
// Device prepare (passes/device_prepare.py): what geometry/prepare.py, occlusion.sphere_bounds
// and screen_box do on the CPU, once per particle on the GPU, so the host only uploads the
// client's arrays. Float64 from the uploaded positions to the view-space centre, as on the CPU
// (coordinates of 1e5 lose nothing); then float32 spheres for the splat (w: radius, negative
// for exact droplets, 0 when culled: common/splat_particles.glsl) and, reduced over all
// particles, the far distance, the screen box and the counts the host reads back.

layout(local_size_x = 256) in;

#include "common/sphere_bounds.glsl"

layout(std430, binding = 0) writeonly buffer SplatSpheres { vec4 spheres[]; };
layout(std430, binding = 3) readonly buffer SplatAxes { float axes[]; };     // 9 per particle
layout(std430, binding = 4) readonly buffer Positions { double positions[]; };  // 3 per particle, world
layout(std430, binding = 5) readonly buffer Radii { float radii[]; };
layout(std430, binding = 6) readonly buffer Droplets { uint droplet_bytes[]; };  // 1 byte per particle
layout(std430, binding = 7) coherent buffer Summary {
    int box[4];       // min x0, min y0, -max x1, -max y1 of the silhouette rectangles (pixels)
    uint far_bits;    // largest eye depth + radius of a visible particle (float bits)
    uint visible;     // particles in front of the camera and inside the image
    uint droplets;    // of those, exact droplets
    uint unbounded;   // visible spheres reaching the eye plane: no rectangle, whole image
    uint near_bits;   // smallest nearest eye depth of a visible particle (float bits, >= 0)
} summary;

uniform uint u_first;       // this dispatch's first particle (dispatches are capped at 65535 groups)
uniform uint u_count;
uniform dvec3 u_eye;
uniform dmat3 u_rotation;     // rows: view axes in world coordinates (v = R (p - eye))
uniform float u_radius;       // every particle's radius when u_has_radii is false
uniform bool u_has_radii;
uniform bool u_has_droplets;
uniform bool u_ellipsoid;     // radius = the longest semi-axis (the bounding sphere)
uniform double u_near;
uniform double u_far_limit;   // the scene's far, or <= 0 for none
uniform dvec2 u_tan_half_fov; // x, y
uniform ivec2 u_size;         // image width, height

shared int s_box[4];
shared uint s_far_bits;
shared uint s_visible;
shared uint s_droplets;
shared uint s_unbounded;
shared uint s_near_bits;

float particle_radius(uint i) {
    if (!u_ellipsoid) {
        return u_has_radii ? radii[i] : u_radius;
    }
    float longest = 0.0;
    for (uint k = 0u; k < 3u; ++k) {
        vec3 column = vec3(axes[i * 9u + k], axes[i * 9u + 3u + k], axes[i * 9u + 6u + k]);
        longest = max(longest, length(column));
    }
    return longest;
}

bool is_droplet(uint i) {
    return u_has_droplets && ((droplet_bytes[i >> 2] >> (8u * (i & 3u))) & 0xffu) != 0u;
}

// camera.visible_mask: in front of the near plane, before far, not around the eye, inside the
// four side planes (with the radius as margin).
bool visible(dvec3 v, double r) {
    double depth = -v.z;
    if (!(depth + r > u_near)) return false;
    if (u_far_limit > 0.0 && !(depth - r < u_far_limit)) return false;
    double grown = r * 1.000001;
    if (!(dot(v, v) > grown * grown)) return false;
    for (int axis = 0; axis < 2; ++axis) {
        double t = u_tan_half_fov[axis];
        double norm = sqrt(1.0 + t * t);
        if (!((t * depth - v[axis]) / norm > -r) || !((t * depth + v[axis]) / norm > -r)) {
            return false;
        }
    }
    return true;
}

void main() {
    if (gl_LocalInvocationIndex == 0u) {
        s_box[0] = 2147483647; s_box[1] = 2147483647; s_box[2] = 2147483647; s_box[3] = 2147483647;
        s_far_bits = 0u; s_visible = 0u; s_droplets = 0u; s_unbounded = 0u;
        s_near_bits = 0x7f800000u;  // +inf
    }
    barrier();
    uint i = u_first + gl_GlobalInvocationID.x;
    if (i < u_count) {
        dvec3 world = dvec3(positions[3u * i], positions[3u * i + 1u], positions[3u * i + 2u]);
        dvec3 v = u_rotation * (world - u_eye);
        float r = particle_radius(i);
        vec4 sphere = vec4(vec3(v), 0.0);
        if (visible(v, double(r))) {
            bool droplet = is_droplet(i);
            sphere.w = droplet ? -r : r;
            atomicAdd(s_visible, 1u);
            if (droplet) atomicAdd(s_droplets, 1u);
            dvec3 c = dvec3(sphere.xyz);
            double rr = double(r);
            double depth = -c.z;
            atomicMax(s_far_bits, floatBitsToUint(float(-v.z + double(r))));
            atomicMin(s_near_bits, floatBitsToUint(max(float(-v.z - double(r)), 0.0)));
            if (has_bounds(depth, rr)) {
                ivec2 x = pixel_interval(c.x, depth, rr, u_tan_half_fov.x, u_size.x, u_size);
                ivec2 y = pixel_interval(c.y, depth, rr, u_tan_half_fov.y, u_size.y, u_size);
                atomicMin(s_box[0], x.x);
                atomicMin(s_box[1], y.x);
                atomicMin(s_box[2], -x.y);
                atomicMin(s_box[3], -y.y);
            } else {
                atomicAdd(s_unbounded, 1u);
            }
        }
        spheres[i] = sphere;
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u && s_visible > 0u) {
        for (int k = 0; k < 4; ++k) atomicMin(summary.box[k], s_box[k]);
        atomicMax(summary.far_bits, s_far_bits);
        atomicAdd(summary.visible, s_visible);
        atomicAdd(summary.droplets, s_droplets);
        atomicAdd(summary.unbounded, s_unbounded);
        atomicMin(summary.near_bits, s_near_bits);
    }
}
