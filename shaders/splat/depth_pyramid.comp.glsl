#version 430 core
// The front layer's max-depth pyramid for the device occlusion culling
// (occlusion_cull.comp.glsl): level 0 is the splat's eye depth inside the screen box, with the
// background (0) as +inf; level k + 1 holds the largest of each 2 x 2 block of level k (blocks
// at the odd edge take what exists). One dispatch per level, a barrier between them.

layout(local_size_x = 16, local_size_y = 16) in;

layout(std430, binding = 10) buffer Pyramid { float pyramid[]; };

uniform sampler2D u_depth;
uniform int u_level;           // the level this dispatch writes
uniform ivec2 u_origin;        // level 0's lower-left pixel in the depth texture
uniform int u_offset;          // where this level starts in `pyramid`
uniform int u_source_offset;   // where level - 1 starts
uniform ivec2 u_dims;          // this level's width, height
uniform ivec2 u_source_dims;   // level - 1's

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_dims.x || p.y >= u_dims.y) return;
    float value;
    if (u_level == 0) {
        float z = texelFetch(u_depth, u_origin + p, 0).r;
        value = z > 0.0 ? z : uintBitsToFloat(0x7f800000u);  // background: +inf
    } else {
        ivec2 q = 2 * p;
        ivec2 last = u_source_dims - 1;
        int row0 = u_source_offset + q.y * u_source_dims.x;
        int row1 = u_source_offset + min(q.y + 1, last.y) * u_source_dims.x;
        int x1 = min(q.x + 1, last.x);
        value = max(max(pyramid[row0 + q.x], pyramid[row0 + x1]),
                    max(pyramid[row1 + q.x], pyramid[row1 + x1]));
    }
    pyramid[u_offset + p.y * u_dims.x + p.x] = value;
}
