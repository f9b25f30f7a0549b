// Anisotropic GGX for brushed metal (Burley 2012; Heitz 2014, "Understanding the
// Masking-Shadowing Function"), with t along the brush and b across it, in the tangent plane:
//   D(h) = 1 / (pi at ab ((t.h / at)^2 + (b.h / ab)^2 + (n.h)^2)^2)
//   V    = G2 / (4 n.l n.v), height-correlated Smith:
//          0.5 / (n.l |(at t.v, ab b.v, n.v)| + n.v |(at t.l, ab b.l, n.l)|)
// The thesis's Cook-Torrance G (G_TERM 1) does not depend on alpha and is used as it is.
// Needs common/brdf.glsl and common/sampling.glsl.

// sin^2 of the brush-normal angle below which the lobe fades to isotropic (about 6 degrees):
// the projected brush direction turns arbitrary there, so the anisotropy fades with it.
const float BRUSH_FADE_SIN2 = 0.01;

struct AnisotropicFrame {
    vec3 t;         // along the brush (unit, tangent plane)
    vec3 b;         // across the brush, n x t
    float alpha_t;
    float alpha_b;
    float strength; // the anisotropy after the fade, in [-1, 1]
};

// The frame at unit normal `n` for a world brush direction `brush` (unit) and `anisotropy` in
// [-1, 1]; alpha along = alpha (1 - a), across = alpha (1 + a), clamped to [MIN alpha, 1].
AnisotropicFrame anisotropic_frame(vec3 n, vec3 brush, float alpha, float anisotropy) {
    AnisotropicFrame f;
    vec3 along = brush - n * dot(n, brush);
    float sin2 = dot(along, along);
    if (sin2 > 1e-12) {
        f.t = along * inversesqrt(sin2);
        f.b = cross(n, f.t);
    } else {
        tangent_frame(n, f.t, f.b);
    }
    f.strength = anisotropy * clamp(sin2 / BRUSH_FADE_SIN2, 0.0, 1.0);
    float min_alpha = MIN_ROUGHNESS * MIN_ROUGHNESS;
    f.alpha_t = clamp(alpha * (1.0 - f.strength), min_alpha, 1.0);
    f.alpha_b = clamp(alpha * (1.0 + f.strength), min_alpha, 1.0);
    return f;
}

float d_ggx_anisotropic(AnisotropicFrame f, vec3 n, vec3 h) {
    float x = dot(f.t, h) / f.alpha_t;
    float y = dot(f.b, h) / f.alpha_b;
    float z = max(dot(n, h), 0.0);
    float s = x * x + y * y + z * z;
    return 1.0 / (PI * f.alpha_t * f.alpha_b * s * s);
}

float visibility_anisotropic(AnisotropicFrame f, vec3 v, vec3 l, float nl, float nv, float nh,
                             float vh) {
#if G_TERM == G_TERM_SMITH_HEIGHT_CORRELATED
    float lambda_v = nl * length(vec3(f.alpha_t * dot(f.t, v), f.alpha_b * dot(f.b, v), nv));
    float lambda_l = nv * length(vec3(f.alpha_t * dot(f.t, l), f.alpha_b * dot(f.b, l), nl));
    return 0.5 / (lambda_v + lambda_l);
#else
    return visibility(nl, nv, nh, vh, 1.0);
#endif
}

// brdf_lobes (common/brdf.glsl) with the anisotropic D and V.
void brdf_lobes_anisotropic(
    vec3 n, vec3 v, vec3 l, vec3 f0, vec3 diffuse_albedo, AnisotropicFrame frame,
    out vec3 diffuse, out vec3 specular
) {
    vec3 h = normalize(v + l);
    float nl = max(dot(n, l), 0.0);
    float nv = max(dot(n, v), MIN_NV);
    float nh = max(dot(n, h), 0.0);
    float vh = max(dot(v, h), 0.0);
    float d = d_ggx_anisotropic(frame, n, h);
    vec3 f = SURFACE_FRESNEL(f0, vh);
    diffuse = (1.0 - f) * diffuse_albedo * (1.0 / PI);
    specular = d * visibility_anisotropic(frame, v, l, nl, nv, nh, vh) * f;
}

// Half vector with pdf D(h) (n.h) for the anisotropic lobe, in the (t, b, n) frame: the
// alpha = 1 sample (cos^2 theta = 1 - xi.x) with its slopes stretched by (at, ab), which maps
// the unit slope distribution onto the anisotropic one (Heitz 2014, section 5).
vec3 sample_ggx_anisotropic_tangent(vec2 xi, AnisotropicFrame f) {
    float sin_t = sqrt(xi.x);
    float cos_t = sqrt(1.0 - xi.x);
    float phi = 2.0 * PI * xi.y;
    return normalize(vec3(f.alpha_t * sin_t * cos(phi), f.alpha_b * sin_t * sin(phi), cos_t));
}

// The perceptual roughness of the lobe's RMS slope, alpha = sqrt((at^2 + ab^2) / 2): the
// prefiltered level along the plain reflection where no tap of prefiltered_anisotropic
// (shade/anisotropic_ibl.glsl) lies above the horizon.
float anisotropic_lookup_roughness(AnisotropicFrame f) {
    return sqrt(sqrt(0.5 * (f.alpha_t * f.alpha_t + f.alpha_b * f.alpha_b)));
}
