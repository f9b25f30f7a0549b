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
// keeps its depth. So a depth only ever gets nearer (no hole opens where the spheres cover),
// a notch between two beads at a silhouette (enclosed along the edge only) stays open, and two
// particles whose silhouettes are farther apart than u_gap_radii radii stay apart.
// Bounded search (the same result): the tiles of gap_tiles.frag.glsl (nearest depth, edge flag)
// around the pixel: the 16-pixel ones cover +-16 >= GAP_MAX_PX pixels: without an edge or a
// pixel nearer than zc - u_edge_jump there (the interior of a surface), nothing to do; else no
// span can exceed u_gap_radii * r * f / z16 pixels, the reach; the 4-pixel tiles over +-reach
// then give the same tests and a nearer bound z4, and the walks stop at the reach.

#define GAP_MAX_PX 16

#include "common/depth_image.glsl"

uniform sampler2D u_depth;
uniform sampler2D u_tiles4;       // nearest depth per 4 x 4 pixels (0: none)
uniform sampler2D u_tiles16;      // nearest depth per 16 x 16 pixels (0: none)
uniform float u_focal_px;         // pixels per unit at eye depth 1
uniform float u_particle_radius;  // scene units
uniform float u_gap_radii;        // widest gap closed, in particle radii
uniform float u_edge_jump;        // a surface nearer by more than this is in front

layout(location = 0) out vec4 out_depth;

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

// Over tiles lo..hi (clamped to the image of tiles): the nearest positive depth (0: none), and
// whether any holds an edge.
float nearest_in(sampler2D tiles, ivec2 lo, ivec2 hi, out bool edge) {
    ivec2 last = textureSize(tiles, 0) - 1;
    lo = clamp(lo, ivec2(0), last);
    hi = clamp(hi, ivec2(0), last);
    float nearest = 0.0;
    edge = false;
    for (int y = lo.y; y <= hi.y; ++y) {
        for (int x = lo.x; x <= hi.x; ++x) {
            vec2 tile = texelFetch(tiles, ivec2(x, y), 0).rg;
            float z = tile.r;
            edge = edge || tile.g > 0.0;
            if (z > 0.0 && (nearest == 0.0 || z < nearest)) {
                nearest = z;
            }
        }
    }
    return nearest;
}

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    float zc = fetch_depth(u_depth, p);
    float tolerance = u_gap_radii * u_particle_radius;
    float limit_px = tolerance * u_focal_px;  // the gap limit in pixels is limit_px / min(za, zb)
    out_depth = vec4(zc, 0.0, 0.0, 0.0);
    bool edge;
    float z16 = nearest_in(u_tiles16, p / 16 - 1, p / 16 + 1, edge);
    if (!edge || !nearer(z16, zc)) {
        return;
    }
    int reach = min(int(ceil(limit_px / z16)), GAP_MAX_PX);
    float z4 = nearest_in(u_tiles4, (p - reach) / 4, (p + reach) / 4, edge);
    if (!edge || !nearer(z4, zc)) {
        return;
    }
    reach = min(reach, int(ceil(limit_px / z4)));
    ivec2 steps[4] = ivec2[4](ivec2(1, 0), ivec2(0, 1), ivec2(1, 1), ivec2(1, -1));
    int enclosing = 0;
    float best_span = 0.0;
    float fill = zc;
    for (int i = 0; i < 4; ++i) {
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
                fill = za + (zb - za) * float(ka) / float(ka + kb);
            }
        }
    }
    if (enclosing >= (zc > 0.0 ? 1 : 2)) {
        out_depth = vec4(fill, 0.0, 0.0, 0.0);
    }
}
