// Procedural brushed detail fixed in world space: a height field of three octaves of 3-D value
// noise in pattern coordinates q = B p + o, where B's rows are e1 / s, e2 / s and
// brush / (40 s) (e1, e2 across the brush, s the finest groove width) and o is the eye in those
// coordinates modulo the pattern's period, taken on the host in float64. Grooves so run along
// the brush about 40 widths long; the pattern repeats every 256 cells, so p far from the origin
// loses nothing to fp32. Height in world units is s H(q); its gradient tilts the normal.

uniform mat3 u_detail_basis;        // world (eye-relative) -> pattern coordinates
uniform vec3 u_detail_offset;       // the eye in pattern coordinates, modulo DETAIL_PERIOD
uniform float u_detail_scale;       // s, scene units
uniform float u_detail_normal_strength;
uniform float u_detail_roughness_strength;

const float DETAIL_PERIOD = 256.0;
const vec3 DETAIL_WEIGHTS = vec3(0.5, 0.3, 0.2);  // octave widths s, 2 s, 4 s

float detail_hash(vec3 cell) {
    uvec3 c = uvec3(mod(cell, DETAIL_PERIOD));
    uint h = c.x + 256u * (c.y + 256u * c.z);
    // lowbias32 (C. Wellons): a full-avalanche 32-bit integer hash.
    h ^= h >> 16;
    h *= 0x7feb352du;
    h ^= h >> 15;
    h *= 0x846ca68bu;
    h ^= h >> 16;
    return float(h) * 2.3283064365386963e-10;
}

// Value noise in [0, 1] with its gradient (xyz) and value (w); quintic fade, so the gradient
// is continuous across cells.
vec4 detail_noise(vec3 x) {
    vec3 i = floor(x);
    vec3 f = x - i;
    vec3 u = f * f * f * (f * (f * 6.0 - 15.0) + 10.0);
    vec3 du = 30.0 * f * f * (f * (f - 2.0) + 1.0);
    float a = detail_hash(i);
    float b = detail_hash(i + vec3(1.0, 0.0, 0.0));
    float c = detail_hash(i + vec3(0.0, 1.0, 0.0));
    float d = detail_hash(i + vec3(1.0, 1.0, 0.0));
    float e = detail_hash(i + vec3(0.0, 0.0, 1.0));
    float g = detail_hash(i + vec3(1.0, 0.0, 1.0));
    float k = detail_hash(i + vec3(0.0, 1.0, 1.0));
    float m = detail_hash(i + vec3(1.0, 1.0, 1.0));
    float k1 = b - a;
    float k2 = c - a;
    float k3 = e - a;
    float k4 = a - b - c + d;
    float k5 = a - c - e + k;
    float k6 = a - b - e + g;
    float k7 = -a + b + c - d + e - g - k + m;
    float value = a + k1 * u.x + k2 * u.y + k3 * u.z + k4 * u.x * u.y + k5 * u.y * u.z
        + k6 * u.z * u.x + k7 * u.x * u.y * u.z;
    vec3 gradient = du * vec3(
        k1 + k4 * u.y + k6 * u.z + k7 * u.y * u.z,
        k2 + k5 * u.z + k4 * u.x + k7 * u.z * u.x,
        k3 + k6 * u.x + k5 * u.y + k7 * u.x * u.y
    );
    return vec4(gradient, value);
}

// H and its gradient in pattern coordinates at eye-relative world position `position`.
vec4 detail_height(vec3 position) {
    vec3 q = u_detail_basis * position + u_detail_offset;
    vec4 sum = vec4(0.0);
    float width = 1.0;
    for (int octave = 0; octave < 3; ++octave) {
        vec4 noise = detail_noise(q / width);
        // Height scales with the octave's width, so each octave's slope is its weight alone.
        sum += DETAIL_WEIGHTS[octave] * vec4(noise.xyz, noise.w * width);
        width *= 2.0;
    }
    return sum;
}

// Unit normal `n` tilted by the grooves' slope at `position`.
vec3 detail_normal(vec3 n, vec3 position) {
    vec3 gradient_q = detail_height(position).xyz;
    // d(s H)/dp = s B^T dH/dq; B^T g is g * B for a row vector.
    vec3 slope = u_detail_normal_strength * u_detail_scale * (gradient_q * u_detail_basis);
    vec3 tilted = n - (slope - n * dot(n, slope));
    return normalize(tilted);
}

// Roughness raised in the troughs and lowered on the crests of the grooves.
float detail_roughness(float roughness, vec3 position) {
    float h = detail_height(position).w / dot(DETAIL_WEIGHTS, vec3(1.0, 2.0, 4.0));
    return clamp(roughness + u_detail_roughness_strength * (1.0 - 2.0 * h), 0.0, 1.0);
}
