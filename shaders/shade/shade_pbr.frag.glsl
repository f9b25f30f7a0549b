#version 330 core
// Physically based shading of the reconstructed surface (thesis chapter 4):
//   direct   sum over lights of f_r (Lambert + Cook-Torrance, common/brdf.glsl) E_light (n.l)
//            x the light's shadow visibility (SHADOWS, shadow/shadow_lookup.glsl); sphere
//            lights: representative point + form factor (SPHERE_LIGHTS, shade/sphere_light.glsl)
//   indirect diffuse (1 - (F0 A + B)) c_diff E_sh(n) / pi, E_sh from 9 SH coefficients
//            + specular IBL: prefiltered mip chain x (F0 A + B) (split sum), or per-pixel GGX
//            importance sampling with pdf-based source LOD (eq 50-53, corrected)
//   multiple scattering (option): every specular term x (1 + F0 (1 / E_ss - 1)), E_ss = A + B
//            the single-scatter albedo at F = 1 (Fdez-Aguera 2019; Filament's energy
//            compensation), so rough metal keeps the energy GGX's single bounce loses
//   combine  direct + indirect (default) or weighted (eq 55): w direct + (1 - w) indirect
//   emission (1 - F(n.v)) B(T) for hot metal, from the splatted temperature (added after)
//   finish   (options) ANISOTROPIC: the brushed GGX lobe of lighting/anisotropic_ggx.glsl in
//            place of the isotropic one, its split-sum (A, B) from its own table
//            (lighting/anisotropic_albedo.glsl); DETAIL_ROUGHNESS: roughness from
//            detail/surface_detail.glsl
// Output: straight scene-linear RGB, alpha = coverage (1 over the environment background).
// ANTIALIAS: coverage is the splat's sub-pixel coverage (splat/splat_coverage.frag.glsl); a
// pixel just outside a silhouette (coverage > 0, no surface at its centre) shows the nearest of
// its 8 neighbours' surfaces, seen along its own ray; over the environment the surface is
// blended with the background by coverage.

#define IBL_NONE 0
#define IBL_PREFILTERED 1
#define IBL_SAMPLED 2
#define IBL_MODE 1
#define COMBINE_ADD 0
#define COMBINE_WEIGHTED 1
#define COMBINE 0
#define HAS_TEMPERATURE 0
#define HEAT_TINT 0
#define MOLTEN 0
#define MULTIPLE_SCATTERING 0
#define BACKGROUND_ENVIRONMENT 0
#define VIEW_BEAUTY 0
#define VIEW_DIRECT 1
#define VIEW_DIFFUSE_IBL 2
#define VIEW_SPECULAR_IBL 3
#define VIEW_EMISSION 4
#define VIEW_IRRADIANCE 5
#define DEBUG_VIEW 0
#define MAX_LIGHTS 8
#define ANTIALIAS 0
#define LIGHT_DIRECTIONAL 0
#define LIGHT_POINT 1
#define LIGHT_SPHERE 2
#define SPHERE_LIGHTS 0
#define SHADOWS 0
#define ANISOTROPIC 0
#define DETAIL_ROUGHNESS 0

#include "common/depth_image.glsl"
#if HEAT_TINT
vec3 heat_fresnel(vec3 f0, float cos_theta);  // lighting/thin_film.glsl
#define SURFACE_FRESNEL heat_fresnel
#endif
#include "common/brdf.glsl"
#include "common/sampling.glsl"
#include "common/equirect.glsl"
#include "common/sh9.glsl"
#include "lighting/anisotropic_ggx.glsl"
#include "detail/surface_detail.glsl"

uniform sampler2D u_normal_depth;   // world normal xyz, eye depth w (0 = no surface)
uniform vec2 u_tan_half_fov;        // (tan(fov_y / 2) * aspect, tan(fov_y / 2))
uniform mat3 u_view_to_world;

uniform vec3 u_f0;                  // effective specular F0 (after the metallic blend)
uniform vec3 u_diffuse_albedo;
uniform float u_roughness;

