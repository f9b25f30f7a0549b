#version 330 core
// Gap closing in the splatted eye depth, before the smoothing (passes/gaps.py; numpy reference
// in tests/test_gaps.py). A sparse sheet of particles splats as beads with background or the
// surface behind showing between them; the fluid surface spans those gaps. Per pixel (depth
// zc, 0 = background) and per direction d of the four (1,0), (0,1), (1,1), (1,-1):
// * walk both ways to the first pixel of a NEARER surface (depth > 0 and, where zc > 0,
//   nearer than zc - u_edge_jump; a pixel of the same or a farther surface is passed over), at
//   most GAP_MAX_PX steps; it counts when the walk arrives there by a jump (the pixel before
//   it is background or farther by more than u_edge_jump), not up a slope of one surface (then
//   that side has none); depths za, zb at k_a, k_b steps;
// * the direction encloses the pixel when the span (k_a + k_b) |d| is at most the gap limit,
//   u_gap_radii particle radii projected at the nearer of za, zb (u_gap_radii * r * f /
//   min(za, zb) pixels), and the two sides are one surface: |za - zb| <= u_gap_radii * r.
// A background pixel enclosed in at least 2 directions (a hole, a slit), or a pixel of a
// farther surface enclosed in at least 1, takes the depth interpolated linearly along the
// enclosing direction of the shortest span (za + (zb - za) k_a / (k_a + k_b)); every other pixel
// keeps its depth. HAS_TEMPERATURE: the splatted kelvin image is filled the same way (the
// kelvin of the two pixels reached, interpolated alike; elsewhere copied), so a closed gap is
// not a cold spot in the temperature blur. So a depth only ever gets nearer (no hole opens
// where the spheres cover), a notch between two beads at a silhouette (enclosed along the edge
// only) stays open, and two particles whose silhouettes are farther apart than u_gap_radii
// radii stay apart.
// Bounded search (the same result): the 4-pixel tiles of gap_tiles.frag.glsl dilated by
// gap_dilate.frag.glsl hold, for the pixel's tile, the nearest depth z_near and the nearest jump
// front (a pixel a walk can stop on: reached from a neighbour by a jump) within +-16 >=
// GAP_MAX_PX pixels: without a jump front nearer than zc - u_edge_jump there (the inside of a
// surface, the slope inside a silhouette, open background), nothing to do; else no span can
// exceed u_gap_radii * r * f / z_near pixels, the reach, and the walks stop there. A walk can
// only stop on a jump front nearer than zc - u_edge_jump (its predecessor on the walk is a
// neighbour that is background or farther by more), so a direction can enclose the pixel only
// when the tile has such a front on both sides along it (u_axes: along the tile's row and
// column; u_diagonals: in its quadrants); the other directions are not walked, and a pixel
// with too few such directions left stops (most of the background beside a silhouette and
// most of a bumpy surface next to one).

#define GAP_MAX_PX 16
#define HAS_TEMPERATURE 0
// 1: passes/gaps.py close_again, on the smoothed depth: background pixels only (pinholes: the
// holes a lattice's channels leave once the first pass closed their walls), with the first
// pass's tiles (the smoothing moves depths by a fraction of r, so their bounds are a heuristic
// there, not the exact search they are here).
#define BACKGROUND_ONLY 0

#include "common/depth_image.glsl"

uniform sampler2D u_depth;
uniform sampler2D u_tiles;        // per 4x4 pixels: nearest depth (0: none), jump front, in 16 px
uniform sampler2D u_axes;         // nearest front along the tile's row and column: x-, x+, y+, y-
uniform sampler2D u_diagonals;    // nearest front of its quadrants: x+y+, x-y-, x+y-, x-y+
uniform float u_focal_px;         // pixels per unit at eye depth 1
uniform float u_particle_radius;  // scene units
uniform float u_gap_radii;        // widest gap closed, in particle radii
uniform float u_edge_jump;        // a surface nearer by more than this is in front

layout(location = 0) out vec4 out_depth;
#if HAS_TEMPERATURE
uniform sampler2D u_temperature;  // the splat's front-sphere kelvin (0 where no sphere), peak in g
layout(location = 1) out vec4 out_temperature;
#endif

