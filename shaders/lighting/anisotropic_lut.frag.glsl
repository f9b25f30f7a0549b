#version 330 core
// Split-sum table of the anisotropic GGX lobe (lighting/anisotropic_ggx.glsl): per texel of a
// 2-D atlas, A = E[(1 - Fc) G_vis] and B = E[Fc G_vis] as in brdf_lut.frag.glsl, over
// (sqrt(n.v), the view's azimuth from the brush in [0, pi/2] at cosine spacing, sqrt(alpha_t),
// sqrt(alpha_b)).
// Atlas: x = i_nv + NV * i_phi, y = i_t + ROUGH * i_b; the owner (lighting/anisotropic_lut.py)
// reads it back into a 3-D texture (nv, phi, t + ROUGH b). Half vectors ~ D(h) (n.h) by the
// stretched sampling map, integrated with Gauss-Legendre nodes in s times the midpoint rule in
// t (32 x 32 points; against a hemisphere quadrature: benchmarks/STUDIES.md).

#include "common/brdf.glsl"
#include "common/sampling.glsl"
#include "lighting/anisotropic_ggx.glsl"

#define NV 32
#define PHI 24
#define ROUGH 16
#define NODES 32

uniform float u_nodes[NODES];    // Gauss-Legendre nodes mapped to [0, 1]
uniform float u_weights[NODES];  // their weights (sum 1)

layout(location = 0) out vec2 out_scale_bias;

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    float x = float(texel.x % NV) / float(NV - 1);
    // Azimuths at cosine spacing: at grazing views the albedo turns fastest next to the axes.
    float phi = 0.25 * PI * (1.0 - cos(PI * float(texel.x / NV) / float(PHI - 1)));
    float rho_t = mix(MIN_ROUGHNESS, 1.0, float(texel.y % ROUGH) / float(ROUGH - 1));
    float rho_b = mix(MIN_ROUGHNESS, 1.0, float(texel.y / ROUGH) / float(ROUGH - 1));
    AnisotropicFrame frame;
    frame.t = vec3(1.0, 0.0, 0.0);
    frame.b = vec3(0.0, 1.0, 0.0);
    frame.alpha_t = rho_t * rho_t;
    frame.alpha_b = rho_b * rho_b;
    frame.strength = 0.0;
    float nv = max(x * x, MIN_NV);
    float sin_v = sqrt(max(1.0 - nv * nv, 0.0));
    vec3 v = vec3(sin_v * cos(phi), sin_v * sin(phi), nv);
    float a = 0.0;
    float b = 0.0;
    for (int i = 0; i < NODES; ++i) {
        for (int j = 0; j < NODES; ++j) {
            vec2 st = vec2(u_nodes[i], (float(j) + 0.5) / float(NODES));
            vec3 h = sample_ggx_anisotropic_tangent(st, frame);
            float vh = dot(v, h);
            vec3 l = 2.0 * vh * h - v;
            float nl = l.z;
            if (nl <= 0.0 || vh <= 0.0) {
                continue;
            }
            float nh = h.z;
            float g_vis = visibility_anisotropic(frame, v, l, nl, nv, nh, vh) * 4.0 * nl * vh / nh;
            float fc = pow5(1.0 - vh);
            a += u_weights[i] * (1.0 - fc) * g_vis;
            b += u_weights[i] * fc * g_vis;
        }
    }
    out_scale_bias = vec2(a, b) / float(NODES);
}