uniform int u_light_count;
uniform int u_light_type[MAX_LIGHTS];
uniform vec3 u_light_vector[MAX_LIGHTS];    // directional: unit vector towards the light;
                                            // point: position relative to the eye (world axes)
uniform vec3 u_light_radiance[MAX_LIGHTS];  // colour * intensity
uniform float u_light_radius[MAX_LIGHTS];   // sphere lights

uniform mat3 u_world_to_env;
uniform float u_env_intensity;
uniform vec3 u_sh[9];               // radiance SH of the environment (environment frame)
uniform sampler2D u_env_source;     // equirect radiance, box-filtered mip chain
uniform vec2 u_env_source_size;
uniform sampler2D u_env_prefiltered;  // level i = roughness i / (levels - 1)
uniform float u_prefiltered_max_lod;
uniform sampler2D u_brdf_lut;       // (n.v, roughness) -> (A, B)
uniform int u_ibl_samples;
uniform float u_direct_weight;

// The half-width of the 3 x 3 neighbour windows below, 1: a uniform, not a constant, so that
// their loops stay loops. llvmpipe runs both sides of a branch for every pixel of its block
// under a mask and skips only loops whose lanes are all done: unrolled, the two windows (needed
// only next to a silhouette) cost every pixel 18 fetches (~2 ms of the 100k ball's 1280x720
// frame). A GPU skips a branch no lane of a warp takes either way.
uniform int u_neighbour_reach;
uniform sampler2D u_coverage;       // sub-pixel coverage of the silhouettes (ANTIALIAS)
uniform sampler2D u_temperature;    // kelvin, nearest particle (0 = none)
uniform sampler2D u_blackbody;      // 1 x N: rgb at luminance 1, log2(luminance) in alpha
uniform vec2 u_blackbody_range;     // kelvin at the first and last texel centres
uniform vec3 u_emissivity;          // normal-incidence emissivity
uniform float u_emission_scale;     // scene-linear per cd/m^2
uniform vec3 u_brush_direction;     // ANISOTROPIC: unit world direction of the brush strokes
uniform float u_anisotropy;

// This pixel's F0, diffuse albedo and roughness: the uniforms', or with HEAT_TINT / MOLTEN
// the hot metal's (lighting/thin_film.glsl).
vec3 g_f0;
vec3 g_diffuse_albedo;
float g_roughness;
#if HAS_TEMPERATURE && (HEAT_TINT || MOLTEN)
#include "lighting/thin_film.glsl"
#endif

#include "shade/anisotropic_ibl.glsl"
#if ANISOTROPIC
AnisotropicFrame g_frame;  // the pixel's brushed frame, set in main before any lighting
uniform sampler3D u_anisotropic_lut;  // the brushed lobe's (A, B), lighting/anisotropic_albedo
#include "lighting/anisotropic_albedo.glsl"
#endif

layout(location = 0) out vec4 out_color;

#if SPHERE_LIGHTS
#include "shade/sphere_light.glsl"
#endif
#if SHADOWS
#include "shadow/shadow_lookup.glsl"
#endif

vec3 environment_radiance(vec3 world_direction, float lod) {
    vec3 d = u_world_to_env * world_direction;
    return textureLod(u_env_source, equirect_uv(d), lod).rgb * u_env_intensity;
}

