#version 330 core
// The normal guide's one-sided limits (quality.normal_guide, passes/smooth.py), at the guide's
// reduced size: per pixel, for the 1-D passes along AXIS, how far its kernel may reach along
// +AXIS and along -AXIS before the guide cuts. The guide's rule (cut_at) is evaluated on the
// pilot (its normals and its depth) for every tap out to the farthest reach of any pass; the
// limit is where the cut c, linear between taps (0 at the centre), first reaches u_limit_cut,
// so it moves continuously as the pilot does, and a pass weighs the tap at offset k by
// clamp(limit - k + 1/2, 0, 1) (smooth_depth_separable.frag.glsl guide_limit_weight). No cut:
// the largest code (no limit); a rim pixel cuts nothing. Out, packed like the depth (texel
// (x, y): pixels 4x .. 4x+3 of row y in .xyzw): round(8 limit_plus) * 4096 +
// round(8 limit_minus), each at most 4095.

#define AXIS 0

#include "common/packed_image.glsl"

uniform sampler2D u_guide_normals;  // encoded and flagged (guide_flat.frag.glsl)
uniform sampler2D u_packed_depth;   // the pilot's depth
uniform ivec2 u_image_size_px;
uniform float u_px_per_unit;
uniform float u_particle_radius;
// The cut's ramp over the squared turn less the squared turn tolerated: t = x * scale + offset
// (0 at quality.normal_guide, 1 at the upper limit); the tolerated turn's square per squared
// scene unit of distance to the tap; the convex ramp over the chord's sine behind the centre's
// pilot tangent plane over the turn (passes/smooth.py _set_guide_uniforms).
uniform vec2 u_guide_ramp;
uniform float u_guide_turn2;
uniform vec2 u_guide_convex;
uniform float u_reach_radii;   // the farthest reach of any pass, in projected radii
uniform int u_reach_max_px;    // ... and at most this many pixels
uniform float u_limit_cut;     // the cut that sets a limit (1/2)

layout(location = 0) out vec4 out_packed_limits;

const float NO_LIMIT = 4095.0 / 8.0;

vec4 g_center;     // the pilot's depth at the lanes
vec4 g_normal_x;   // the lanes' pilot normals, unit
vec4 g_normal_y;
vec4 g_normal_z;
vec4 g_ray_x;      // the lanes' view position over their depth
float g_ray_y;
vec4 g_normal_ray;
vec4 g_normal_axis;

// guide_flat.frag.glsl's normal (7 bits a component under two flag bits), unit.
void decode(vec4 v, out vec4 nx, out vec4 ny, out vec4 nz) {
    v = abs(v);  // negative: a rim pixel
    v -= floor(v / 2097152.0) * 2097152.0;
    vec4 a = floor(v / 16384.0);
    vec4 rest = v - a * 16384.0;
    vec4 b = floor(rest / 128.0);
    nx = a / 63.5 - 1.0;
    ny = b / 63.5 - 1.0;
    nz = (rest - b * 128.0) / 63.5 - 1.0;
    vec4 inverse_norm = inversesqrt(max(nx * nx + ny * ny + nz * nz, vec4(1e-6)));
    nx *= inverse_norm;
    ny *= inverse_norm;
    nz *= inverse_norm;
}

