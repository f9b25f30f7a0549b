// Specular image-based light for the anisotropic lobe (lighting/anisotropic_ggx.glsl), included
// by shade_pbr.frag.glsl after its uniforms: per-pixel importance sampling of D(h) (n.h), the
// same estimator and pdf-based source LOD as sampled_specular, with the anisotropic D and V.

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
