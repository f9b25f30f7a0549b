#version 330 core
// Split-sum BRDF table (Karis 2013): for n.v (x) and perceptual roughness (y) at texel centres,
//   A = mean over GGX samples of (1 - Fc) G_vis,   B = mean of Fc G_vis,
//   G_vis = V 4 (n.l)(v.h) / (n.h) = (BRDF / F) (n.l) / pdf(l),  Fc = (1 - v.h)^5,
// so the specular directional albedo for any F0 is F0 A + B. Rendered once per G term into a
// 16-bit float RG target (8-bit is too coarse).

#include "common/brdf.glsl"
#include "common/sampling.glsl"

uniform vec2 u_size;
uniform int u_samples;

layout(location = 0) out vec2 out_scale_bias;

void main() {
    vec2 coord = gl_FragCoord.xy / u_size;
    float nv = max(coord.x, MIN_NV);
    float alpha = alpha_from_roughness(coord.y);
    vec3 v = vec3(sqrt(max(1.0 - nv * nv, 0.0)), 0.0, nv);
    float a = 0.0;
    float b = 0.0;
    for (int i = 0; i < u_samples; ++i) {
        float sin2;
        vec3 h = sample_ggx_tangent(hammersley(i, u_samples), alpha, sin2);
        float vh = dot(v, h);
        vec3 l = 2.0 * vh * h - v;
        float nl = l.z;
        if (nl <= 0.0 || vh <= 0.0) {
            continue;
        }
        float nh = h.z;
        float g_vis = visibility(nl, nv, nh, vh, alpha) * 4.0 * nl * vh / nh;
        float fc = pow5(1.0 - vh);
        a += (1.0 - fc) * g_vis;
        b += fc * g_vis;
    }
    out_scale_bias = vec2(a, b) / float(u_samples);
}