// The guide's cut (0..1) of taps at signed offsets k (per lane) whose encoded pilot normals
// are `encoded` and pilot depths z: 1 - smoothstep over the turn between the pilot normals at
// the centre and the tap (its square taken as 2 (1 - cos)), less a sphere's turn over the
// distance in space to the tap (a box edge is cut, a slow turn passes); only where the tap
// lies behind the centre's pilot tangent plane (a convex turn) and the pilot is flat past it
// (and behind the centre: main() gives a side no reach where it is not).
vec4 cut_at(vec4 encoded, vec4 z, vec4 k) {
    vec4 nx;
    vec4 ny;
    vec4 nz;
    decode(encoded, nx, ny, nz);
    vec4 turn2 = 2.0 - 2.0 * (nx * g_normal_x + ny * g_normal_y + nz * g_normal_z);
    vec4 shift = k / u_px_per_unit;
    vec4 dz = z - g_center;
    vec4 dx = g_ray_x * dz + (AXIS == 0 ? shift : vec4(0.0)) * z;
    vec4 dy = g_ray_y * dz + (AXIS == 1 ? shift : vec4(0.0)) * z;
    vec4 distance2 = dx * dx + dy * dy + dz * dz;
    vec4 t = clamp((turn2 - u_guide_turn2 * distance2) * u_guide_ramp.x + u_guide_ramp.y,
                   0.0, 1.0);
    vec4 cut = t * t * (3.0 - 2.0 * t);
    vec4 behind = -(dz * g_normal_ray + (shift * z) * g_normal_axis)
                  * inversesqrt(max(distance2, vec4(1e-30)));
    // the chord's sine behind the tangent plane over the turn (about 1/2 on a rounded edge)
    behind *= inversesqrt(max(turn2, vec4(1e-6)));
    vec4 c = clamp(behind * u_guide_convex.x + u_guide_convex.y, 0.0, 1.0);
    cut *= c * c * (3.0 - 2.0 * c);
    vec4 flags = floor(abs(encoded) / 2097152.0);  // +AXIS: bit 0, -AXIS: bit 1
    vec4 minus = floor(flags / 2.0);
    cut *= mix(minus, flags - 2.0 * minus, greaterThan(k, vec4(0.0)));
    // background taps are never taken
    return mix(vec4(0.0), cut, greaterThan(z, vec4(0.0)));
}

// A side's walk out from the centre, tap by tap in order of distance: the limit is where the
// cut, linear between taps (0 at the centre), first reaches u_limit_cut, so it moves
// continuously as the cuts change.
struct Walk {
    vec4 limit;      // NO_LIMIT until the cut is reached
    vec4 last_cut;   // the cut of the tap one nearer (0: the centre)
};

Walk walk_start() {
    return Walk(vec4(NO_LIMIT), vec4(0.0));
}

// The walk on past the taps at distances `distance` (per lane; taken only at distances
// 1 .. reach, each one past the last) of cut `cut`.
void walk_on(inout Walk w, vec4 cut, vec4 distance, vec4 reach) {
    bvec4 taken = both(greaterThanEqual(distance, vec4(1.0)), lessThanEqual(distance, reach));
    bvec4 found = lessThan(w.limit, vec4(NO_LIMIT));
    taken = both(taken, not(found));
    bvec4 crossed = both(taken, greaterThanEqual(cut, vec4(u_limit_cut)));
    vec4 f = (u_limit_cut - w.last_cut) / max(cut - w.last_cut, vec4(1e-6));
    w.limit = mix(w.limit, distance - 1.0 + clamp(f, 0.0, 1.0), crossed);
    w.last_cut = mix(w.last_cut, cut, taken);
}

// Whether every lane's walk has its limit or has gone past its reach at distance `next`.
bool walk_done(Walk w, vec4 next, vec4 reach) {
    return all(either(lessThan(w.limit, vec4(NO_LIMIT)), greaterThan(next, reach)));
}

