// Field normals (passes/field_normals.py; numpy reference in tests/reference_field_normals.py):
// the functions of its two compute passes, field/field_list.comp.glsl (which pixels, and
// their weights) and field/field_blend.comp.glsl (the field's normal, blended in).
// Near a rim the depth-differenced normal follows the beads of the particle spheres and stays
// flat up to the edge of a sheet's hole; the surface a reconstruction would draw there (an
// iso-surface of the field phi(x) = sum_j W(|x - x_j|, h), the cubic spline of support
// h = quality.field_normals_support radii, as splashsurf's of 4 r) turns smoothly.
// Its normal is -grad phi / |grad phi|, which `field_blend` evaluates at the pixel's own
// surface point and blends in by the distance to the rim (`field_weight`):
// * reach k = u_reach_radii projected particle radii at the pixel's depth, rounded, in
//   1 .. FIELD_MAX_REACH pixels (the rim tiles' +-8 pixels must hold distance k + 1);
// * rims: a pixel q at d = |dx| + |dy| <= k + 1 without surface (strength 1), or whose depth
//   differs by more than jump = max(u_edge_jump, d u_edge_jump_px footprints) (nearer or
//   farther; the image border is no rim): the normals pass's edge rule between neighbours,
//   whose footprint part (a grazing surface far away steps by more than 4 r per pixel and is
//   still one surface) adds up over d pixels. A step's strength rises smoothly from 0 at the
//   jump to 1 at FIELD_RIM_FEATHER jumps: a step just past it is barely a rim, so no small
//   move of a particle turns a rim on or off. (At 960x540: the spatter's droplets 0.84 -> 0.55
//   deg and its band 2.25 -> 1.66: a droplet a few radii in front of the pool no longer pulls
//   the pool's normals beside it, nor the pool the droplet's; the dam break's tolerant band
//   8.31 -> 8.32; a feather of 3: 0.41, 1.28, 8.38; of 1.5: 0.70, 2.08, 8.31);
// * an exact droplet (drawn over the smoothed bulk, passes/splat.py run_droplets) is no rim of
//   the bulk behind it: at a pixel of the bulk a nearer neighbour is measured at the bulk's
//   own depth under it (u_bulk_depth). The bulk's surface goes on behind a droplet, its depth
//   normals there are those of the frame without the droplet, and its field normal differs
//   from them by degrees: a ring around every droplet on a mirror-like pool (dam break frame 9
//   close-up at 1280x720: 9.4 deg against the pool's own normal next to an exact droplet,
//   1.3 deg without; at 960x540 the spatter's band 1.66 -> 1.32 deg, the dam break's
//   tolerant band 8.10 / 8.00 / 9.06 -> 8.13 / 7.93 / 8.90 deg on frames 5 / 9 / 13);
//   weight t = the largest over the rims of strength x (1 - (d - 1) / (k + 1)) (1 next to a
//   full rim, 0 beyond the reach);
// * grad phi at the pixel's view-space point x from every centre of the field grid
//   (common/field_grid.glsl: rows of cells of side h / 2) within h of x: the cubic spline's dW/dq / q times (x - x_j)
//   (constants dropped: only the direction is used);
// * a visible surface faces the eye: a field normal pointing away from it is mirrored at the
//   plane perpendicular to the view ray (n - 2 (n.ray) ray), keeping its direction on screen,
//   the part the field gets right next to a rim, and its angle to that plane; the pixel's
//   surface point there lies off the field's iso-surface, on a side of it the eye cannot
//   see. (Dropping the away part instead, a grazing normal: dam-break band 8.9 vs 8.5 deg.)
//   Where |grad phi| vanishes (no neighbour, a symmetric neighbourhood) the depth normal stays;
// * the result is normalize(mix(n_depth, n_field, t)). Depth unchanged.
// Pixels whose rim tile (passes/rim_tiles.py: farthest and nearest depth within +-8 pixels)
// holds nothing beyond the jump either way skip all of it.

// At most 5 pixels: the dam break at 960x540 against splashsurf, 1-px tolerant band 8.55 deg at
// 7 px, 8.52 at 5, 8.64 at 4; on the 100k ball at 1280x720 (reach 2 r = 8.6 px there) the
// listed pixels fall by a third (the normals stage 29 -> 24 ms on llvmpipe).
#define FIELD_MAX_REACH 5
// A depth step is a full rim from this many edge jumps on (see the header).
#define FIELD_RIM_FEATHER 2.0

#include "common/field_grid.glsl"

layout(std430, binding = 14) readonly buffer Buckets { uint starts[]; };
layout(std430, binding = 16) readonly buffer Sorted { vec4 sorted_centres[]; };

uniform sampler2D u_tiles;    // (farthest, nearest) depth within 8 px, per 4 x 4 tile
uniform sampler2D u_tile_extremes;  // the same of each tile's own 4 x 4 pixels
uniform sampler2D u_bulk_depth;  // the bulk's eye depth under the droplets (u_depth if none)
uniform bool u_droplets;          // whether droplets were drawn over the bulk (u_bulk_depth)
uniform float u_reach_radii;  // quality.field_normals: the reach in projected particle radii
// Also read, declared by the including shader: u_depth (the eye depth image), u_edge_jump,
// u_edge_jump_px, u_focal_px and u_particle_radius.

