#version 330 core
// PLACEHOLDER shading until the physically based metal shading lands: grey Lambert under one
// light fixed relative to the camera plus a constant ambient. Straight (not premultiplied)
// colour; alpha is coverage (1 on the surface, 0 elsewhere).

uniform sampler2D u_normal_depth;
uniform vec3 u_light_direction_world;   // unit vector towards the light
uniform vec3 u_base_color;

layout(location = 0) out vec4 out_color;

void main() {
    vec4 normal_depth = texelFetch(u_normal_depth, ivec2(gl_FragCoord.xy), 0);
    if (normal_depth.w <= 0.0) {
        out_color = vec4(0.0);
        return;
    }
    float lambert = max(dot(normal_depth.xyz, u_light_direction_world), 0.0);
    out_color = vec4(u_base_color * (0.15 + 0.85 * lambert), 1.0);
}
