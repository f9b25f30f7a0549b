#version 330 core
// Ray-sphere intersection per fragment gives the exact, perspective-correct front surface.
// Output: eye depth (positive, along the view axis) into an R32F target, and a *linear*
// gl_FragDepth (eye depth / far) for the depth test, so precision does not depend on near.
// With HAS_TEMPERATURE a second target receives the front-most particle's temperature (kelvin)
// (and its peak: common/splat_kelvin.glsl).

#define HAS_TEMPERATURE 0

#include "common/splat_kelvin.glsl"

in vec3 v_view_position;
flat in vec4 v_sphere;
flat in vec2 v_temperature;

uniform float u_near;
uniform float u_far;

layout(location = 0) out float out_eye_depth;
#if HAS_TEMPERATURE
layout(location = 1) out SPLAT_KELVIN out_temperature;
#endif

void main() {
    vec3 direction = normalize(v_view_position);
    vec3 center = v_sphere.xyz;
    float radius = v_sphere.w;
    float along = dot(direction, center);
    // Squared distance from the centre to the ray, computed from the perpendicular vector so
    // it does not cancel when |center| >> radius.
    vec3 perpendicular = center - along * direction;
    float discriminant = radius * radius - dot(perpendicular, perpendicular);
    if (discriminant < 0.0 || along <= 0.0) {
        discard;
    }
    float t = along - sqrt(discriminant);
    float eye_depth = -(t * direction.z);
    if (!(eye_depth >= u_near && eye_depth <= u_far)) {
        discard;  // the front surface is cut by the near or far plane (or is not finite)
    }
    out_eye_depth = eye_depth;
#if HAS_TEMPERATURE
    out_temperature = SPLAT_KELVIN_OF(v_temperature);
#endif
    gl_FragDepth = clamp(eye_depth / u_far, 0.0, 1.0);
}
