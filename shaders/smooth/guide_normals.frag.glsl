#version 330 core
// The normal guide's pilot normals (quality.normal_guide, passes/smooth.py): per pixel the view
// space normal of a packed eye-depth image (the pilot: the splat smoothed at about one projected
// radius), facing the eye, encoded for guide_flat.frag.glsl.
// In and out packed: texel (x, y) holds pixels 4x .. 4x+3 of row y in .xyzw; 0 = background;
// negative: a rim pixel (u_rim_radii).

#include "common/packed_image.glsl"

uniform sampler2D u_packed_depth;
uniform ivec2 u_image_size_px;  // the unpacked image
uniform float u_px_per_unit;    // (H / 2) / tan(fov_y / 2)
uniform float u_particle_radius;
// Pixels with background within this many projected radii (8 directions) are rim pixels,
// encoded negative (the guide cuts no tap of theirs); 0: none.
uniform float u_rim_radii;

layout(location = 0) out vec4 out_packed_normals;

vec3 view_position(float px, float py, float z) {
    vec2 centre = 0.5 * vec2(u_image_size_px);
    return vec3((vec2(px, py) + 0.5 - centre) * (z / u_px_per_unit), z);
}

// The difference of positions along one axis: central where both neighbours lie on the
// surface and neither steps much further than the other, else the side with the smaller step
// (a silhouette, a step to another surface); 0 where neither neighbour is surface.
vec3 axis_difference(vec3 minus, vec3 centre, vec3 plus, bool has_minus, bool has_plus) {
    float step_minus = abs(centre.z - minus.z);
    float step_plus = abs(plus.z - centre.z);
    if (has_minus && has_plus) {
        if (max(step_minus, step_plus) <= 3.0 * min(step_minus, step_plus) + 1e-6 * centre.z) {
            return 0.5 * (plus - minus);
        }
        return step_plus < step_minus ? plus - centre : centre - minus;
    }
    if (has_plus) {
        return plus - centre;
    }
    if (has_minus) {
        return centre - minus;
    }
    return vec3(0.0);
}

// Whether the pixel at (px, py) is background (past the image's end: not; the kernels go on
// one-sided there, image_border_taps.glsl).
bool background_at(int px, int py) {
    if (px < 0 || py < 0 || px >= u_image_size_px.x || py >= u_image_size_px.y) {
        return false;
    }
    return texelFetch(u_packed_depth, ivec2(px >> 2, py), 0)[px & 3] <= 0.0;
}

// Whether background lies `reach` pixels away in one of eight directions.
bool near_rim(int px, int py, float reach) {
    int d = int(ceil(reach));
    int e = int(ceil(0.7071 * reach));
    return background_at(px + d, py) || background_at(px - d, py) || background_at(px, py + d)
           || background_at(px, py - d) || background_at(px + e, py + e)
           || background_at(px - e, py + e) || background_at(px + e, py - e)
           || background_at(px - e, py - e);
}

// Three components of 8 bits each in one float (exact below 2^24).
float encode(vec3 n) {
    vec3 q = floor((clamp(n, -1.0, 1.0) * 0.5 + 0.5) * 255.0 + 0.5);
    return q.x * 65536.0 + q.y * 256.0 + q.z;
}

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 zc = fetch_packed(u_packed_depth, texel);
    if (all(lessThanEqual(zc, vec4(0.0)))) {
        out_packed_normals = vec4(0.0);
        return;
    }
    vec4 z_left = fetch_packed(u_packed_depth, texel - ivec2(1, 0));
    vec4 z_right = fetch_packed(u_packed_depth, texel + ivec2(1, 0));
    vec4 z_up = fetch_packed(u_packed_depth, texel + ivec2(0, 1));
    vec4 z_down = fetch_packed(u_packed_depth, texel - ivec2(0, 1));
    // each lane's neighbours along the row
    vec4 row_minus = vec4(z_left.w, zc.xyz);
    vec4 row_plus = vec4(zc.yzw, z_right.x);
    vec4 result = vec4(0.0);
    for (int i = 0; i < 4; ++i) {
        float z = zc[i];
        if (z <= 0.0) {
            continue;
        }
        float px = float(4 * texel.x + i);
        float py = float(texel.y);
        vec3 centre = view_position(px, py, z);
        vec3 ddx = axis_difference(view_position(px - 1.0, py, row_minus[i]), centre,
                                   view_position(px + 1.0, py, row_plus[i]), row_minus[i] > 0.0,
                                   row_plus[i] > 0.0);
        vec3 ddy = axis_difference(view_position(px, py - 1.0, z_down[i]), centre,
                                   view_position(px, py + 1.0, z_up[i]), z_down[i] > 0.0,
                                   z_up[i] > 0.0);
        vec3 n = cross(ddx, ddy);
        float len = length(n);
        n = len > 0.0 ? n / len : -normalize(centre);
        n = dot(n, centre) > 0.0 ? -n : n;  // facing the eye
        result[i] = encode(n);
        float rim_px = u_rim_radii * u_particle_radius * u_px_per_unit / z;
        if (u_rim_radii > 0.0 && near_rim(4 * texel.x + i, texel.y, rim_px)) {
            result[i] = -result[i];
        }
    }
    out_packed_normals = result;
}
