// Shadows of the shade pass (shade/shade_pbr.frag.glsl, maps from passes/shadow.py): PCSS over
// an atlas of shadow maps, R32F, one slot per shadowed light. Cube maps (point and sphere
// lights) hold the distance from the light, six faces in a 3 x 2 block; an orthographic map
// (directional) holds the depth behind its near plane.
//   blocker search  taps over a disc around the receiver's ray; a tap's receiver depth is that of
//                   the receiver's tangent plane along the tap (receiver-plane bias), so a
//                   tilted surface does not shadow itself
//   penumbra        w = R (d_r - d_b) / d_b at the receiver for a sphere light of radius R, d_b
//                   the farthest blocker found (the edge that casts the penumbra: an average
//                   takes in a convex occluder's near face and widens it)
//                   (similar triangles); the PCF disc has radius w, so a straight edge's
//                   profile is the disc's circular-segment area, as a real disc light gives
//   acne            depth bias = (SHADOW_SURFACE_DEPTH particle radii + a texel across the
//                   tilt) / cos(theta): the smoothed surface lies behind the spheres' fronts
// Needs MAX_LIGHTS, u_light_vector (shade_pbr.frag.glsl).

#define SHADOW_NONE 0
#define SHADOW_CUBE 1
#define SHADOW_ORTHO 2
#define SHADOW_SEARCH_TAPS 16
#define SHADOW_FILTER_TAPS 32
#define SHADOW_HARD_TAPS 8
#define SHADOW_MIN_TEXELS 1.5  // the narrowest filter: hard shadows' edges, in texels
// How far (in particle radii, along the normal) the smoothed surface may lie behind the fronts of
// the spheres the map holds: up to ~2.2 r for lattices of touching spheres, 99th percentile of
// the lit pixels of a lattice ball (tests/test_shadows.py).
#define SHADOW_SURFACE_DEPTH 2.5

uniform sampler2D u_shadow_atlas;
uniform vec4 u_shadow_slot[MAX_LIGHTS];   // kind, first row, side in texels, depth bias
uniform vec4 u_shadow_light[MAX_LIGHTS];  // ortho: near-plane centre (eye-relative); w: radius
                                          // (cube) or tan(angular radius) (ortho)
uniform mat3 u_shadow_axes[MAX_LIGHTS];   // ortho: world -> map axes (z along the travel)
uniform vec2 u_shadow_half[MAX_LIGHTS];   // ortho: half extents, scene units

// Cube faces in the order passes/shadow.py draws them: view direction, right, up.
const vec3 FACE_DIR[6] = vec3[6](
    vec3(1, 0, 0), vec3(-1, 0, 0), vec3(0, 1, 0), vec3(0, -1, 0), vec3(0, 0, 1), vec3(0, 0, -1));
const vec3 FACE_RIGHT[6] = vec3[6](
    vec3(0, 0, 1), vec3(0, 0, -1), vec3(-1, 0, 0), vec3(-1, 0, 0), vec3(-1, 0, 0), vec3(1, 0, 0));
const vec3 FACE_UP[6] = vec3[6](
    vec3(0, 1, 0), vec3(0, 1, 0), vec3(0, 0, -1), vec3(0, 0, 1), vec3(0, 1, 0), vec3(0, 1, 0));

// The stored blocker distance along direction `d` from the light (any length).
float cube_stored(vec4 slot, vec3 d) {
    vec3 a = abs(d);
    int f = a.x >= a.y && a.x >= a.z ? (d.x > 0.0 ? 0 : 1) : (a.y >= a.z ? (d.y > 0.0 ? 2 : 3)
                                                                         : (d.z > 0.0 ? 4 : 5));
    float depth = dot(d, FACE_DIR[f]);
    vec2 uv = vec2(dot(d, FACE_RIGHT[f]), dot(d, FACE_UP[f])) / depth;
    int side = int(slot.z);
    ivec2 texel = clamp(ivec2((uv * 0.5 + 0.5) * slot.z), ivec2(0), ivec2(side - 1));
    return texelFetch(u_shadow_atlas, texel + ivec2((f % 3) * side, int(slot.y) + (f / 3) * side), 0).r;
}

float ortho_stored(vec4 slot, vec2 xy, vec2 half_extent) {
    int side = int(slot.z);
    ivec2 texel = clamp(ivec2((xy / half_extent * 0.5 + 0.5) * slot.z), ivec2(0), ivec2(side - 1));
    return texelFetch(u_shadow_atlas, texel + ivec2(0, int(slot.y)), 0).r;
}

vec2 vogel_disc(int k, int count, float turn) {
    float r = sqrt((float(k) + 0.5) / float(count));
    float a = float(k) * 2.39996323 + turn;
    return r * vec2(cos(a), sin(a));
}

// Light-space frame of one shadow lookup: cube, rays fan out from the light; ortho, they are
// parallel to z. `receiver` in light space (cube: relative to the light; ortho: map axes).
struct ShadowFrame {
    int kind;
    vec4 slot;
    vec3 receiver;
    vec3 normal;  // receiver's normal, light space
    vec3 t;       // across the receiver's ray
    vec3 b;
    float depth;  // receiver: distance from the light (cube) or behind the near plane (ortho)
    vec2 half_extent;
};

