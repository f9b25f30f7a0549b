// Field normals, first part (passes/field_normals.py), included by
// normals/surface_normals.frag.glsl when FIELD_NORMALS is 1: a surface pixel within reach of a
// rim (field_weight, field/field_normals.glsl; the rim tiles let the rest stop at once)
// appends (x | y << 16, its weight's bits) to `rims`, counts itself in `rim_count` and flags
// its rim block (common/rim_blocks.glsl);
// field/field_blend.comp.glsl then changes the listed pixels' normals. In the fragment
// shader, which has the depth at hand: as a compute pass of its own over the image the same
// test cost 17 ms on the 100k ball at 1280x720 on llvmpipe, several times its share here.

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
