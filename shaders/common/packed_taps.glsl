// The taps of a separable 1-D kernel over packed images (common/packed_image.glsl), walked in
// order k = 1, 2, ... with the mirror pair (+k, -k) together, up to `radius`, for the four
// pixels of one texel at once. For each k it calls
//     tap_pair(k, guide at +k, guide at -k, value at +k, value at -k)
// (vec4s, component i = pixel 4x + i), which the including shader defines before including
// this file, along with AXIS (0: rows, 1: columns) and PACKED_VALUE (1: a separate value image
// is filtered under the guide's control; 0: the guide is the value, `value_image` is unused).
//   AXIS 1: each fetch serves all four pixels.
//   AXIS 0: pixel 4x + i + k lies in texel x + ((i + k) >> 2), component (i + k) & 3; with
//   k = 4s + j + 1 (j = 0..3) that is texel x + s or x + s + 1 (`ahead`, `ahead_next`), and
//   for -k texel x - s or x - s - 1 (`behind`, `behind_next`): two fetches per side serve four
//   offsets of four pixels.

// The four pixels at +k (k = 4s + j, j = 1..3) from the windows at texels +s and +s + 1,
// and the four at -k from the windows at -s and -s - 1.
vec4 ahead_by(int j, vec4 at_s, vec4 at_next) {
    return j == 1 ? vec4(at_s.yzw, at_next.x) : j == 2 ? vec4(at_s.zw, at_next.xy)
                                                       : vec4(at_s.w, at_next.xyz);
}

vec4 behind_by(int j, vec4 at_s, vec4 at_next) {
    return j == 1 ? vec4(at_next.w, at_s.xyz) : j == 2 ? vec4(at_next.zw, at_s.xy)
                                                       : vec4(at_next.yzw, at_s.x);
}

void walk_packed_taps(
    sampler2D guide_image, sampler2D value_image, ivec2 texel, vec4 guide, vec4 value, int radius
) {
#if AXIS == 0
    vec4 ahead = guide;
    vec4 ahead_next = fetch_packed(guide_image, texel + ivec2(1, 0));
    vec4 behind = guide;
    vec4 behind_next = fetch_packed(guide_image, texel - ivec2(1, 0));
    vec4 value_ahead = value;
    vec4 value_behind = value;
#if PACKED_VALUE
    vec4 value_ahead_next = fetch_packed(value_image, texel + ivec2(1, 0));
    vec4 value_behind_next = fetch_packed(value_image, texel - ivec2(1, 0));
#else
    vec4 value_ahead_next = ahead_next;
    vec4 value_behind_next = behind_next;
#endif
    for (int s = 0; 4 * s + 1 <= radius; ++s) {
        for (int j = 1; j <= 3; ++j) {  // constant bounds: unrolled, the selects fold away
            tap_pair(4 * s + j, ahead_by(j, ahead, ahead_next), behind_by(j, behind, behind_next),
                     ahead_by(j, value_ahead, value_ahead_next),
                     behind_by(j, value_behind, value_behind_next));
        }
        tap_pair(4 * s + 4, ahead_next, behind_next, value_ahead_next, value_behind_next);
        ahead = ahead_next;
        behind = behind_next;
        ahead_next = fetch_packed(guide_image, texel + ivec2(s + 2, 0));
        behind_next = fetch_packed(guide_image, texel - ivec2(s + 2, 0));
        value_ahead = value_ahead_next;
        value_behind = value_behind_next;
#if PACKED_VALUE
        value_ahead_next = fetch_packed(value_image, texel + ivec2(s + 2, 0));
        value_behind_next = fetch_packed(value_image, texel - ivec2(s + 2, 0));
#else
        value_ahead_next = ahead_next;
        value_behind_next = behind_next;
#endif
    }
#else
    for (int k = 1; k <= radius; ++k) {
        vec4 guide_up = fetch_packed(guide_image, texel + ivec2(0, k));
        vec4 guide_down = fetch_packed(guide_image, texel - ivec2(0, k));
#if PACKED_VALUE
        tap_pair(k, guide_up, guide_down, fetch_packed(value_image, texel + ivec2(0, k)),
                 fetch_packed(value_image, texel - ivec2(0, k)));
#else
        tap_pair(k, guide_up, guide_down, guide_up, guide_down);
#endif
    }
#endif
}

#if !PACKED_VALUE
// The taps at offsets first, first + stride, ... up to `radius` (1 <= stride <= 4; the spread
// taps of close-ups past the cap, smooth_depth_separable.frag.glsl), the guide its own value,
// walked outwards like the above.
//   AXIS 0: offset k = 4s + j reads the windows at texels +-s and +-(s + 1) as above; a stride
//   of at most 4 moves them by one texel at most per tap, so a texel is still fetched once.
void walk_strided_taps(sampler2D image, ivec2 texel, int first, int radius, int stride) {
#if AXIS == 0
    int window = first >> 2;  // s of the windows held
    vec4 ahead = fetch_packed(image, texel + ivec2(window, 0));
    vec4 ahead_next = fetch_packed(image, texel + ivec2(window + 1, 0));
    vec4 behind = fetch_packed(image, texel - ivec2(window, 0));
    vec4 behind_next = fetch_packed(image, texel - ivec2(window + 1, 0));
    for (int k = first; k <= radius; k += stride) {
        int s = k >> 2;
        if (s != window) {
            window = s;
            ahead = ahead_next;
            behind = behind_next;
            ahead_next = fetch_packed(image, texel + ivec2(s + 1, 0));
            behind_next = fetch_packed(image, texel - ivec2(s + 1, 0));
        }
        int j = k & 3;
        vec4 za = j == 0 ? ahead : ahead_by(j, ahead, ahead_next);
        vec4 zb = j == 0 ? behind : behind_by(j, behind, behind_next);
        tap_pair(k, za, zb, za, zb);
    }
#else
    for (int k = first; k <= radius; k += stride) {
        vec4 za = fetch_packed(image, texel + ivec2(0, k));
        vec4 zb = fetch_packed(image, texel - ivec2(0, k));
        tap_pair(k, za, zb, za, zb);
    }
#endif
}
#endif
