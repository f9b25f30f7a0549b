// Microfacet BRDF of the thesis §4.2.1 (eq 33-38) with the corrections in validation-data.md:
//   f_r = (1 - F) c_diff / pi + D G F / (4 (n.l)(n.v))
// F itself plays k_s (it is not applied twice), k_d = 1 - F. D is GGX (eq 36) with
// alpha = roughness^2; G is Smith height-correlated GGX (Heitz 2014; Filament) or the thesis's
// eq 37 (Cook-Torrance / Blinn 1977), chosen by G_TERM. Everything returns the *visibility*
// V = G / (4 (n.l)(n.v)) so that neither term divides by a vanishing cosine on its own.

#define G_TERM_SMITH_HEIGHT_CORRELATED 0
#define G_TERM_COOK_TORRANCE 1
#define G_TERM 0

const float PI = 3.14159265358979;
// Smallest perceptual roughness (alpha = 0.002025): D's peak 1 / (pi alpha^2) ~ 7.8e4 and
// alpha^4 stay in fp32's normal range (Frostbite/Filament use the same clamp).
const float MIN_ROUGHNESS = 0.045;
// Smallest n.v used: screen-space normals at silhouettes can be exactly perpendicular.
const float MIN_NV = 1e-4;

float alpha_from_roughness(float roughness) {
    float r = clamp(roughness, MIN_ROUGHNESS, 1.0);
    return r * r;
}

// GGX / Trowbridge-Reitz D (eq 36). `one_minus_nh2` = 1 - (n.h)^2 = |n x h|^2 is passed in
// separately: computed from the cross product it keeps full relative precision near the
// peak, where 1 - nh*nh would cancel (Filament's trick).
float d_ggx(float nh, float one_minus_nh2, float alpha) {
    float a = nh * alpha;
    float k = alpha / (one_minus_nh2 + a * a);
    return k * k * (1.0 / PI);
}

// V = G / (4 n.l n.v) for the selected G.
float visibility(float nl, float nv, float nh, float vh, float alpha) {
#if G_TERM == G_TERM_SMITH_HEIGHT_CORRELATED
    float a2 = alpha * alpha;
    float ggx_v = nl * sqrt(nv * nv * (1.0 - a2) + a2);
    float ggx_l = nv * sqrt(nl * nl * (1.0 - a2) + a2);
    return 0.5 / (ggx_v + ggx_l);
#else
    // eq 37: G = min(1, 2 nh nv / vh, 2 nh nl / lh), and l.h = v.h for the half vector.
    // Divided by 4 nl nv term by term, so no 0/0 when a cosine vanishes.
    float g_over = min(1.0 / (4.0 * nl * nv), nh / (2.0 * vh * nl));
    return min(g_over, nh / (2.0 * vh * nv));
#endif
}

float pow5(float x) {
    float x2 = x * x;
    return x2 * x2 * x;
}

// Schlick's Fresnel (eq 35).
vec3 fresnel_schlick(vec3 f0, float cos_theta) {
    return f0 + (1.0 - f0) * pow5(clamp(1.0 - cos_theta, 0.0, 1.0));
}

// The Fresnel of the specular lobes; a shader may name its own (declared before this include).
#ifndef SURFACE_FRESNEL
#define SURFACE_FRESNEL fresnel_schlick
#endif

// The two lobes of f_r (no cosine) for unit n, v, l with n.l > 0: (1 - F) c_diff / pi and D V F.
void brdf_lobes(
    vec3 n, vec3 v, vec3 l, vec3 f0, vec3 diffuse_albedo, float alpha,
    out vec3 diffuse, out vec3 specular
) {
    vec3 h = normalize(v + l);
    float nl = max(dot(n, l), 0.0);
    float nv = max(dot(n, v), MIN_NV);
    float nh = max(dot(n, h), 0.0);
    float vh = max(dot(v, h), 0.0);
    vec3 nxh = cross(n, h);
    float d = d_ggx(nh, dot(nxh, nxh), alpha);
    vec3 f = SURFACE_FRESNEL(f0, vh);
    diffuse = (1.0 - f) * diffuse_albedo * (1.0 / PI);
    specular = d * visibility(nl, nv, nh, vh, alpha) * f;
}

// The whole BRDF times nothing (no cosine): returns f_r for unit n, v, l with n.l > 0.
vec3 brdf(vec3 n, vec3 v, vec3 l, vec3 f0, vec3 diffuse_albedo, float alpha) {
    vec3 diffuse;
    vec3 specular;
    brdf_lobes(n, v, l, f0, diffuse_albedo, alpha, diffuse, specular);
    return diffuse + specular;
}
