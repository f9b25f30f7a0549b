#version 430 core
// Ray-ellipsoid intersection per fragment: in unit-sphere coordinates u = A^-1 (x - c) the ray
// t d becomes t d' - c' (d' = A^-1 d, c' = A^-1 c), a sphere test of radius 1. As for spheres
// (splat_sphere.frag.glsl), the miss distance comes from the perpendicular vector
// c' - (c'.d'/d'.d') d', which does not cancel when the ellipsoid is far relative to its size.
// Depth mode: eye depth (R32F) + linear gl_FragDepth; HAS_TEMPERATURE adds the kelvin target.
// COVERAGE mode (the coverage pass, blend MAX): sub-pixel coverage from the normalised miss
// distance 1 - |q| divided by its screen-space rate (dFdx, dFdy), as the sphere coverage does
// with the angular distance.

#define HAS_TEMPERATURE 0
#define COVERAGE 0

#include "common/edge_coverage.glsl"
#include "common/splat_kelvin.glsl"

in vec3 v_view_position;
flat in vec3 v_center;
flat in mat3 v_to_unit;
flat in vec2 v_temperature;

uniform float u_near;
uniform float u_far;

#if COVERAGE
// Outside the band (coverage_band.frag.glsl) the target's depth test rejects the fragment
// first (splat_coverage.frag.glsl).
layout(early_fragment_tests) in;
layout(location = 0) out float out_coverage;
#else
layout(location = 0) out float out_eye_depth;
#if HAS_TEMPERATURE
layout(location = 1) out SPLAT_KELVIN out_temperature;
#endif
#endif

void main() {
    vec3 direction = normalize(v_view_position);
    vec3 d = v_to_unit * direction;
    vec3 c = v_to_unit * v_center;
    float dd = dot(d, d);
    float along = dot(c, d) / dd;   // ray parameter of the point closest to the centre
    vec3 perpendicular = c - along * d;
    float miss2 = dot(perpendicular, perpendicular);
#if COVERAGE
    float miss = sqrt(miss2);
    // Distance to the edge in pixels: (1 - miss) / |gradient|; edge normal: the gradient.
    vec2 gradient = vec2(dFdx(miss), dFdy(miss));
    float rate = length(gradient);
    float coverage = rate > 0.0 ? edge_coverage((1.0 - miss) / rate, gradient / rate)
                                : (miss <= 1.0 ? 1.0 : 0.0);
    if (coverage <= 0.0 || along <= 0.0) {
        discard;
    }
    if (miss2 <= 1.0 && -((along - sqrt((1.0 - miss2) / dd)) * direction.z) < u_near) {
        discard;  // the front surface is cut by the near plane here, as in the depth splat
    }
    out_coverage = coverage;
#else
    if (miss2 > 1.0 || along <= 0.0) {
        discard;
    }
    float t = along - sqrt((1.0 - miss2) / dd);
    float eye_depth = -(t * direction.z);
    if (!(eye_depth >= u_near && eye_depth <= u_far)) {
        discard;  // the front surface is cut by the near or far plane (or is not finite)
    }
    out_eye_depth = eye_depth;
#if HAS_TEMPERATURE
    out_temperature = SPLAT_KELVIN_OF(v_temperature);
#endif
    gl_FragDepth = clamp(eye_depth / u_far, 0.0, 1.0);
#endif
}
