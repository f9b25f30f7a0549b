#version 330 core
// The nearer of the fluid surface and the solid per pixel: normal + eye depth, eye depth alone
// (the temperature blur's guide), kelvin, coverage. With anti-aliasing the solid's silhouette
// gets a coverage from its 3x3 neighbourhood (the discs give no sub-pixel area): a pixel with
// the solid at its centre 0.5 + 0.5 x (covered neighbours / 8), one without 0.5 x (solid
// neighbours / 8), so a straight edge's two pixels still add up to about one.
#define HAS_TEMPERATURE 0
#define HAS_PEAK 0
#define HAS_COVERAGE 0

uniform sampler2D u_fluid_normal_depth;
uniform sampler2D u_solid_normal_depth;
#if HAS_TEMPERATURE
uniform sampler2D u_fluid_temperature;
uniform sampler2D u_solid_temperature;
#endif
#if HAS_COVERAGE
uniform sampler2D u_fluid_coverage;
#endif

layout(location = 0) out vec4 out_normal_depth;
layout(location = 1) out float out_depth;
#if HAS_PEAK
layout(location = 2) out vec2 out_temperature;  // kelvin, peak kelvin (a fluid without: 0)
#else
layout(location = 2) out float out_temperature;
#endif
layout(location = 3) out float out_coverage;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 fluid = texelFetch(u_fluid_normal_depth, pixel, 0);
    vec4 solid = texelFetch(u_solid_normal_depth, pixel, 0);
    bool take_solid = solid.w > 0.0 && (fluid.w <= 0.0 || solid.w < fluid.w);
    out_normal_depth = take_solid ? solid : fluid;
    out_depth = take_solid ? solid.w : max(fluid.w, 0.0);
#if HAS_TEMPERATURE
#if HAS_PEAK
    out_temperature = take_solid ? texelFetch(u_solid_temperature, pixel, 0).rg
                                 : texelFetch(u_fluid_temperature, pixel, 0).rg;
#else
    out_temperature = take_solid ? texelFetch(u_solid_temperature, pixel, 0).r
                                 : texelFetch(u_fluid_temperature, pixel, 0).r;
#endif
#else
    out_temperature = 0.0;
#endif
#if HAS_COVERAGE
    float fluid_coverage = texelFetch(u_fluid_coverage, pixel, 0).r;
    ivec2 last = textureSize(u_fluid_normal_depth, 0) - 1;
    float covered = 0.0;
    float solid_near = 0.0;
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            if (dx == 0 && dy == 0) {
                continue;
            }
            ivec2 q = clamp(pixel + ivec2(dx, dy), ivec2(0), last);
            bool solid_q = texelFetch(u_solid_normal_depth, q, 0).w > 0.0;
            bool fluid_q = texelFetch(u_fluid_normal_depth, q, 0).w > 0.0
                || texelFetch(u_fluid_coverage, q, 0).r > 0.0;
            covered += solid_q || fluid_q ? 1.0 : 0.0;
            solid_near += solid_q ? 1.0 : 0.0;
        }
    }
    if (take_solid) {
        out_coverage = 0.5 + 0.5 * covered / 8.0;
    } else if (fluid.w > 0.0) {
        out_coverage = fluid_coverage;
    } else {
        out_coverage = max(fluid_coverage, 0.5 * solid_near / 8.0);
    }
#else
    out_coverage = take_solid || fluid.w > 0.0 ? 1.0 : 0.0;
#endif
}
