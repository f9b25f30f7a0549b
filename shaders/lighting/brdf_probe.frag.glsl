#version 330 core
// Evaluates the shading BRDF (common/brdf.glsl) at parameters given per pixel, so tests can
// compare the shader's own arithmetic with a numpy reference. n = +z; v in the xz plane;
// l at azimuth phi from v.
//   u_params0 (RGBA32F): n.l, n.v, phi (radians), perceptual roughness
//   u_params1 (RGBA32F): F0 rgb, metallic-workflow diffuse albedo (grey)
// Output: f_r rgb, and D * V in alpha.

#include "common/brdf.glsl"

uniform sampler2D u_params0;
uniform sampler2D u_params1;

layout(location = 0) out vec4 out_value;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 p0 = texelFetch(u_params0, p, 0);
    vec4 p1 = texelFetch(u_params1, p, 0);
    float nl = p0.x;
    float nv = p0.y;
    float phi = p0.z;
    float alpha = alpha_from_roughness(p0.w);
    vec3 n = vec3(0.0, 0.0, 1.0);
    vec3 v = vec3(sqrt(max(1.0 - nv * nv, 0.0)), 0.0, nv);
    float sl = sqrt(max(1.0 - nl * nl, 0.0));
    vec3 l = vec3(sl * cos(phi), sl * sin(phi), nl);
    vec3 f = brdf(n, v, l, p1.rgb, vec3(p1.a), alpha);
    vec3 h = normalize(v + l);
    vec3 nxh = cross(n, h);
    float dv = d_ggx(max(dot(n, h), 0.0), dot(nxh, nxh), alpha)
        * visibility(max(nl, 0.0), max(nv, MIN_NV), max(dot(n, h), 0.0), max(dot(v, h), 0.0), alpha);
    out_value = vec4(f, dv);
}
