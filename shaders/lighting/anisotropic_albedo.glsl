// The anisotropic lobe's split-sum scale and bias (A, B) for any F0, from the 3-D table of
// lighting/anisotropic_lut.frag.glsl: axes sqrt(n.v), the view's azimuth from the brush folded
// to [0, pi/2] (cosine spacing), sqrt(alpha_t); sqrt(alpha_b) is the slab index, interpolated
// here between two fetches. Sizes from the texture: (NV, PHI, ROUGH^2). Needs
// lighting/anisotropic_ggx.glsl.

float albedo_texel(float unit, float count) {
    return (clamp(unit, 0.0, 1.0) * (count - 1.0) + 0.5) / count;
}

vec2 anisotropic_scale_bias(sampler3D table, float nv, vec3 v, AnisotropicFrame f) {
    vec3 size = vec3(textureSize(table, 0));
    float rough = floor(sqrt(size.z) + 0.5);
    float phi = atan(abs(dot(f.b, v)), abs(dot(f.t, v)) + 1e-20);
    float x = albedo_texel(sqrt(nv), size.x);
    // Cosine spacing; the clamp keeps acos defined where atan rounds past pi/2.
    float y = albedo_texel(acos(clamp(1.0 - phi * (4.0 / PI), -1.0, 1.0)) * (1.0 / PI), size.y);
    float span = 1.0 / (1.0 - MIN_ROUGHNESS);
    float t = clamp((sqrt(f.alpha_t) - MIN_ROUGHNESS) * span, 0.0, 1.0) * (rough - 1.0);
    float b = clamp((sqrt(f.alpha_b) - MIN_ROUGHNESS) * span, 0.0, 1.0) * (rough - 1.0);
    float b0 = min(floor(b), rough - 2.0);
    float slabs = size.z;
    vec2 lower = texture(table, vec3(x, y, (b0 * rough + t + 0.5) / slabs)).rg;
    vec2 upper = texture(table, vec3(x, y, ((b0 + 1.0) * rough + t + 0.5) / slabs)).rg;
    return mix(lower, upper, b - b0);
}