// `specular_energy`: the multiple-scattering factor of the specular lobe (1 without it).
vec3 direct_light(vec3 n, vec3 v, vec3 position, float alpha, vec3 specular_energy) {
    vec3 sum = vec3(0.0);
    for (int i = 0; i < MAX_LIGHTS; ++i) {
        if (i >= u_light_count) {
            break;
        }
#if SPHERE_LIGHTS
        if (u_light_type[i] == LIGHT_SPHERE) {
            vec3 to_sphere = u_light_vector[i] - position;
            vec3 light = sphere_light(to_sphere, u_light_radius[i], u_light_radiance[i], n, v,
                alpha, g_f0, g_diffuse_albedo, specular_energy);
#if SHADOWS
            if (any(greaterThan(light, vec3(0.0)))) {
                light *= shadow_visibility(i, position, n);
            }
#endif
            sum += light;
            continue;
        }
#endif
        vec3 l;
        vec3 irradiance = u_light_radiance[i];
        if (u_light_type[i] == LIGHT_POINT) {
            vec3 to_light = u_light_vector[i] - position;
            // Floor the distance at a micrometre of scene units so a light on the surface
            // stays finite (1e12 / 1e-12 still fits fp32).
            float d2 = max(dot(to_light, to_light), 1e-12);
            l = to_light * inversesqrt(d2);
            irradiance /= d2;
        } else {
            l = u_light_vector[i];
        }
        float nl = dot(n, l);
        if (nl > 0.0) {
#if SHADOWS
            irradiance *= shadow_visibility(i, position, n);
#endif
            vec3 diffuse;
            vec3 specular;
#if ANISOTROPIC
            brdf_lobes_anisotropic(n, v, l, g_f0, g_diffuse_albedo, g_frame, diffuse, specular);
#else
            brdf_lobes(n, v, l, g_f0, g_diffuse_albedo, alpha, diffuse, specular);
#endif
            sum += (diffuse + specular * specular_energy) * irradiance * nl;
        }
    }
    return sum;
}

// Per-pixel GGX importance sampling of the environment (thesis §4.2.2 with eq 52 corrected).
// Estimator per sample: L(l) F V 4 (n.l)(v.h) / (n.h), i.e. f_r (n.l) / pdf(l),
// pdf(l) = D (n.h) / (4 v.h). Each sample reads the source at the LOD whose texel covers the
// sample's share of the solid angle, 1 / (N pdf) (Krivanek & Colbert 2008).
vec3 sampled_specular(vec3 n, vec3 v, float nv, float alpha) {
    vec3 t;
    vec3 b;
    tangent_frame(n, t, b);
    vec3 sum = vec3(0.0);
    for (int i = 0; i < u_ibl_samples; ++i) {
        float sin2;
        vec3 h_t = sample_ggx_tangent(hammersley(i, u_ibl_samples), alpha, sin2);
        vec3 h = t * h_t.x + b * h_t.y + n * h_t.z;
        float vh = dot(v, h);
        vec3 l = 2.0 * vh * h - v;  // eq 53
        float nl = dot(n, l);
        if (nl <= 0.0 || vh <= 0.0) {
            continue;
        }
        float nh = h_t.z;
        float pdf = d_ggx(nh, sin2, alpha) * nh / (4.0 * vh);
        vec3 l_env = u_world_to_env * l;
        float omega_s = 1.0 / (float(u_ibl_samples) * pdf);
        float omega_p = equirect_texel_solid_angle(l_env, u_env_source_size);
        float lod = max(0.5 * log2(omega_s / omega_p) + 1.0, 0.0);
        vec3 radiance = textureLod(u_env_source, equirect_uv(l_env), lod).rgb;
        float weight = visibility(nl, nv, nh, vh, alpha) * 4.0 * nl * vh / nh;
        sum += radiance * SURFACE_FRESNEL(g_f0, vh) * weight;
    }
    return sum * (u_env_intensity / float(u_ibl_samples));
}

vec3 blackbody_radiance(float kelvin) {
    if (kelvin < u_blackbody_range.x) {
        return vec3(0.0);  // below the table nothing visible is emitted
    }
    float count = float(textureSize(u_blackbody, 0).x);
    float x = (min(kelvin, u_blackbody_range.y) - u_blackbody_range.x)
        / (u_blackbody_range.y - u_blackbody_range.x);
    vec4 entry = textureLod(u_blackbody, vec2((x * (count - 1.0) + 0.5) / count, 0.5), 0.0);
    return entry.rgb * exp2(entry.a);
}

