#version 430 core
// The display transform on the GPU (passes/display.py): scene-linear straight RGBA -> 8-bit
// sRGB codes, the same codes server/output/display.py computes on the CPU, so PNG, JPEG and raw
// rgba8 need no per-pixel work on the host: RGB x 2**exposure (u_scale, float32 as on the CPU),
// the tone mapper (TONE_MAPPER 0 clamp, 1 Hill's ACES fit, same float32 operation order,
// `precise` so nothing is fused), NaN -> 0 and +-inf -> 1 / 0 per channel, then the code by
// search in the CPU's own OETF thresholds (display._Oetf8: the first float32 bit pattern of
// each code), alpha floor(a * 255 + 0.5). COMPOSITE: the RGB codes over an opaque background
// as encoders' composite_codes does in integers, (c a + bg (255 - a) + 127) / 255, alpha 255.
// Rows are written top first (the read-back is then the image as encoders want it).

#define TONE_MAPPER 0
#define COMPOSITE 0

uniform sampler2D u_color;
uniform float u_scale;
uniform int u_height;
uniform uvec3 u_background;   // COMPOSITE: background codes
layout(std430, binding = 0) readonly buffer Thresholds { uint thresholds[]; };  // 256 entries

layout(location = 0) out vec4 out_codes;   // RGBA8 UNORM: code / 255 converts back exactly

vec3 mat_mul(mat3 rows, vec3 x) {
    precise vec3 out_value;
    for (int i = 0; i < 3; ++i) {
        precise float v = x.r * rows[i][0] + x.g * rows[i][1];
        out_value[i] = v + x.b * rows[i][2];
    }
    return out_value;
}

vec3 tone_map(vec3 x) {
#if TONE_MAPPER == 1
    const mat3 aces_input = mat3(0.59719, 0.35458, 0.04823, 0.07600, 0.90834, 0.01566,
                                 0.02840, 0.13383, 0.83777);  // rows, as display.ACES_INPUT
    const mat3 aces_output = mat3(1.60475, -0.53108, -0.07367, -0.10208, 1.10813, -0.00605,
                                  -0.00327, -0.07276, 1.07602);
    if (any(isnan(x))) {
        // numpy's maximum and matrix product spread a NaN to all three channels (GLSL's max
        // would drop it); `sanitize` then maps them as the CPU does.
        return vec3(uintBitsToFloat(0x7fc00000u));
    }
    precise vec3 v = mat_mul(aces_input, max(x, vec3(0.0)));
    precise vec3 curve;
    for (int i = 0; i < 3; ++i) {
        bool big = v[i] > 1e6;
        precise float s = big ? 1.0 : v[i];
        precise float a = s * (s + 0.0245786) - 0.000090537;
        precise float b = s * (0.983729 * s + 0.4329510) + 0.238081;
        curve[i] = big ? 1.0 / 0.983729 : a / b;
    }
    return clamp(mat_mul(aces_output, curve), 0.0, 1.0);
#else
    return clamp(x, 0.0, 1.0);
#endif
}

float sanitize(float mapped, float source) {
    if (isnan(source)) return 0.0;
    if (isinf(source)) return source > 0.0 ? 1.0 : 0.0;
    return isnan(mapped) ? 0.0 : clamp(mapped, 0.0, 1.0);
}

// The code is the number of thresholds at or below the value's bit pattern. The GPU's pow gives
// it to within one; the thresholds then settle it exactly (one or two loads, not a search).
uint oetf_code(float display_linear) {
    uint pattern = floatBitsToUint(display_linear);
    if (pattern > 0x3f800000u) pattern = 0u;  // -0.0 (and anything negative) -> 0
    float v = uintBitsToFloat(pattern);
    float encoded = v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1.0 / 2.4) - 0.055;
    uint code = uint(clamp(floor(encoded * 255.0 + 0.5), 0.0, 255.0));
    while (code < 255u && pattern >= thresholds[code]) ++code;
    while (code > 0u && pattern < thresholds[code - 1u]) --code;
    return code;
}

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 color = texelFetch(u_color, ivec2(pixel.x, u_height - 1 - pixel.y), 0);
    precise vec3 exposed = color.rgb * u_scale;
    vec3 mapped = tone_map(exposed);
    uvec3 rgb;
    for (int i = 0; i < 3; ++i) {
        rgb[i] = oetf_code(sanitize(mapped[i], color[i]));
    }
    float a = isnan(color.a) ? 0.0 : clamp(color.a, 0.0, 1.0);
    precise float scaled_alpha = a * 255.0 + 0.5;
    uint alpha = uint(scaled_alpha);
#if COMPOSITE
    rgb = (rgb * alpha + u_background * (255u - alpha) + 127u) / 255u;
    alpha = 255u;
#endif
    out_codes = vec4(uvec4(rgb, alpha)) / 255.0;
}