bool nearer(float z, float zc) {
    return z > 0.0 && (zc <= 0.0 || z < zc - u_edge_jump);
}

// First step k in 1..reach along `step` onto a nearer surface, reached by a jump; 0 if none
// (or reached up a slope); its depth in `z`.
int walk(ivec2 p, ivec2 step, float zc, int reach, out float z) {
    z = 0.0;
    float previous = zc;
    for (int k = 1; k <= GAP_MAX_PX; ++k) {
        if (k > reach) {
            break;
        }
        float zk = fetch_depth(u_depth, p + k * step);
        if (nearer(zk, zc)) {
            if (previous <= 0.0 || zk < previous - u_edge_jump) {
                z = zk;
                return k;
            }
            return 0;
        }
        previous = zk;
    }
    return 0;
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    float zc = fetch_depth(u_depth, p);
    float tolerance = u_gap_radii * u_particle_radius;
    float limit_px = tolerance * u_focal_px;  // the gap limit in pixels is limit_px / min(za, zb)
    out_depth = vec4(zc, 0.0, 0.0, 0.0);
#if HAS_TEMPERATURE
    out_temperature = vec4(texelFetch(u_temperature, p, 0).rg, 0.0, 0.0);
#endif
#if BACKGROUND_ONLY
    if (zc > 0.0) {
        return;
    }
#endif
    vec2 tile = texelFetch(u_tiles, p / 4, 0).rg;
    if (!nearer(tile.g, zc)) {
        return;  // no jump front nearer than this pixel within reach: no walk can stop
    }
    vec4 axes = texelFetch(u_axes, p / 4, 0);
    vec4 diagonals = texelFetch(u_diagonals, p / 4, 0);
    bool possible[4] = bool[4](
        nearer(axes.r, zc) && nearer(axes.g, zc),
        nearer(axes.b, zc) && nearer(axes.a, zc),
        nearer(diagonals.r, zc) && nearer(diagonals.g, zc),
        nearer(diagonals.b, zc) && nearer(diagonals.a, zc));
    int need = zc > 0.0 ? 1 : 2;
    int left = int(possible[0]) + int(possible[1]) + int(possible[2]) + int(possible[3]);
    if (left < need) {
        return;  // too few directions with a nearer jump front on both sides
    }
    int reach = min(int(ceil(limit_px / tile.r)), GAP_MAX_PX);
    ivec2 steps[4] = ivec2[4](ivec2(1, 0), ivec2(0, 1), ivec2(1, 1), ivec2(1, -1));
    int enclosing = 0;
    float best_span = 0.0;
    float fill = zc;
    ivec2 fill_a = p;  // the pixels the fill interpolates between, and the weight of the second
    ivec2 fill_b = p;
    float fill_t = 0.0;
    for (int i = 0; i < 4; ++i) {
        if (!possible[i]) {
            continue;
        }
        if (enclosing + left < need) {
            break;  // too few directions left
        }
        left -= 1;
        float za;
        float zb;
        int ka = walk(p, steps[i], zc, reach, za);
        if (ka == 0) {
            continue;
        }
        int kb = walk(p, -steps[i], zc, reach - ka, zb);
        if (kb == 0) {
            continue;
        }
        float span = float(ka + kb) * (i < 2 ? 1.0 : sqrt(2.0));
        if (span <= limit_px / min(za, zb) && abs(za - zb) <= tolerance) {
            enclosing += 1;
            if (enclosing == 1 || span < best_span) {
                best_span = span;
                fill_t = float(ka) / float(ka + kb);
                fill = za + (zb - za) * fill_t;
                fill_a = p + ka * steps[i];
                fill_b = p - kb * steps[i];
            }
        }
    }
    if (enclosing >= need) {
        out_depth = vec4(fill, 0.0, 0.0, 0.0);
#if HAS_TEMPERATURE
        vec2 ta = texelFetch(u_temperature, fill_a, 0).rg;
        vec2 tb = texelFetch(u_temperature, fill_b, 0).rg;
        out_temperature = vec4(ta + (tb - ta) * fill_t, 0.0, 0.0);
#endif
    }
}
