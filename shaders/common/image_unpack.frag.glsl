#version 330 core
// Packed (RGBA32F, see image_pack.frag.glsl) -> one float per texel (R32F).

uniform sampler2D u_packed;

layout(location = 0) out float out_value;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    out_value = texelFetch(u_packed, ivec2(pixel.x >> 2, pixel.y), 0)[pixel.x & 3];
}
