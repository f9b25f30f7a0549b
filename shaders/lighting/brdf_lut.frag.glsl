#version 330 core
// Split-sum BRDF table (Karis 2013): for n.v (x) and perceptual roughness (y) at texel centres,
//   A = E[(1 - Fc) G_vis],   B = E[Fc G_vis]   over half vectors h ~ D(h) (n.h),
//   G_vis = V 4 (n.l)(v.h) / (n.h) = (BRDF / F) (n.l) / pdf(l),  Fc = (1 - v.h)^5,
// so the specular directional albedo for any F0 is F0 A + B. Rendered once per G term into a
// 16-bit float RG target (8-bit is too coarse).
// The expectation over the GGX sampling map (s, t) is a product rule, not Hammersley points:
// Gauss-Legendre nodes in s (u_nodes/u_weights on [0, 1]) times the midpoint rule in t = phi / 2pi
// (periodic, so the midpoint rule converges fast). With 64 x 64 points the error is <= 2e-3
// everywhere; 1024 Hammersley points err by up to 2.3% at grazing n.v, where part of the
// lobe falls below the horizon (measured in tests/test_shading_ibl.py).

#include "common/brdf.glsl"
#include "common/sampling.glsl"

#define NODES 64

uniform vec2 u_size;
uniform float u_nodes[NODES];    // Gauss-Legendre nodes mapped to [0, 1]
uniform float u_weights[NODES];  // their weights (sum 1)

layout(location = 0) out vec2 out_scale_bias;

void main() {
    vec2 coord = gl_FragCoord.xy / u_size;
    float nv = max(coord.x, MIN_NV);
    float alpha = alpha_from_roughness(coord.y);
    vec3 v = vec3(sqrt(max(1.0 - nv * nv, 0.0)), 0.0, nv);
    float a = 0.0;
    float b = 0.0;
    for (int i = 0; i < NODES; ++i) {
        for (int j = 0; j < NODES; ++j) {
            float sin2;
            vec2 st = vec2(u_nodes[i], (float(j) + 0.5) / float(NODES));
            vec3 h = sample_ggx_tangent(st, alpha, sin2);
            float vh = dot(v, h);
            vec3 l = 2.0 * vh * h - v;
            float nl = l.z;
            if (nl <= 0.0 || vh <= 0.0) {
                continue;
            }
            float nh = h.z;
            float g_vis = visibility(nl, nv, nh, vh, alpha) * 4.0 * nl * vh / nh;
            float fc = pow5(1.0 - vh);
            a += u_weights[i] * (1.0 - fc) * g_vis;
            b += u_weights[i] * fc * g_vis;
        }
    }
    out_scale_bias = vec2(a, b) / float(NODES);
}
