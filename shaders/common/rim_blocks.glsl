// Rim blocks (passes/field_normals.py): one word per RIM_BLOCK x RIM_BLOCK pixels; bit 0 is set
// where the field normals listed a pixel (field/field_rims.glsl), bit 1 where a block within
// +-RIM_REACH blocks along each axis has bit 0 (field/field_grid.comp.glsl's phase 0). The
// field grid sorts only the particles whose support can reach a listed block: the rest add
// nothing to any listed pixel's gradient.

#define RIM_BLOCK 16
#define RIM_REACH 2

layout(std430, binding = 19) buffer RimBlocks { uint rim_blocks[]; };

uniform ivec2 u_rim_blocks;  // blocks per row and per column: ceil(image / RIM_BLOCK)

uint rim_block(ivec2 p) {
    return uint((p.y / RIM_BLOCK) * u_rim_blocks.x + p.x / RIM_BLOCK);
}
