#version 430 core
// Pyramid level 0 of the glare pass: the light above threshold of each pixel.
#include "glare/glare_light.glsl"

uniform sampler2D u_color;   // straight scene-linear RGBA
layout(location = 0) out vec4 out_excess;

void main() {
    vec4 c = premultiplied(texelFetch(u_color, ivec2(gl_FragCoord.xy), 0));
    out_excess = vec4(excess(c.rgb), 0.0);
}