// The nearest surface among the 8 neighbours of `pixel` (w = 0: none), and where it is.
vec4 nearest_neighbour_surface(ivec2 pixel, ivec2 size, out ivec2 source) {
    vec4 best = vec4(0.0);
    source = pixel;
    for (int dy = -u_neighbour_reach; dy <= u_neighbour_reach; ++dy) {
        for (int dx = -u_neighbour_reach; dx <= u_neighbour_reach; ++dx) {
            ivec2 q = pixel + ivec2(dx, dy);
            if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) {
                continue;
            }
            vec4 candidate = texelFetch(u_normal_depth, q, 0);
            if (candidate.w > 0.0 && (best.w <= 0.0 || candidate.w < best.w)) {
                best = candidate;
                source = q;
            }
        }
    }
    return best;
}

// Whether any of the 8 neighbours of `pixel` has no surface at its centre (a silhouette is near).
bool next_to_background(ivec2 pixel, ivec2 size) {
    for (int dy = -u_neighbour_reach; dy <= u_neighbour_reach; ++dy) {
        for (int dx = -u_neighbour_reach; dx <= u_neighbour_reach; ++dx) {
            ivec2 q = clamp(pixel + ivec2(dx, dy), ivec2(0), size - 1);
            if (texelFetch(u_normal_depth, q, 0).w <= 0.0) {
                return true;
            }
        }
    }
    return false;
}

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 normal_depth = texelFetch(u_normal_depth, pixel, 0);
    ivec2 size = textureSize(u_normal_depth, 0);
    ivec2 source = pixel;  // the pixel whose surface this one shows
#if ANTIALIAS
    float coverage = texelFetch(u_coverage, pixel, 0).r;
    if (normal_depth.w <= 0.0 && coverage > 0.0) {
        normal_depth = nearest_neighbour_surface(pixel, size, source);
    } else if (normal_depth.w > 0.0 && coverage < 0.5) {
        // A surface at the centre that no sphere's coverage accounts for (a sphere covering the
        // centre gives at least 1/2, splat_coverage.frag.glsl): a gap the gap pass closed
        // (passes/gaps.py), which lies inside the fluid's outline: covered.
        coverage = 1.0;
    } else if (normal_depth.w > 0.0 && coverage < 1.0 && !next_to_background(pixel, size)) {
        // Inside a surface (no neighbour without one): the union covers the pixel. The coverage
        // pass writes only next to such neighbours (passes/coverage_band.py), and where two
        // front spheres meet it would keep only the larger single coverage anyway.
        coverage = 1.0;
    }
#endif
    if (normal_depth.w <= 0.0) {
#if BACKGROUND_ENVIRONMENT
        vec3 ray = u_view_to_world * view_position(pixel, size, u_tan_half_fov, 1.0);
        out_color = vec4(environment_radiance(normalize(ray), 0.0), 1.0);
#else
        out_color = vec4(0.0);
#endif
        return;
    }
    vec3 position = u_view_to_world * view_position(pixel, size, u_tan_half_fov, normal_depth.w);
    vec3 n = normalize(normal_depth.xyz);
    vec3 v = -normalize(position);
    float nv = max(dot(n, v), MIN_NV);
    g_f0 = u_f0;
    g_diffuse_albedo = u_diffuse_albedo;
    g_roughness = u_roughness;
#if DETAIL_ROUGHNESS
    g_roughness = detail_roughness(g_roughness, n, position);
#endif
#if HAS_TEMPERATURE && (HEAT_TINT || MOLTEN)
    hot_metal(source);
#endif
    float alpha = alpha_from_roughness(g_roughness);
    float lookup_roughness = g_roughness;
#if ANISOTROPIC
    g_frame = anisotropic_frame(n, u_brush_direction, alpha, u_anisotropy);
#endif

#if (IBL_MODE != IBL_NONE || MULTIPLE_SCATTERING) && ANISOTROPIC
    vec2 scale_bias = anisotropic_scale_bias(u_anisotropic_lut, nv, v, g_frame);
