#version 430 core
// One axis of a pyramid level's Gaussian blur; taps past the edge are 0 (that light leaves the
// frame).

#define RADIUS 3

uniform sampler2D u_source;
uniform ivec2 u_direction;
uniform float u_taps[2 * RADIUS + 1];
layout(location = 0) out vec4 out_blurred;

void main() {
    ivec2 size = textureSize(u_source, 0);
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 sum = vec4(0.0);
    for (int i = -RADIUS; i <= RADIUS; ++i) {
        ivec2 p = pixel + i * u_direction;
        if (all(greaterThanEqual(p, ivec2(0))) && all(lessThan(p, size))) {
            sum += u_taps[i + RADIUS] * texelFetch(u_source, p, 0);
        }
    }
    out_blurred = sum;
}