// The first ring d (1 .. limit) of the diamond around p that can hold a rim pixel for a pixel
// of depth zc, limit + 1 if none, from the extremes of the 4 x 4 tiles (u_tile_extremes) that
// the square within +-limit of p overlaps: a tile whose nearest pixel lies dm = |dx| + |dy|
// from p holds rim pixels only at d >= dm, whose jump is at least that at max(dm, 1), so it can
// hold one only if a depth in it differs from zc by more (the same float comparisons as
// rim_strength's test for a step, on its farthest and its nearest depth: no rim is ever
// missed). On the 100k ball at 1280x720 the pixels near a silhouette with no rim within reach
// stop here after ~20 fetches instead of walking every ring's ~4 d.
int first_rim_ring(ivec2 p, float zc, float footprint_jump, int limit) {
    ivec2 last_tile = textureSize(u_tile_extremes, 0) - 1;
    ivec2 lo = max(p - limit, ivec2(0)) / 4;
    ivec2 hi = min((p + limit) / 4, last_tile);
    int first = limit + 1;
    for (int ty = lo.y; ty <= hi.y; ++ty) {
        int gy = max(max(4 * ty - p.y, p.y - 4 * ty - 3), 0);
        for (int tx = lo.x; tx <= hi.x; ++tx) {
            int gx = max(max(4 * tx - p.x, p.x - 4 * tx - 3), 0);
            int dm = max(gx + gy, 1);
            if (dm < first) {
                float jump = max(u_edge_jump, footprint_jump * float(dm));
                vec2 tile = texelFetch(u_tile_extremes, ivec2(tx, ty), 0).rg;
                if (tile.r - zc > jump || zc - tile.g > jump) {
                    first = dm;
                }
            }
        }
    }
    return first;
}

// How much of a rim q is for a pixel of depth zc at the jump `jump`: 1 without surface, 0 on
// the pixel's own surface (and off the image), smoothly in between for a depth step from 1 to
// FIELD_RIM_FEATHER jumps. `on_bulk`: the pixel shows the bulk (no droplet over it); a nearer
// q is then measured at the bulk's depth under it, at most zc (header: a droplet drawn in
// front of the bulk is no rim of it). Never farther from zc than u_depth's value, so the tile
// tests, which read u_depth's extremes, still never miss a rim.
float rim_strength(ivec2 q, ivec2 size, float zc, float jump, bool on_bulk) {
    if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) {
        return 0.0;
    }
    float z = texelFetch(u_depth, q, 0).r;
    if (z <= 0.0) {
        return 1.0;
    }
    if (on_bulk && z < zc) {
        float under = texelFetch(u_bulk_depth, q, 0).r;
        z = under > 0.0 ? min(under, zc) : z;  // no bulk under it: the droplet's step stays
    }
    return smoothstep(jump, FIELD_RIM_FEATHER * jump, abs(z - zc));
}

// The field's weight from the rims within reach + 1 (header): the largest of strength x
// (1 - (d - 1) / (reach + 1)) over the rings d. `tile`: the farthest and the nearest depth of a
// window holding every pixel within reach + 1 (the rim tiles); once no depth in it differs from
// zc by more than the next ring's jump, no farther ring can hold a rim (the jump only grows
// with d): on a smooth slope the search stops there instead of walking every ring. The walk
// starts at first_rim_ring's and stops at the first ring whose weight a rim found already
// reaches (a full rim: that ring; the 100k ball at 1280x720: 61k pixels search, 49k of them
// find no rim).
float rim_weight(ivec2 p, ivec2 size, float zc, float footprint_jump, int reach, vec2 tile,
                 bool on_bulk) {
    int limit = reach + 1;
    float best = 0.0;
    for (int d = first_rim_ring(p, zc, footprint_jump, limit); d <= FIELD_MAX_REACH + 1; ++d) {
        if (d > limit) {
            break;
        }
        float ring = 1.0 - float(d - 1) / float(reach + 1);
        if (best >= ring) {
            break;
        }
        float jump = max(u_edge_jump, footprint_jump * float(d));
        if (tile.r - zc <= jump && zc - tile.g <= jump) {
            break;
        }
        float strongest = 0.0;
        for (int k = 0; k < d && strongest < 1.0; ++k) {
            strongest = max(strongest, rim_strength(p + ivec2(d - k, k), size, zc, jump, on_bulk));
            strongest = max(strongest, rim_strength(p + ivec2(-k, d - k), size, zc, jump, on_bulk));
            strongest = max(strongest, rim_strength(p + ivec2(k - d, -k), size, zc, jump, on_bulk));
            strongest = max(strongest, rim_strength(p + ivec2(k, k - d), size, zc, jump, on_bulk));
        }
        best = max(best, strongest * ring);
    }
    return best;
}

// (dW/dq) / q of the cubic spline without its constant; zero from q = 1 on.
float spline_dw_over_q(float q) {
    if (q <= 0.5) {
        return 6.0 * (3.0 * q - 2.0);
    }
    if (q < 1.0) {
        float t = 1.0 - q;
        return -6.0 * t * t / q;
    }
    return 0.0;
}