#elif IBL_MODE != IBL_NONE || MULTIPLE_SCATTERING
    vec2 scale_bias = texture(u_brdf_lut, vec2(nv, lookup_roughness)).rg;
#endif
#if MULTIPLE_SCATTERING
    // E_ss >= ~0.3 for GGX (alpha = 1, grazing); the floor only guards a broken table.
    vec3 specular_energy = 1.0 + g_f0 * (1.0 / max(scale_bias.x + scale_bias.y, 0.05) - 1.0);
#else
    vec3 specular_energy = vec3(1.0);
#endif
    vec3 direct = direct_light(n, v, position, alpha, specular_energy);

    vec3 diffuse_ibl = vec3(0.0);
    vec3 specular_ibl = vec3(0.0);
    vec3 irradiance = vec3(0.0);
#if IBL_MODE != IBL_NONE
    vec3 specular_albedo = g_f0 * scale_bias.x + scale_bias.y;
#if HEAT_TINT && HAS_TEMPERATURE
    specular_albedo *= film_tint(nv);
#endif
    irradiance = max(sh9_irradiance(u_sh, u_world_to_env * n), 0.0) * u_env_intensity;
    diffuse_ibl = (1.0 - specular_albedo) * g_diffuse_albedo * irradiance * (1.0 / PI);
#if IBL_MODE == IBL_PREFILTERED && ANISOTROPIC
    specular_ibl = prefiltered_anisotropic(n, v, g_frame) * u_env_intensity * specular_albedo;
#elif IBL_MODE == IBL_PREFILTERED
    vec3 r = u_world_to_env * reflect(-v, n);
    float lod = clamp(lookup_roughness, 0.0, 1.0) * u_prefiltered_max_lod;
    specular_ibl = textureLod(u_env_prefiltered, equirect_uv(r), lod).rgb * u_env_intensity
        * specular_albedo;
#else
#if ANISOTROPIC
    specular_ibl = sampled_specular_anisotropic(n, v, nv, g_frame);
#else
    specular_ibl = sampled_specular(n, v, nv, alpha);
#endif
#endif
    specular_ibl *= specular_energy;
#endif
    vec3 indirect = diffuse_ibl + specular_ibl;

    vec3 emission = vec3(0.0);
#if HAS_TEMPERATURE
    float kelvin = texelFetch(u_temperature, source, 0).r;
    // Kirchhoff: emissivity = 1 - reflectance; its angular shape follows Schlick with
    // F0_e = 1 - emissivity, so (1 - F) = emissivity (1 - (1 - n.v)^5).
    vec3 emissivity = u_emissivity * (1.0 - pow5(1.0 - nv));
    emission = emissivity * blackbody_radiance(kelvin) * u_emission_scale;
#endif

#if COMBINE == COMBINE_WEIGHTED
    vec3 color = u_direct_weight * direct + (1.0 - u_direct_weight) * indirect + emission;
#else
    vec3 color = direct + indirect + emission;
#endif
#if DEBUG_VIEW == VIEW_DIRECT
    color = direct;
#elif DEBUG_VIEW == VIEW_DIFFUSE_IBL
    color = diffuse_ibl;
#elif DEBUG_VIEW == VIEW_SPECULAR_IBL
    color = specular_ibl;
#elif DEBUG_VIEW == VIEW_EMISSION
    color = emission;
#elif DEBUG_VIEW == VIEW_IRRADIANCE
    color = irradiance;
#endif
    // Radiance is non-negative and finite; clamp keeps absurd inputs (1e12 lights on mirrors)
    // inside fp32 instead of letting them reach +inf.
    color = clamp(color, vec3(0.0), vec3(1e30));
#if ANTIALIAS && BACKGROUND_ENVIRONMENT
    vec3 ray = u_view_to_world * view_position(pixel, size, u_tan_half_fov, 1.0);
    out_color = vec4(mix(environment_radiance(normalize(ray), 0.0), color, coverage), 1.0);
#elif ANTIALIAS
    out_color = vec4(color, coverage);
#else
    out_color = vec4(color, 1.0);
#endif
}
