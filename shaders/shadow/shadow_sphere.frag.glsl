#version 430 core
// The nearest sphere surface along each shadow-map texel's ray (passes/shadow.py): CUBE, the
// distance from the light; otherwise the depth behind the map's near plane. Written into an R32F
// target under MIN blending (no depth buffer), cleared to "nothing".

#define CUBE 1

in vec3 v_position;
flat in vec4 v_sphere;

layout(location = 0) out float out_distance;

void main() {
#if CUBE
    vec3 ray = normalize(v_position);
    float along = dot(ray, v_sphere.xyz);
    vec3 off = v_sphere.xyz - along * ray;  // closest approach: no cancellation far away
    float h2 = v_sphere.w * v_sphere.w - dot(off, off);
    if (h2 < 0.0) {
        discard;
    }
    out_distance = max(along - sqrt(h2), 0.0);
#else
    vec2 off = v_position.xy - v_sphere.xy;
    float h2 = v_sphere.w * v_sphere.w - dot(off, off);
    if (h2 < 0.0) {
        discard;
    }
    out_distance = v_sphere.z - sqrt(h2);
#endif
}