// Distance along one axis from offset o (in [0, cell)) inside a cell to the cell `delta`
// steps away: 0 for its own cell.
float gap_to_cell(int delta, float o, float cell) {
    if (delta == 0) {
        return 0.0;
    }
    return delta < 0 ? o + float(-delta - 1) * cell : cell - o + float(delta - 1) * cell;
}

// Adds the terms of the sorted centres first .. end - 1 within h of x, each times its weight.
void add_centres(uint first, uint end, vec3 x, float h, inout vec3 outward, inout float scale) {
    float h2 = h * h;
    for (uint j = first; j < end; ++j) {
        vec4 c = sorted_centres[j];  // w: how many coincident centres it stands for
        vec3 d = x - c.xyz;
        float r2 = dot(d, d);
        if (r2 < h2) {
            float r = sqrt(r2);
            float w = spline_dw_over_q(r / h) * c.w;
            outward -= w * d;  // dW/dq < 0: away from x_j
            scale += abs(w) * r;
        }
    }
}

// -grad phi at x (unnormalised), and the sum of the terms' magnitudes in .w. Visits the rows
// of cells along x (common/field_grid.glsl: one contiguous run of centres each) of the
// (2 m + 1)^2 around x's own whose nearest point lies within h (~22 for m = 2), each only over
// the cells its chord of the support sphere crosses: ~10.5 h^3 of volume against 20.6 h^3 for
// the 27 cells of side h the grid had, box-tested (1.42M against 1.78M centres visited on the
// 100k ball at 1280x720; the blend pass 9.4 -> 7.5 ms on llvmpipe; inside the fragment shader
// it was no faster, its lanes running rows of different lengths; m = 3: more rows than saved).
vec4 field_gradient(vec3 x) {
    const int m = FIELD_CELLS_PER_SUPPORT;
    float h = u_support;
    float cell = grid_cell_side();
    uint buckets = u_bucket_mask + 1u;
    ivec3 home = grid_cell(x);
    vec3 local = x - vec3(home) * cell;
    vec3 outward = vec3(0.0);
    float scale = 0.0;
    for (int dz = -m; dz <= m; ++dz) {
        float gz = gap_to_cell(dz, local.z, cell);
        for (int dy = -m; dy <= m; ++dy) {
            float gy = gap_to_cell(dy, local.y, cell);
            float row2 = gy * gy + gz * gz;
            if (row2 >= h * h) {
                continue;
            }
            float chord = sqrt(h * h - row2);
            int lo = max(int(floor((local.x - chord) / cell)), -m);
            int hi = min(int(floor((local.x + chord) / cell)), m);
            uint first = grid_bucket(home + ivec3(lo, dy, dz));
            uint last = first + uint(hi - lo + 1);  // one past the row's last bucket
            if (last <= buckets) {
                add_centres(starts[first], starts[last], x, h, outward, scale);
            } else {  // the row wraps at the table's end
                add_centres(starts[first], starts[buckets], x, h, outward, scale);
                add_centres(starts[0], starts[last - buckets], x, h, outward, scale);
            }
        }
    }
    return vec4(outward, scale);
}

// The field's weight t at the pixel p of eye depth zc (> 0): rim_weight's, 0 where no rim lies
// within reach + 1 (the depth normal stays).
float field_weight(ivec2 p, ivec2 size, float zc) {
    float jump = max(u_edge_jump, u_edge_jump_px * zc / u_focal_px);
    vec2 tile = texelFetch(u_tiles, p / 4, 0).rg;
    if (tile.r - zc <= jump && zc - tile.g <= jump) {
        return 0.0;
    }
    float radius_px = u_particle_radius * u_focal_px / zc;
    int reach = clamp(int(round(u_reach_radii * radius_px)), 1, FIELD_MAX_REACH);
    // The composite copies the bulk's depth exactly; without droplets there is nothing to test.
    bool on_bulk = u_droplets && texelFetch(u_bulk_depth, p, 0).r == zc;
    return rim_weight(p, size, zc, u_edge_jump_px * zc / u_focal_px, reach, tile, on_bulk);
}

// The view-space normal n at the view point x taken towards the field's by the weight t, in
// `blended`; false (nothing to change) where the field's gradient vanishes.
bool field_blend(vec3 x, vec3 n, float t, out vec3 blended) {
    blended = n;
    vec4 g = field_gradient(x);
    float len_g = length(g.xyz);
    if (!(len_g > 1e-4 * g.w) || !(len_g > 0.0)) {
        return false;
    }
    vec3 n_field = g.xyz / len_g;
    vec3 ray = normalize(x);
    float away = dot(n_field, ray);
    if (away > 0.0) {
        n_field = normalize(n_field - 2.0 * away * ray);  // a reflection: unit length kept
    }
    vec3 mixed = mix(n, n_field, t);
    float len_b = length(mixed);
    if (!(len_b > 1e-3)) {
        return false;
    }
    blended = mixed / len_b;
    return true;
}
