#version 430 core
// The next pyramid level: the mean of each 2x2 block, texels past the edge counted as 0 (so
// every level holds the same light: sum x 4^level).

uniform sampler2D u_source;
layout(location = 0) out vec4 out_mean;

void main() {
    ivec2 size = textureSize(u_source, 0);
    ivec2 base = ivec2(gl_FragCoord.xy) * 2;
    vec4 sum = vec4(0.0);
    for (int dy = 0; dy < 2; ++dy) {
        for (int dx = 0; dx < 2; ++dx) {
            ivec2 p = base + ivec2(dx, dy);
            if (all(lessThan(p, size))) sum += texelFetch(u_source, p, 0);
        }
    }
    out_mean = 0.25 * sum;
}
