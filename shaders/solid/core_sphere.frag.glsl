#version 330 core
// Ray-sphere front hit: world normal (view-to-world rotation) + eye depth, linear gl_FragDepth.
#define HAS_TEMPERATURE 0

in vec3 v_view_position;
flat in vec4 v_sphere;
flat in vec2 v_temperature;

uniform float u_near;
uniform float u_far;
uniform mat3 u_view_to_world;

layout(location = 0) out vec4 out_normal_depth;
#if HAS_TEMPERATURE
layout(location = 1) out vec2 out_temperature;  // kelvin, peak kelvin
#endif

void main() {
    vec3 direction = normalize(v_view_position);
    vec3 center = v_sphere.xyz;
    float along = dot(direction, center);
    vec3 perpendicular = center - along * direction;
    float discriminant = v_sphere.w * v_sphere.w - dot(perpendicular, perpendicular);
    if (discriminant < 0.0 || along <= 0.0) {
        discard;
    }
    float t = along - sqrt(discriminant);
    vec3 hit = t * direction;
    float eye_depth = -hit.z;
    if (!(eye_depth >= u_near && eye_depth <= u_far)) {
        discard;
    }
    out_normal_depth = vec4(normalize(u_view_to_world * (hit - center)), eye_depth);
#if HAS_TEMPERATURE
    out_temperature = v_temperature;
#endif
    gl_FragDepth = clamp(eye_depth / u_far, 0.0, 1.0);
}
