#version 430 core
// One sub-frame added to the running average of a motion-blurred frame (passes/accumulate.py):
// premultiplied RGB and alpha, each sub-frame weighted 1/N; FIRST starts the sum, LAST writes
// the average as straight RGBA (RGB / alpha, 0 where alpha is 0) like every colour target.

#define FIRST 0
#define LAST 0

uniform sampler2D u_color;   // the sub-frame, straight RGBA
uniform sampler2D u_sum;     // the running sum, premultiplied
uniform float u_weight;      // 1 / N
layout(location = 0) out vec4 out_color;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 c = texelFetch(u_color, pixel, 0);
    vec4 sum = u_weight * vec4(c.rgb * c.a, c.a);
#if !FIRST
    sum += texelFetch(u_sum, pixel, 0);
#endif
#if LAST
    out_color = vec4(sum.a > 0.0 ? sum.rgb / sum.a : vec3(0.0), sum.a);
#else
    out_color = sum;
#endif
}
