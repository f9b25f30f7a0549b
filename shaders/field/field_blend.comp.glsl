#version 430 core
// Field normals, second part (passes/field_normals.py), by phase (u_phase):
//   0  one invocation: the work groups for the `rim_count` pixels field/field_list.comp.glsl
//      listed, as the arguments of an indirect dispatch (x at most u_groups_x, then rows);
//   1  dispatched with them: for each listed pixel, the normal of the normals pass's target
//      (world space) taken towards the field's at the pixel's view point (field_blend,
//      field/field_normals.glsl), in place.
// 64 listed pixels to a work group, the gradient runs in no idle lane: 6 ms on the 100k ball at
// 1280x720 on llvmpipe, against ~11 ms inside the normals pass's fragment shader, whose 4 x 4
// blocks along the rims were a third idle.

#define FIELD_GROUP 64

layout(local_size_x = FIELD_GROUP) in;

#include "common/depth_image.glsl"

uniform sampler2D u_depth;
uniform float u_edge_jump;
uniform float u_edge_jump_px;
uniform float u_focal_px;
uniform float u_particle_radius;
uniform vec2 u_tan_half_fov;   // (tan(fov_y / 2) * aspect, tan(fov_y / 2))
uniform mat3 u_view_to_world;
uniform int u_phase;
uniform uint u_groups_x;  // work groups per row of the dispatch (field_normals.py GROUPS_X)

#include "field/field_normals.glsl"

layout(std430, binding = 17) readonly buffer Rims { uvec2 rims[]; };
layout(std430, binding = 18) buffer Count { uint rim_count; uint groups_x; uint groups_y; uint groups_z; };
layout(rgba32f, binding = 0) uniform image2D u_normals;  // world normal, eye depth

void main() {
    if (u_phase == 0) {
        uint needed = (rim_count + uint(FIELD_GROUP) - 1u) / uint(FIELD_GROUP);
        uint x = min(needed, u_groups_x);
        groups_x = x;
        groups_y = x > 0u ? (needed + x - 1u) / x : 0u;
        groups_z = 1u;
        return;
    }
    uint i = gl_WorkGroupID.y * u_groups_x * uint(FIELD_GROUP) + gl_GlobalInvocationID.x;
    if (i >= rim_count) {
        return;
    }
    uvec2 rim = rims[i];
    ivec2 p = ivec2(rim.x & 0xffffu, rim.x >> 16);
    float zc = texelFetch(u_depth, p, 0).r;
    vec3 x = view_position(p, textureSize(u_depth, 0), u_tan_half_fov, zc);
    vec4 stored = imageLoad(u_normals, p);
    vec3 blended;
    if (field_blend(x, transpose(u_view_to_world) * stored.xyz, uintBitsToFloat(rim.y), blended)) {
        imageStore(u_normals, p, vec4(normalize(u_view_to_world * blended), stored.w));
    }
}