// Receiver depth and stored blocker depth of the tap `offset` (scene units across the ray, at
// the receiver's depth); the receiver depth is that of its tangent plane along the tap.
vec2 shadow_tap(ShadowFrame s, vec2 offset) {
    vec3 q = s.receiver + s.t * offset.x + s.b * offset.y;
    if (s.kind == SHADOW_CUBE) {
        vec3 ray = normalize(q);
        float nr = dot(s.normal, ray);
        float plane = abs(nr) > 1e-3 ? dot(s.normal, s.receiver) / nr : s.depth;
        return vec2(clamp(plane, 0.5 * s.depth, 2.0 * s.depth), cube_stored(s.slot, ray));
    }
    float nz = s.normal.z;
    float plane = abs(nz) > 1e-3 ? s.depth - dot(s.normal.xy, offset) / nz : s.depth;
    return vec2(clamp(plane, s.depth - 4.0 * length(offset), s.depth + 4.0 * length(offset)),
                ortho_stored(s.slot, q.xy, s.half_extent));
}

// Fraction of `taps` taps over a disc of radius `width` around the receiver's ray that see the light.
float shadow_pcf(ShadowFrame s, float width, int taps, float bias, float turn) {
    float lit = 0.0;
    for (int k = 0; k < taps; ++k) {
        vec2 tap = shadow_tap(s, vogel_disc(k, taps, turn) * width);
        lit += tap.y < tap.x - bias ? 0.0 : 1.0;
    }
    return lit / float(taps);
}

// Fraction of light `i` that reaches `position` (eye-relative, world axes) with normal `n`. The
// tap discs turn per pixel (interleaved gradient noise, Jimenez 2014): banding becomes fine noise.
float shadow_visibility(int i, vec3 position, vec3 n) {
    float turn = 6.2831853 * fract(52.9829189 * fract(dot(gl_FragCoord.xy, vec2(0.06711056, 0.00583715))));
    vec4 slot = u_shadow_slot[i];
    ShadowFrame s;
    s.kind = int(slot.x);
    if (s.kind == SHADOW_NONE) {
        return 1.0;
    }
    s.slot = slot;
    float radius = u_shadow_light[i].w;
    float texel;
    vec3 along;
    if (s.kind == SHADOW_CUBE) {
        s.receiver = position - u_light_vector[i];
        s.normal = n;
        s.depth = length(s.receiver);
        along = s.receiver / max(s.depth, 1e-30);
        texel = 2.0 * s.depth / slot.z;
    } else {
        s.receiver = u_shadow_axes[i] * (position - u_shadow_light[i].xyz);
        s.normal = u_shadow_axes[i] * n;
        s.depth = s.receiver.z;
        s.half_extent = u_shadow_half[i];
        along = vec3(0.0, 0.0, 1.0);
        texel = 2.0 * max(s.half_extent.x, s.half_extent.y) / slot.z;
    }
    vec3 helper = abs(along.y) < 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
    s.t = normalize(cross(helper, along));
    s.b = cross(along, s.t);
    float cos_t = clamp(abs(dot(s.normal, along)), 0.1, 1.0);
    float bias = (SHADOW_SURFACE_DEPTH * slot.w + texel * sqrt(1.0 - cos_t * cos_t)) / cos_t;

    // Blockers nearer the light than a fifth of the receiver's distance would need a wider search
    // than this; their penumbrae are cut at this width.
    float nearest = max(0.2 * s.depth, radius);
    // Ortho: `radius` is tan(angular radius); a blocker anywhere in front of the receiver counts.
    float search = s.kind == SHADOW_CUBE ? radius * (s.depth - nearest) / nearest
                                         : radius * s.depth;
    search = clamp(search, SHADOW_MIN_TEXELS * texel, 0.5 * s.depth);
    if (search <= SHADOW_MIN_TEXELS * texel) {
        // No penumbra wider than the filter: a hard shadow, its edge filtered over a few texels.
        return shadow_pcf(s, search, SHADOW_HARD_TAPS, bias, turn);
    }
    float blockers = 0.0;
    float blocker_depth = 0.0;
    for (int k = 0; k < SHADOW_SEARCH_TAPS; ++k) {
        vec2 tap = shadow_tap(s, vogel_disc(k, SHADOW_SEARCH_TAPS, turn) * search);
        if (tap.y < tap.x - bias) {
            blockers += 1.0;
            blocker_depth = max(blocker_depth, tap.y);
        }
    }
    if (blockers == 0.0) {
        return 1.0;
    }
    float width = s.kind == SHADOW_CUBE
        ? radius * max(s.depth - blocker_depth, 0.0) / max(blocker_depth, 1e-30)
        : radius * max(s.depth - blocker_depth, 0.0);
    width = clamp(width, SHADOW_MIN_TEXELS * texel, 0.5 * s.depth);
    return shadow_pcf(s, width, SHADOW_FILTER_TAPS, bias, turn);
}
