#version 330 core
// One roughness level of the prefiltered specular environment (split-sum, Karis 2013): for the
// texel's direction r, with n = v = r, the n.l-weighted average of the environment over GGX
// half-vector samples. Source LOD per sample from its pdf (Krivanek & Colbert 2008; Filament's
// cmgen): lod = 1/2 log2(omega_s / omega_p) + 1, omega_s = 1 / (N pdf), pdf = D / 4 (v = n),
// omega_p = the level-0 texel's solid angle in that direction. That filtering is what keeps a
// small bright source (a 1e5 sun) from turning into a few bright dots.

#include "common/brdf.glsl"
#include "common/sampling.glsl"
#include "common/equirect.glsl"

uniform sampler2D u_source;        // equirect radiance, full mip chain
uniform vec2 u_source_size;        // level-0 size of u_source
uniform vec2 u_target_size;        // size of this level
uniform float u_roughness;         // perceptual roughness of this level (0 = copy)
uniform int u_samples;

layout(location = 0) out vec4 out_radiance;

void main() {
    vec2 uv = gl_FragCoord.xy / u_target_size;
    vec3 r = equirect_direction(uv);
    if (u_roughness <= 0.0) {
        // Mirror level: resample the source at the footprint of this level's texel.
        float lod = max(log2(u_source_size.x / u_target_size.x), 0.0);
        out_radiance = vec4(textureLod(u_source, uv, lod).rgb, 1.0);
        return;
    }
    float alpha = alpha_from_roughness(u_roughness);
    vec3 t;
    vec3 b;
    tangent_frame(r, t, b);
    vec3 sum = vec3(0.0);
    float weight = 0.0;
    for (int i = 0; i < u_samples; ++i) {
        float sin2;
        vec3 h_t = sample_ggx_tangent(hammersley(i, u_samples), alpha, sin2);
        vec3 h = t * h_t.x + b * h_t.y + r * h_t.z;
        float nh = h_t.z;
        vec3 l = 2.0 * nh * h - r;  // eq 53 with v = n = r
        float nl = dot(r, l);
        if (nl <= 0.0) {
            continue;
        }
        float pdf = d_ggx(nh, sin2, alpha) * 0.25;
        float omega_s = 1.0 / (float(u_samples) * pdf);
        float omega_p = equirect_texel_solid_angle(l, u_source_size);
        float lod = max(0.5 * log2(omega_s / omega_p) + 1.0, 0.0);
        sum += textureLod(u_source, equirect_uv(l), lod).rgb * nl;
        weight += nl;
    }
    out_radiance = vec4(weight > 0.0 ? sum / weight : vec3(0.0), 1.0);
}