// AXIS 1: the limit along the column on side `side` (+-1).
vec4 column_limit(ivec2 texel, int side, int radius, vec4 reach) {
    Walk w = walk_start();
    int room = side > 0 ? u_image_size_px.y - 1 - texel.y : texel.y;  // rows to the end
    for (int k = 1; k <= radius && k <= room; ++k) {
        ivec2 at = texel + ivec2(0, side * k);
        walk_on(w, cut_at(texelFetch(u_guide_normals, at, 0), texelFetch(u_packed_depth, at, 0),
                          vec4(float(side * k))), vec4(float(k)), reach);
        if (walk_done(w, vec4(float(k + 1)), reach)) {
            break;
        }
    }
    return w.limit;
}

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 encoded = fetch_packed(u_guide_normals, texel);
    g_center = fetch_packed(u_packed_depth, texel);
    bvec4 surface = greaterThan(g_center, vec4(0.0));
    bvec4 cuts = both(surface, greaterThan(encoded, vec4(0.0)));  // a rim pixel cuts nothing
    if (!any(cuts)) {
        out_packed_limits = vec4(4095.0 * 4096.0 + 4095.0);
        return;
    }
    decode(encoded, g_normal_x, g_normal_y, g_normal_z);
    vec2 centre = 0.5 * vec2(u_image_size_px);
    vec4 px = vec4(float(4 * texel.x)) + vec4(0.0, 1.0, 2.0, 3.0);
    g_ray_x = (px + 0.5 - centre.x) / u_px_per_unit;
    g_ray_y = (float(texel.y) + 0.5 - centre.y) / u_px_per_unit;
    g_normal_ray = g_normal_x * g_ray_x + g_normal_y * g_ray_y + g_normal_z;
    g_normal_axis = AXIS == 0 ? g_normal_x : g_normal_y;
    vec4 z = mix(vec4(1.0), g_center, surface);
    vec4 reach = min(ceil(u_reach_radii * u_particle_radius * u_px_per_unit / z),
                     vec4(float(u_reach_max_px)));
    reach = mix(vec4(0.0), reach, cuts);
    int radius = int(max(max(reach.x, reach.y), max(reach.z, reach.w)));
    // a side is cut only where the pilot is flat behind the centre too (away from that side):
    // an edge between two faces, not a rough surface meeting a smooth one
    vec4 flags = floor(abs(encoded) / 2097152.0);
    vec4 flat_minus = floor(flags / 2.0);
    vec4 reach_plus = reach * flat_minus;
    vec4 reach_minus = reach * (flags - 2.0 * flat_minus);
    vec4 lane = vec4(0.0, 1.0, 2.0, 3.0);
#if AXIS == 0
    int texels = (u_image_size_px.x + 3) / 4;
    int steps = (radius + 3) / 4 + 1;
    // along the row, a texel at a time: its four pixels at distance 4 s + j - lane
    Walk ahead = walk_start();
    for (int s = 0; s <= steps && texel.x + s < texels; ++s) {
        vec4 codes = texelFetch(u_guide_normals, texel + ivec2(s, 0), 0);
        vec4 depths = texelFetch(u_packed_depth, texel + ivec2(s, 0), 0);
        for (int j = 0; j < 4; ++j) {
            vec4 k = vec4(float(4 * s + j)) - lane;
            walk_on(ahead, cut_at(vec4(codes[j]), vec4(depths[j]), k), k, reach_plus);
        }
        if (walk_done(ahead, vec4(float(4 * s + 4)) - lane, reach_plus)) {
            break;
        }
    }
    Walk behind = walk_start();
    for (int s = 0; s <= steps && texel.x - s >= 0; ++s) {
        vec4 codes = texelFetch(u_guide_normals, texel - ivec2(s, 0), 0);
        vec4 depths = texelFetch(u_packed_depth, texel - ivec2(s, 0), 0);
        for (int j = 3; j >= 0; --j) {
            vec4 k = vec4(float(4 * s - j)) + lane;  // the distance behind
            walk_on(behind, cut_at(vec4(codes[j]), vec4(depths[j]), -k), k, reach_minus);
        }
        if (walk_done(behind, vec4(float(4 * s + 1)) + lane, reach_minus)) {
            break;
        }
    }
    vec4 plus = ahead.limit;
    vec4 minus = behind.limit;
#else
    vec4 plus = column_limit(texel, 1, radius, reach_plus);
    vec4 minus = column_limit(texel, -1, radius, reach_minus);
#endif
    vec4 code_plus = min(floor(plus * 8.0 + 0.5), vec4(4095.0));
    vec4 code_minus = min(floor(minus * 8.0 + 0.5), vec4(4095.0));
    out_packed_limits = code_plus * 4096.0 + code_minus;
}
