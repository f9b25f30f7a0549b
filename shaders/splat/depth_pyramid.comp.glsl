#version 430 core
// The front layer's max-depth pyramid for the device occlusion culling
// (occlusion_cull.comp.glsl), in one dispatch: level 0 is the splat's eye depth inside the
// screen box, with the background (0) as +inf; level k + 1 holds the largest of each 2 x 2
// block of level k (blocks at the odd edge take what exists). Every level's pixel is the
// largest of an aligned 2^k x 2^k block of level 0, so each work group owns a 64 x 64 block of
// level 0 and writes all its levels (up to 6, one value per block) from shared memory; no
// barrier between dispatches, no per-level uniforms.

layout(local_size_x = 16, local_size_y = 16) in;

layout(std430, binding = 10) buffer Pyramid { float pyramid[]; };

uniform sampler2D u_depth;
uniform ivec2 u_origin;        // level 0's lower-left pixel in the depth texture
uniform int u_levels;          // levels in the pyramid (at most 7)
uniform int u_offsets[8];      // where each level starts in `pyramid`
uniform ivec2 u_dims[8];       // each level's width, height

const float NONE = -1.0;       // outside the level: never the largest (depths are > 0 or inf)
shared float block[16][16];    // this group's level-2 values (4 x 4 pixels of level 0 each)

bool inside(int level, ivec2 p) {
    return level < u_levels && p.x < u_dims[level].x && p.y < u_dims[level].y;
}

void store(int level, ivec2 p, float value) {
    if (inside(level, p)) pyramid[u_offsets[level] + p.y * u_dims[level].x + p.x] = value;
}

float level0(ivec2 p) {
    if (!inside(0, p)) return NONE;
    float z = texelFetch(u_depth, u_origin + p, 0).r;
    return z > 0.0 ? z : uintBitsToFloat(0x7f800000u);  // background: +inf
}

void main() {
    ivec2 local = ivec2(gl_LocalInvocationID.xy);
    ivec2 cell = ivec2(gl_GlobalInvocationID.xy);  // this thread's 4 x 4 block of level 0
    // Levels 0-2 in registers: 16 pixels, their four 2 x 2 maxima, the block's maximum.
    float level2 = NONE;
    for (int j = 0; j < 2; ++j) {
        for (int i = 0; i < 2; ++i) {
            ivec2 p1 = 2 * cell + ivec2(i, j);
            float level1 = NONE;
            for (int y = 0; y < 2; ++y) {
                for (int x = 0; x < 2; ++x) {
                    ivec2 p0 = 2 * p1 + ivec2(x, y);
                    float z = level0(p0);
                    store(0, p0, z);
                    level1 = max(level1, z);
                }
            }
            store(1, p1, level1);
            level2 = max(level2, level1);
        }
    }
    store(2, cell, level2);
    block[local.y][local.x] = level2;
    // Levels 3-6 in shared memory: each step halves the group's block.
    for (int level = 3, side = 8; level < 7; ++level, side /= 2) {
        barrier();
        float value = NONE;
        bool writes = local.x < side && local.y < side;
        if (writes) {
            ivec2 q = 2 * local;
            value = max(max(block[q.y][q.x], block[q.y][q.x + 1]),
                        max(block[q.y + 1][q.x], block[q.y + 1][q.x + 1]));
        }
        barrier();
        if (writes) {
            block[local.y][local.x] = value;
            store(level, ivec2(gl_WorkGroupID.xy) * side + local, value);
        }
    }
}
