#version 330 core
// The normal guide at reduced size (quality.normal_guide, passes/smooth.py GUIDE_SCALE): the eye
// depth (one float per texel, 0 = background) reduced SCALE times along both axes and packed
// (common/packed_image.glsl): texel (x, y) holds reduced pixels 4x .. 4x+3 of row y, each the
// mean of the surface among its SCALE x SCALE full-size pixels (0 where none is surface).

#define SCALE 4

uniform sampler2D u_image;

layout(location = 0) out vec4 out_packed;

float half_pixel(int p, int row) {
    ivec2 size = textureSize(u_image, 0);
    float sum = 0.0;
    float count = 0.0;
    for (int dy = 0; dy < SCALE; ++dy) {
        for (int dx = 0; dx < SCALE; ++dx) {
            ivec2 at = ivec2(SCALE * p + dx, SCALE * row + dy);
            if (at.x < size.x && at.y < size.y) {
                float z = texelFetch(u_image, at, 0).r;
                sum += z > 0.0 ? z : 0.0;
                count += z > 0.0 ? 1.0 : 0.0;
            }
        }
    }
    return count > 0.0 ? sum / count : 0.0;
}

void main() {
    int first = 4 * int(gl_FragCoord.x);
    int row = int(gl_FragCoord.y);
    out_packed = vec4(half_pixel(first, row), half_pixel(first + 1, row),
                      half_pixel(first + 2, row), half_pixel(first + 3, row));
}
