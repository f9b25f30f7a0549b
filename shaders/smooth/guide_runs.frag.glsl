#version 330 core
// The normal guide's crease runs (quality.normal_guide, passes/smooth.py), at the guide's
// reduced size, for the 1-D passes along AXIS: a one-sided limit (guide_limits.frag.glsl) is
// kept only where it belongs to a crease line, one that sets limits on the same side in at
// least u_run - 1 more neighbouring rows (AXIS 0) or columns (AXIS 1) in a row, each within
// u_shift pixels along AXIS of the last (the nearest taken). A box edge is a line; a fold's
// or a ripple's short cut is a spot, where a one-sided kernel would bend the surface (and
// flicker as the cut comes and goes).
// Packed in and out, limits coded as guide_limits.frag.glsl's.

#define AXIS 0

#include "common/packed_image.glsl"

uniform sampler2D u_guide_limits;  // guide_limits.frag.glsl's, this axis
uniform ivec2 u_image_size_px;
uniform int u_run;                 // the least crease length that keeps a limit, in pixels
uniform int u_shift;               // how far along AXIS a crease may step between two lines

layout(location = 0) out vec4 out_packed_limits;

const float NO_CODE = 4095.0;

// The limit codes (plus, minus) of pixel (px, py); no limit past the image's ends.
vec2 codes_at(int px, int py) {
    if (px < 0 || py < 0 || px >= u_image_size_px.x || py >= u_image_size_px.y) {
        return vec2(NO_CODE);
    }
    float code = texelFetch(u_guide_limits, ivec2(px >> 2, py), 0)[px & 3];
    float plus = floor(code / 4096.0);
    return vec2(plus, code - plus * 4096.0);
}

// Per side, the place along AXIS of the limit in line `line` across AXIS nearest `along`
// (.x: the plus side's, .y: the minus side's), within u_shift; `found` where there is one.
ivec2 nearest_limits(ivec2 along, int line, out bvec2 found) {
    ivec2 at = along;
    found = bvec2(false);
    for (int i = 0; i <= 2 * u_shift; ++i) {
        int d = (i + 1) / 2 * (i % 2 == 0 ? 1 : -1);  // 0, -1, 1, -2, 2, ...
        vec2 plus = AXIS == 0 ? codes_at(along.x + d, line) : codes_at(line, along.x + d);
        vec2 minus = AXIS == 0 ? codes_at(along.y + d, line) : codes_at(line, along.y + d);
        bvec2 has = bvec2(plus.x < NO_CODE, minus.y < NO_CODE);
        bvec2 first = bvec2(ivec2(has) & ~ivec2(found) & 1);
        at = ivec2(first.x ? along.x + d : at.x, first.y ? along.y + d : at.y);
        found = bvec2(ivec2(found) | ivec2(has));
    }
    return at;
}

// How many lines in a row from `start` on in direction `step` carry the crease (per side),
// following it from `along`, at most u_run - 1.
ivec2 run_from(int along, int start, int step) {
    ivec2 run = ivec2(0);
    ivec2 at = ivec2(along);
    bvec2 going = bvec2(true);
    for (int d = 0; d < u_run - 1; ++d) {
        bvec2 found;
        at = nearest_limits(at, start + step * d, found);
        going = bvec2(ivec2(going) & ivec2(found));
        run += ivec2(going);
        if (!any(going)) {
            break;
        }
    }
    return run;
}

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 codes = texelFetch(u_guide_limits, texel, 0);
    vec4 result = codes;
    for (int i = 0; i < 4; ++i) {
        float plus = floor(codes[i] / 4096.0);
        float minus = codes[i] - plus * 4096.0;
        if (plus >= NO_CODE && minus >= NO_CODE) {
            continue;
        }
        ivec2 pixel = ivec2(4 * texel.x + i, texel.y);
        int along = AXIS == 0 ? pixel.x : pixel.y;
        int line = AXIS == 0 ? pixel.y : pixel.x;
        ivec2 run = ivec2(1) + run_from(along, line + 1, 1) + run_from(along, line - 1, -1);
        plus = run.x >= u_run ? plus : NO_CODE;
        minus = run.y >= u_run ? minus : NO_CODE;
        result[i] = plus * 4096.0 + minus;
    }
    out_packed_limits = result;
}
