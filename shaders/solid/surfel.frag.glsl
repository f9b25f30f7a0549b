#version 330 core
// A disc cut by the particle's other faces' planes: world normal + eye depth, and a linear
// gl_FragDepth (eye depth / far) shared with the core spheres for the depth test.
#define HAS_TEMPERATURE 0

in vec3 v_view_position;
in vec2 v_local;
flat in vec3 v_world_normal;
flat in vec4 v_clip0;
flat in vec4 v_clip1;
flat in vec4 v_clip2;
flat in vec2 v_temperature;

uniform float u_near;
uniform float u_far;

layout(location = 0) out vec4 out_normal_depth;
#if HAS_TEMPERATURE
layout(location = 1) out vec2 out_temperature;  // kelvin, peak kelvin
#endif

void main() {
    if (dot(v_local, v_local) > 1.0) {
        discard;
    }
    vec3 p = v_view_position;
    if (dot(v_clip0.xyz, p) > v_clip0.w || dot(v_clip1.xyz, p) > v_clip1.w
            || dot(v_clip2.xyz, p) > v_clip2.w) {
        discard;
    }
    float eye_depth = -p.z;
    if (!(eye_depth >= u_near && eye_depth <= u_far)) {
        discard;
    }
    out_normal_depth = vec4(v_world_normal, eye_depth);
#if HAS_TEMPERATURE
    out_temperature = v_temperature;
#endif
    gl_FragDepth = clamp(eye_depth / u_far, 0.0, 1.0);
}
