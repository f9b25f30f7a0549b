#version 330 core
// The normal guide's flat-beyond flags (quality.normal_guide, passes/smooth.py), for the
// 1-D passes along AXIS: per pixel, whether the pilot surface is flat past it in +AXIS and in
// -AXIS (the pilot normals at 1, 2 and 3 times u_flat_radii projected radii on agree within
// u_flat_cos; background there is no evidence). Out: guide_normals.frag.glsl's normal in 7 bits a
// component, + 2^21 (flat along +AXIS) + 2^22 (flat along -AXIS), negative for a rim pixel
// (decoded by guide_limits.frag.glsl). Packed in and out.

#define AXIS 0

#include "common/packed_image.glsl"

uniform sampler2D u_guide_normals;  // guide_normals.frag.glsl's
uniform sampler2D u_packed_depth;   // the pilot's depth (for the projected radius)
uniform ivec2 u_image_size_px;
uniform float u_px_per_unit;
uniform float u_particle_radius;
uniform float u_flat_radii;
uniform float u_flat_cos;

layout(location = 0) out vec4 out_packed_normals;

// guide_normals.frag.glsl's encoded normal at pixel (px, py), unit; 0 for background or past
// the image's end.
vec3 normal_at(int px, int py) {
    if (px < 0 || py < 0 || px >= u_image_size_px.x || py >= u_image_size_px.y) {
        return vec3(0.0);
    }
    float v = abs(texelFetch(u_guide_normals, ivec2(px >> 2, py), 0)[px & 3]);
    if (v <= 0.0) {
        return vec3(0.0);
    }
    float a = floor(v / 65536.0);
    float rest = v - a * 65536.0;
    float b = floor(rest / 256.0);
    vec3 n = vec3(a, b, rest - b * 256.0) / 127.5 - 1.0;
    return normalize(n);
}

bool agree(vec3 a, vec3 b) {
    return dot(a, a) == 0.0 || dot(b, b) == 0.0 || dot(a, b) >= u_flat_cos;
}

// Whether the pilot is flat past (px, py) in direction `step` (unit along AXIS) at `reach` px.
bool flat_past(int px, int py, ivec2 step, float reach) {
    ivec2 p = ivec2(px, py);
    vec3 n1 = normal_at(p.x + int(round(reach)) * step.x, p.y + int(round(reach)) * step.y);
    vec3 n2 = normal_at(p.x + int(round(2.0 * reach)) * step.x,
                        p.y + int(round(2.0 * reach)) * step.y);
    vec3 n3 = normal_at(p.x + int(round(3.0 * reach)) * step.x,
                        p.y + int(round(3.0 * reach)) * step.y);
    return agree(n1, n2) && agree(n2, n3) && agree(n1, n3);
}

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 encoded = fetch_packed(u_guide_normals, texel);
    vec4 depth = fetch_packed(u_packed_depth, texel);
    vec4 result = vec4(0.0);
    ivec2 step = AXIS == 0 ? ivec2(1, 0) : ivec2(0, 1);
    for (int i = 0; i < 4; ++i) {
        float v = encoded[i];
        if (v == 0.0 || depth[i] <= 0.0) {
            continue;
        }
        int px = 4 * texel.x + i;
        vec3 n = normal_at(px, texel.y);
        float reach = max(u_flat_radii * u_particle_radius * u_px_per_unit / depth[i], 1.0);
        float flags = (flat_past(px, texel.y, step, reach) ? 2097152.0 : 0.0)
                      + (flat_past(px, texel.y, -step, reach) ? 4194304.0 : 0.0);
        vec3 q = floor((n * 0.5 + 0.5) * 127.0 + 0.5);
        float code = q.x * 16384.0 + q.y * 128.0 + q.z + flags;
        result[i] = v < 0.0 ? -code : code;
    }
    out_packed_normals = result;
}
