#version 330 core
// The nearer of the fluid surface and the solid per pixel: normal + eye depth, eye depth alone
// (the temperature blur's guide), kelvin, coverage (a solid pixel is covered whole).
#define HAS_TEMPERATURE 0
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
layout(location = 2) out float out_temperature;
layout(location = 3) out float out_coverage;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 fluid = texelFetch(u_fluid_normal_depth, pixel, 0);
    vec4 solid = texelFetch(u_solid_normal_depth, pixel, 0);
    bool take_solid = solid.w > 0.0 && (fluid.w <= 0.0 || solid.w < fluid.w);
    out_normal_depth = take_solid ? solid : fluid;
    out_depth = take_solid ? solid.w : max(fluid.w, 0.0);
#if HAS_TEMPERATURE
    out_temperature = take_solid ? texelFetch(u_solid_temperature, pixel, 0).r
                                 : texelFetch(u_fluid_temperature, pixel, 0).r;
#else
    out_temperature = 0.0;
#endif
#if HAS_COVERAGE
    out_coverage = take_solid ? 1.0 : texelFetch(u_fluid_coverage, pixel, 0).r;
#else
    out_coverage = take_solid || fluid.w > 0.0 ? 1.0 : 0.0;
#endif
}
