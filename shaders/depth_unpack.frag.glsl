#version 330 core
// Packed eye depth (RGBA32F, see depth_pack.frag.glsl) -> one pixel per texel (R32F).

uniform sampler2D u_packed_depth;

layout(location = 0) out float out_eye_depth;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    out_eye_depth = texelFetch(u_packed_depth, ivec2(pixel.x >> 2, pixel.y), 0)[pixel.x & 3];
}
