// Specular image-based light for the anisotropic lobe (lighting/anisotropic_ggx.glsl), included
// by shade_pbr.frag.glsl after its uniforms: per-pixel importance sampling of D(h) (n.h), the
// same estimator and pdf-based source LOD as sampled_specular, with the anisotropic D and V;
// and the prefiltered chain's radiance for the split sum, from four taps along the lobe.

// GGX's slope marginal along one axis (alpha 1) has CDF (1 + x / sqrt(1 + x^2)) / 2: these are
// its quantiles at 1/8, 3/8, 5/8, 7/8, so four equal taps stand for the lobe's long extent.
const float LOBE_TAPS[4] = float[4](-1.1339, -0.2582, 0.2582, 1.1339);

// The prefiltered radiance over the brushed lobe: four reflections of half vectors spread
// along its rough axis by the slope the isotropic level does not cover, sqrt(a_max^2 - a_min^2),
// each read at the smooth axis' level and weighted by the sampled estimator's G_vis (the albedo
// itself comes from the table). Against sampled mode, relative L1 0.41 -> 0.21 on spheres, 0.37
// -> 0.31 on the brushed plate (benchmarks/STUDIES.md). No tap above the horizon: the plain
// reflection at the lobe's RMS roughness.
vec3 prefiltered_anisotropic(vec3 n, vec3 v, AnisotropicFrame f) {
    float a_min = min(f.alpha_t, f.alpha_b);
    float a_max = max(f.alpha_t, f.alpha_b);
    vec3 axis = f.alpha_t > f.alpha_b ? f.t : f.b;
    float spread = sqrt(max(a_max * a_max - a_min * a_min, 0.0));
    float lod = clamp(sqrt(a_min), 0.0, 1.0) * u_prefiltered_max_lod;
    vec3 sum = vec3(0.0);
    float taps = 0.0;
    float nv = max(dot(n, v), MIN_NV);
    for (int k = 0; k < 4; ++k) {
        vec3 h = normalize(n + LOBE_TAPS[k] * spread * axis);
        float vh = dot(v, h);
        vec3 l = 2.0 * vh * h - v;
        float nl = dot(n, l);
        if (nl > 0.0 && vh > 0.0) {
            float nh = dot(n, h);
            float w = visibility_anisotropic(f, v, l, nl, nv, nh, vh) * nl * vh / nh;
            sum += w * textureLod(u_env_prefiltered, equirect_uv(u_world_to_env * l), lod).rgb;
            taps += w;
        }
    }
    if (taps > 0.0) {
        return sum / taps;
    }
    vec3 r = u_world_to_env * reflect(-v, n);
    lod = clamp(anisotropic_lookup_roughness(f), 0.0, 1.0) * u_prefiltered_max_lod;
    return textureLod(u_env_prefiltered, equirect_uv(r), lod).rgb;
}

vec3 sampled_specular_anisotropic(vec3 n, vec3 v, float nv, AnisotropicFrame frame) {
    vec3 sum = vec3(0.0);
    for (int i = 0; i < u_ibl_samples; ++i) {
        vec3 h_t = sample_ggx_anisotropic_tangent(hammersley(i, u_ibl_samples), frame);
        vec3 h = frame.t * h_t.x + frame.b * h_t.y + n * h_t.z;
        float vh = dot(v, h);
        vec3 l = 2.0 * vh * h - v;
        float nl = dot(n, l);
        if (nl <= 0.0 || vh <= 0.0) {
            continue;
        }
        float nh = h_t.z;
        float pdf = d_ggx_anisotropic(frame, n, h) * nh / (4.0 * vh);
        vec3 l_env = u_world_to_env * l;
        float omega_s = 1.0 / (float(u_ibl_samples) * pdf);
        float omega_p = equirect_texel_solid_angle(l_env, u_env_source_size);
        float lod = max(0.5 * log2(omega_s / omega_p) + 1.0, 0.0);
        vec3 radiance = textureLod(u_env_source, equirect_uv(l_env), lod).rgb;
        float weight = visibility_anisotropic(frame, v, l, nl, nv, nh, vh) * 4.0 * nl * vh / nh;
        sum += radiance * SURFACE_FRESNEL(g_f0, vh) * weight;
    }
    return sum * (u_env_intensity / float(u_ibl_samples));
}
