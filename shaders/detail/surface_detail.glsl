// Procedural brushed detail fixed in world space, projected triplanar: on each axis plane the
// grooves are 2-D value noise (three octaves, widths s, 2 s, 4 s) in coordinates across and
// along the brush direction projected into that plane, stretched 40 x along it; the three are
// blended by |n_axis|^4. A face so reads the plane it faces, and its pattern does not move with
// the surface's depth along the normal. The eye's pattern coordinates (modulo the pattern's
// period) are taken on the host in float64, so a workpiece at 1e5 scene units keeps its grooves.
// DETAIL_PATTERN: these grooves; DETAIL_IMAGE: an image's height and roughness added (the same
// triplanar frame, detail/detail_image.glsl).

#define DETAIL_PATTERN 1
#define DETAIL_IMAGE 0

// Per axis plane k (coordinates p[k+1], p[k+2]): the unit brush direction in the plane (xy)
// and the eye's (across, along) pattern coordinates (zw).
uniform vec4 u_detail_plane[3];  // offsets modulo DETAIL_PERIOD x the widest octave (4)
uniform float u_detail_scale;       // s, scene units
uniform float u_detail_normal_strength;
uniform float u_detail_roughness_strength;
uniform float u_detail_pixel_angle;  // 2 tan(fov_y / 2) / height: a pixel's width per unit distance

#include "detail/detail_image.glsl"

const float DETAIL_PERIOD = 256.0;
const float DETAIL_GROOVE_LENGTH = 40.0;
const vec3 DETAIL_WEIGHTS = vec3(0.5, 0.3, 0.2);  // octave widths s, 2 s, 4 s

float detail_hash(vec2 cell, int plane) {
    uvec2 c = uvec2(mod(cell, DETAIL_PERIOD));
    uint h = c.x + 256u * (c.y + 256u * uint(plane));
    // lowbias32 (C. Wellons): a full-avalanche 32-bit integer hash.
    h ^= h >> 16;
    h *= 0x7feb352du;
    h ^= h >> 15;
    h *= 0x846ca68bu;
    h ^= h >> 16;
    return float(h) * 2.3283064365386963e-10;
}

// Value noise in [0, 1]: gradient (xy) and value (z); quintic fade, so the gradient is
// continuous across cells.
vec3 detail_noise(vec2 x, int plane) {
    vec2 i = floor(x);
    vec2 f = x - i;
    vec2 u = f * f * f * (f * (f * 6.0 - 15.0) + 10.0);
    vec2 du = 30.0 * f * f * (f * (f - 2.0) + 1.0);
    float a = detail_hash(i, plane);
    float b = detail_hash(i + vec2(1.0, 0.0), plane);
    float c = detail_hash(i + vec2(0.0, 1.0), plane);
    float d = detail_hash(i + vec2(1.0, 1.0), plane);
    float k1 = b - a;
    float k2 = c - a;
    float k4 = a - b - c + d;
    float value = a + k1 * u.x + k2 * u.y + k4 * u.x * u.y;
    return vec3(du * vec2(k1 + k4 * u.y, k2 + k4 * u.x), value);
}

// A pixel's footprint on the surface in units of s (widened where the surface is seen edge-on).
float detail_footprint(vec3 n, vec3 position) {
    float distance = length(position);
    float nv = max(abs(dot(n, position)) / max(distance, 1e-30), 0.25);
    return distance * u_detail_pixel_angle / (nv * u_detail_scale);
}

// Height H (z, in units of s) and its gradient per unit of plane coordinate / s (xy, along the
// plane's two world axes) on axis plane `k`, at eye-relative world position `position`. An
// octave fades out as its cells shrink from 2 to 1 pixel (`footprint`), so grooves finer than
// the pixels do not alias into moire.
vec3 detail_plane_height(int k, vec3 position, float footprint) {
    vec4 plane = u_detail_plane[k];
    vec2 p = vec2(position[(k + 1) % 3], position[(k + 2) % 3]) / u_detail_scale;
    vec2 across_axis = vec2(-plane.y, plane.x);
    // q = (across, along / 40): the grooves' coordinates; dq/dp is the rows below.
    vec2 q = vec2(dot(p, across_axis), dot(p, plane.xy) / DETAIL_GROOVE_LENGTH) + plane.zw;
    vec3 sum = vec3(0.0);
    float width = 1.0;
    for (int octave = 0; octave < 3; ++octave) {
        vec3 noise = detail_noise(q / width, k);
        // Height scales with the octave's width, so each octave's slope is its weight alone.
        float fade = clamp(width / footprint - 1.0, 0.0, 1.0);
        sum += fade * DETAIL_WEIGHTS[octave] * vec3(noise.xy, noise.z * width);
        width *= 2.0;
    }
    vec2 gradient = sum.x * across_axis + sum.y * plane.xy / DETAIL_GROOVE_LENGTH;
    return vec3(gradient, sum.z);
}

vec3 detail_plane_weights(vec3 n) {
    vec3 w = n * n;
    w *= w;
    return w / (w.x + w.y + w.z);
}

// Unit normal `n` tilted by the grooves' and the image's slope at `position`.
vec3 detail_normal(vec3 n, vec3 position) {
    vec3 weights = detail_plane_weights(n);
    vec3 slope = vec3(0.0);
#if DETAIL_PATTERN
    float footprint = detail_footprint(n, position);
    for (int k = 0; k < 3; ++k) {
        vec2 g = detail_plane_height(k, position, footprint).xy * weights[k];
        slope[(k + 1) % 3] += g.x;
        slope[(k + 2) % 3] += g.y;
    }
    slope *= u_detail_normal_strength;  // d(s H)/dp = dH/d(p / s)
#endif
#if DETAIL_IMAGE
    slope += clamp(detail_image_slope(weights, n, position), -1e4, 1e4);  // <= 89.99 deg
#endif
    return normalize(n - (slope - n * dot(n, slope)));
}

// Roughness raised in the troughs and lowered on the crests of the grooves; then the image's.
float detail_roughness(float roughness, vec3 n, vec3 position) {
    vec3 weights = detail_plane_weights(n);
#if DETAIL_PATTERN
    float footprint = detail_footprint(n, position);
    float h = 0.0;
    for (int k = 0; k < 3; ++k) {
        h += weights[k] * detail_plane_height(k, position, footprint).z;
    }
    h /= dot(DETAIL_WEIGHTS, vec3(1.0, 2.0, 4.0));
    roughness = clamp(roughness + u_detail_roughness_strength * (1.0 - 2.0 * h), 0.0, 1.0);
#endif
#if DETAIL_IMAGE
    roughness = detail_image_roughness(roughness, weights, n, position);
#endif
    return roughness;
}
