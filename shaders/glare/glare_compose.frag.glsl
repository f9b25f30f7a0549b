#version 430 core
// The glared image: each pixel keeps its light below threshold and c0 of its excess, and gets
// the blurred levels, bilinearly upsampled, with their weights (glare_psf.py fits c0 and w_l to
// the PSF). Straight RGBA out; alpha rises where glare lands on uncovered pixels, so that the
// premultiplied radiance is what was computed.
#include "glare/glare_light.glsl"

#define LEVELS 1

uniform sampler2D u_color;
uniform float u_centre;
uniform float u_weights[LEVELS];
uniform float u_scale;   // 2^exposure
uniform sampler2D u_level0;
uniform sampler2D u_level1;
uniform sampler2D u_level2;
uniform sampler2D u_level3;
uniform sampler2D u_level4;
uniform sampler2D u_level5;
uniform sampler2D u_level6;
uniform sampler2D u_level7;
uniform sampler2D u_level8;
uniform sampler2D u_level9;
layout(location = 0) out vec4 out_color;

vec3 fetch_or_zero(sampler2D level, ivec2 p, ivec2 size) {
    bool inside = all(greaterThanEqual(p, ivec2(0))) && all(lessThan(p, size));
    return inside ? texelFetch(level, p, 0).rgb : vec3(0.0);
}

// Bilinear at level texel coordinate (pixel + 0.5) / step - 0.5, zero outside the level.
vec3 upsample(sampler2D level, float step, ivec2 pixel) {
    ivec2 size = textureSize(level, 0);
    vec2 u = (vec2(pixel) + 0.5) / step - 0.5;
    vec2 j = floor(u);
    vec2 f = u - j;
    ivec2 i = ivec2(j);
    vec3 a = mix(fetch_or_zero(level, i, size), fetch_or_zero(level, i + ivec2(1, 0), size), f.x);
    vec3 b = mix(fetch_or_zero(level, i + ivec2(0, 1), size),
                 fetch_or_zero(level, i + ivec2(1, 1), size), f.x);
    return mix(a, b, f.y);
}

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 c = premultiplied(texelFetch(u_color, pixel, 0));
    vec3 spread = excess(c.rgb);
    vec3 glow = u_centre * spread;
    glow += u_weights[0] * upsample(u_level0, 1.0, pixel);
#if LEVELS > 1
    glow += u_weights[1] * upsample(u_level1, 2.0, pixel);
#endif
#if LEVELS > 2
    glow += u_weights[2] * upsample(u_level2, 4.0, pixel);
#endif
#if LEVELS > 3
    glow += u_weights[3] * upsample(u_level3, 8.0, pixel);
#endif
#if LEVELS > 4
    glow += u_weights[4] * upsample(u_level4, 16.0, pixel);
#endif
#if LEVELS > 5
    glow += u_weights[5] * upsample(u_level5, 32.0, pixel);
#endif
#if LEVELS > 6
    glow += u_weights[6] * upsample(u_level6, 64.0, pixel);
#endif
#if LEVELS > 7
    glow += u_weights[7] * upsample(u_level7, 128.0, pixel);
#endif
#if LEVELS > 8
    glow += u_weights[8] * upsample(u_level8, 256.0, pixel);
#endif
#if LEVELS > 9
    glow += u_weights[9] * upsample(u_level9, 512.0, pixel);
#endif
    vec3 radiance = c.rgb - spread + glow;
    vec3 gained = max(radiance - c.rgb, vec3(0.0));
    float alpha = max(c.a, min(1.0, u_scale * dot(gained, LUMINANCE)));
    out_color = vec4(alpha > 0.0 ? radiance / alpha : vec3(0.0), alpha);
}
