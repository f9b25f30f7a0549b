// Heat tint and molten metal per pixel (server/engine/lighting/thin_film.py, materials.py).
// HEAT_TINT: the oxide film a peak temperature leaves, as thin-film interference on the metal's
// Fresnel: the preset's Schlick F times R_film(d, cos) / R_film(0, cos), R_film read from the
// spectral table (thin_film.py), d from the peak by the material's Arrhenius calibration.
// MOLTEN: above the liquidus the liquid metal's F0 and roughness, below the solidus the
// material's own with its tint, linear in temperature across the mushy range.

uniform sampler2D u_film_table;      // RGB reflectance over (film nm / u_film_max_nm, cos theta)
uniform float u_film_max_nm;
uniform vec2 u_oxide_calibration;    // (T_ref K, E K): d = d_ref exp(E (1 / T_ref - 1 / T))
uniform float u_oxide_reference_nm;
uniform sampler2D u_peak_temperature;  // kelvin, the surface's peak (the current one without)
uniform vec2 u_melting_range;        // (solidus, liquidus) K
uniform vec3 u_liquid_f0;
uniform float u_liquid_roughness;

float g_film_nm = 0.0;   // this pixel's oxide thickness
float g_oxide = 0.0;     // how much of the pixel is solid, tinted metal (0: liquid)

vec3 film_reflectance(float nm, float cos_theta) {
    vec2 size = vec2(textureSize(u_film_table, 0));
    vec2 x = clamp(vec2(nm / u_film_max_nm, cos_theta), 0.0, 1.0);
    return textureLod(u_film_table, (x * (size - 1.0) + 0.5) / size, 0.0).rgb;
}

// What the film does to the bare metal's reflectance at this angle (1: no film or liquid).
vec3 film_tint(float cos_theta) {
    vec3 bare = max(film_reflectance(0.0, cos_theta), vec3(1e-4));
    return mix(vec3(1.0), film_reflectance(g_film_nm, cos_theta) / bare, g_oxide);
}

// The Fresnel term every specular lobe uses (common/brdf.glsl's SURFACE_FRESNEL).
vec3 heat_fresnel(vec3 f0, float cos_theta) {
    return min(fresnel_schlick(f0, cos_theta) * film_tint(cos_theta), vec3(1.0));
}

// 0 below the solidus, 1 above the liquidus, linear between (a step for a pure metal).
float liquid_fraction(float kelvin) {
    if (kelvin >= u_melting_range.y) {
        return 1.0;
    }
    return clamp((kelvin - u_melting_range.x) / max(u_melting_range.y - u_melting_range.x, 1e-3),
                 0.0, 1.0);
}

float oxide_thickness_nm(float peak_kelvin) {
    float t = max(peak_kelvin, 1.0);
    float exponent = u_oxide_calibration.y * (1.0 / u_oxide_calibration.x - 1.0 / t);
    return u_oxide_reference_nm * exp(min(exponent, 20.0));
}

// This pixel's hot metal: liquid fraction from the current temperature, oxide film from the
// peak (max(peak, current): a peak below the current temperature is raised to it).
void hot_metal(ivec2 source) {
    float kelvin = texelFetch(u_temperature, source, 0).r;
#if MOLTEN
    float liquid = liquid_fraction(kelvin);
    g_f0 = mix(g_f0, u_liquid_f0, liquid);
    g_diffuse_albedo *= 1.0 - liquid;
    g_roughness = mix(g_roughness, u_liquid_roughness, liquid);
#else
    float liquid = 0.0;
#endif
#if HEAT_TINT
    float peak = max(texelFetch(u_peak_temperature, source, 0).r, kelvin);
    g_film_nm = oxide_thickness_nm(peak);
    g_oxide = 1.0 - liquid;
#endif
}
