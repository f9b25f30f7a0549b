#version 330 core
// One float per texel (R32F: eye depth, kelvin) -> packed (RGBA32F, common/packed_image.glsl):
// texel (x, y) holds pixels 4x .. 4x+3 of row y; pixels beyond the image's right edge are 0.
// CHANNEL: which channel of the source is packed (1: the peak kelvin beside the kelvin).

#define CHANNEL 0

uniform sampler2D u_image;

layout(location = 0) out vec4 out_packed;

float fetch_or_zero(ivec2 p) {
    ivec2 size = textureSize(u_image, 0);
    return p.x < size.x ? texelFetch(u_image, p, 0)[CHANNEL] : 0.0;
}

void main() {
    ivec2 first = ivec2(4 * int(gl_FragCoord.x), int(gl_FragCoord.y));
    out_packed = vec4(
        fetch_or_zero(first),
        fetch_or_zero(first + ivec2(1, 0)),
        fetch_or_zero(first + ivec2(2, 0)),
        fetch_or_zero(first + ivec2(3, 0))
    );
}
