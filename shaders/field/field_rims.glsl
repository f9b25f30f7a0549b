// Field normals, first part (passes/field_normals.py), for field/field_list.comp.glsl: a
// surface pixel within reach of a rim (field_weight, field/field_normals.glsl) appends
// (x | y << 16, its weight's bits) to `rims`, counts itself in `rim_count` and flags its rim
// block (common/rim_blocks.glsl); field/field_blend.comp.glsl then changes the listed pixels'
// normals.

#include "field/field_normals.glsl"
#include "common/rim_blocks.glsl"

layout(std430, binding = 17) writeonly buffer Rims { uvec2 rims[]; };
layout(std430, binding = 18) buffer Count { uint rim_count; uint groups_x; uint groups_y; uint groups_z; };

void list_rim(ivec2 p, ivec2 size, float zc) {
    float t = field_weight(p, size, zc);
    if (t > 0.0) {
        uint i = atomicAdd(rim_count, 1u);
        rims[i] = uvec2(uint(p.x) | (uint(p.y) << 16), floatBitsToUint(t));
        rim_blocks[rim_block(p)] = 1u;  // every writer writes 1: no atomic needed
    }
}
