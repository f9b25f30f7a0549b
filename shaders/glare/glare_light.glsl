// The light a glare pass spreads (passes/glare.py): the pixel's premultiplied radiance, made
// finite (NaN -> 0, anything past +-GLARE_LIMIT clipped there, so sums of taps stay finite),
// and the part of it above the exposed threshold, by luminance, that goes through the PSF.

const float GLARE_LIMIT = 1e30;
const vec3 LUMINANCE = vec3(0.2126, 0.7152, 0.0722);

uniform float u_threshold;   // the threshold in scene-linear luminance (threshold / 2^exposure)

vec4 premultiplied(vec4 color) {
    vec4 c = vec4(isnan(color.r) ? 0.0 : color.r, isnan(color.g) ? 0.0 : color.g,
                  isnan(color.b) ? 0.0 : color.b, isnan(color.a) ? 0.0 : color.a);
    c.a = clamp(c.a, 0.0, 1.0);
    return vec4(clamp(c.rgb * c.a, -GLARE_LIMIT, GLARE_LIMIT), c.a);
}

vec3 excess(vec3 radiance) {
    vec3 positive = max(radiance, vec3(0.0));
    float y = dot(positive, LUMINANCE);
    float kept = y > u_threshold ? u_threshold / y : 1.0;
    return positive * (1.0 - kept);
}
