#version 330 core
// Separable depth smoothing (thesis §3.3) on a packed eye-depth image: texel (x, y) holds pixels
// 4x .. 4x+3 of row y in .xyzw (0 = background), so one fragment filters four horizontally
// adjacent pixels, one per component. Same filters and kernel rule as smooth_depth.frag.glsl
// (which does the 2-D kernels); packing only changes how often the image is read: 4x fewer
// fetches along columns, 16x fewer along rows (common/packed_taps.glsl). llvmpipe spends most
// of a 1-D pass on texel fetches, so this is where the time goes.
// Every tap is applied in the same order as in the unpacked filter (offset 1, 2, ... outwards,
// the mirror pair together), which the narrow-range filter's growing range depends on.

#define FILTER_GAUSSIAN 0
#define FILTER_BILATERAL 1
#define FILTER_NARROW_RANGE 2
#define FILTER 2
// 0: filter along rows (x), 1: along columns (y).
#define AXIS 0
#define KERNEL_SIZE_PROJECTED_RADIUS 0
#define KERNEL_SIZE_DEPTH_FALLOFF 1
#define KERNEL_SIZE 0
// 1: the variant passes/smooth.py draws where a kernel may reach past the image's ends (within
// kernel_max_px of them): there the kernel goes on one-sided and fits a line
// (image_border_taps.glsl); the same result as 0 wherever no kernel reaches that far.
#define IMAGE_BORDER 0
// 1: the narrow range's crease test (quality.crease_angle) is compiled in.
#define CREASE_TEST 0
// The narrow range's normal guide (quality.normal_guide): 0 off; 1 a tap's weight times
// 1 - smoothstep of the turn between the pilot normals at the centre and the tap (less a
// sphere's turn over the distance, normal_guide_turn), the result a weighted line fit
// (image_border_taps.glsl); 2 as 1, cutting convex turns only (normal_guide_convex), told by
// the taps' depths; 3 as 2, told on the centre's pilot tangent plane (normal_guide_tangent).
#define NORMAL_GUIDE 0

// 1: the guide's normals carry guide_flat.frag.glsl's flags: a tap is cut only where the pilot
// is flat past it (away from the centre).
#define GUIDE_FLAT 0
// 1: the guide's rule was evaluated once, on the pilot, into per-pixel one-sided limits
// (guide_limits.frag.glsl, u_guide_limits): a tap is weighed by its offset against them alone.
#define GUIDE_LIMITS 0
// Those limits are at 1 / GUIDE_SCALE of the image's size (quality.normal_guide_downscale):
// texel (x, y) holds reduced pixels 4x .. 4x+3 of row y, in reduced pixels.
#define GUIDE_SCALE 1

#if NORMAL_GUIDE && !GUIDE_LIMITS
// The taps' values are the pilot normals (guide_normals.frag.glsl), the guide the depth.
#define PACKED_VALUE 1
#define STRIDED_VALUE 1
#else
// The depth is its own guide (common/packed_taps.glsl).
#define PACKED_VALUE 0
#endif

#include "common/depth_filter_params.glsl"
#include "common/gaussian_steps.glsl"
#include "common/packed_image.glsl"

uniform sampler2D u_packed_depth;
// The kernel's sigma times this: per pass, from quality.last_pass_sigma and quality.destreak
// (passes/smooth.py separable_passes); 1 for equal passes.
uniform float u_sigma_scale;
// The narrow range's pair limit (quality.narrow_range_pairs x r, scene units) on this pass;
// 3e38 where it is off (passes/smooth.py: always on the first pass).
uniform float u_nr_pair_limit;
// The crease test's turn limit on this pass: tan(quality.crease_angle); negative: off.
uniform float u_crease_limit;
#if NORMAL_GUIDE
uniform sampler2D u_guide_normals;  // packed, encoded (guide_normals.frag.glsl)
// The cut's ramp over the squared turn less the squared turn tolerated: t = x * scale + offset
// (0 at the lower limit, 1 at the upper); the tolerated turn's square per squared scene unit
// of distance to the tap; the convex ramp over the sine of the tap's angle behind the centre's
// pilot tangent plane (NORMAL_GUIDE 2) or of the tap normal's tilt towards the tap (3).
uniform vec2 u_guide_ramp;
uniform float u_guide_turn2;
uniform vec2 u_guide_convex;
uniform float u_guide_on;  // 1: this pass weights its taps; 0: plain weights (still fitted)
uniform bool u_guide_fit;  // the line fit (else the weighted mean)
#if GUIDE_LIMITS
uniform sampler2D u_guide_limits;  // packed (guide_limits.frag.glsl)
vec4 g_limit_plus;   // the lanes' limits along +AXIS and -AXIS, pixels (3e4 where
vec4 g_limit_minus;  // u_guide_on is 0)
vec4 g_inverse_centre;  // 1 / the centre's depth
#endif
vec4 g_normal_x;  // the centre's pilot normal, per lane
vec4 g_normal_y;
vec4 g_normal_z;
vec4 g_ray_x;     // the centre's view position over its depth
float g_ray_y;
vec4 g_normal_ray;   // dot(centre normal, (g_ray_x, g_ray_y, 1))
vec4 g_normal_axis;  // the centre normal's component along AXIS
vec4 g_guide_on;     // u_guide_on, 0 where the centre is a rim pixel
vec4 g_tangent_axis;    // NORMAL_GUIDE 3: the centre's pilot tangent along +AXIS: its AXIS
vec4 g_tangent_z;       // and z components,
vec4 g_tangent_scale2;  // and its squared length in scene units per pixel of offset
#endif

layout(location = 0) out vec4 out_packed_depth;

// Per-pixel filter state; component i belongs to pixel 4x + i.
vec4 g_center;
vec4 g_reach;          // kernel radius in pixels; 0 for background pixels
vec4 g_sum;
vec4 g_weight_sum;
#if FILTER == FILTER_NARROW_RANGE
vec4 g_upper;
vec4 g_lower;
vec4 g_lower_clamp;
#if CREASE_TEST
vec4 g_run_start;      // offset where the current run of turning pairs began; -1: none
bvec4 g_crease;        // the kernel met a crease: no tap further out is taken
vec4 g_radius_px;      // the projected particle radius, per lane
#endif
#endif

#if FILTER == FILTER_NARROW_RANGE
// The narrow range averages inverse depth: over a plane 1/z is affine in the image, so a
// plane seen in perspective comes out of the filter unchanged, where an average of z would
// bend it by half its second derivative times sigma^2 (0.12 r on a slab seen from 0.3 units at
// 35 degrees) and tilt its normals where the kernel's size changes. Finite for background 0.
vec4 inverse_depth(vec4 z) {
    return 1.0 / max(z, vec4(1e-30));
}

// Whether a mirrored pair (za at +k, zb at -k) stays on the centre's surface: its midpoint in
// inverse depth departs from the centre's by at most the pair limit, as a depth difference
// (d(1/z) x z^2). A plane's pair never departs (1/z is affine in the image over a plane, at
// any slope and kernel length); a pair whose taps both lie on a surface h behind (a blob
// narrower than the kernel, in front of a pool) departs by about h, a pair across one step
// of h by h / 2.
bvec4 pair_test(vec4 za, vec4 zb) {
    vec4 mid = 0.5 * (inverse_depth(za) + inverse_depth(zb)) - inverse_depth(g_center);
    return lessThanEqual(abs(mid) * g_center * g_center, vec4(u_nr_pair_limit));
}
#if CREASE_TEST
// A crease (two flat faces meeting at an edge) turns the surface by a large angle within the
// kernel, a sphere of radius R by the kernel's length over R only. Where the chords from the
// centre to the pair's two taps turn by more than crease_angle for a projected radius of taps
// in a row (the relief between particles turns them for a tap or two), no further tap is taken:
// the faces are not averaged across the edge. Taps off the centre's surface never count.
// Called once per pair, in order from the centre outwards.
bvec4 crease_met(vec4 za, vec4 zb, float k) {
    // within the narrow range's band: neither behind it (dropped) nor in front (clamped)
    bvec4 on_surface = both(both(greaterThanEqual(za, g_lower), lessThanEqual(za, g_upper)),
                            both(greaterThanEqual(zb, g_lower), lessThanEqual(zb, g_upper)));
    // the chords' slopes da / step, db / step turn by more than L where
    // |da - db| step > tan(L) (step^2 + da db): tan of their angle's difference, without atan
    // (and always where step^2 + da db <= 0: a turn of 90 degrees or more)
    vec4 step = k * g_center / u_px_per_unit;  // the taps' lateral offset, scene units
    vec4 da = za - g_center;
    vec4 db = g_center - zb;
    vec4 turn_excess = abs(da - db) * step - u_crease_limit * (step * step + da * db);
    bvec4 over = both(on_surface, greaterThan(turn_excess, vec4(0.0)));
    over = both(over, bvec4(u_crease_limit >= 0.0));
    vec4 started = mix(g_run_start, vec4(k), lessThan(g_run_start, vec4(0.0)));
    g_run_start = mix(vec4(-1.0), started, over);
    g_crease = either(g_crease, both(over, greaterThanEqual(vec4(k) - g_run_start, g_radius_px)));
    return g_crease;
}
#endif

// pair_test and the crease test together: whether the pair at +-k is taken.
bvec4 pair_kept(vec4 za, vec4 zb, float k) {
#if CREASE_TEST
    return both(pair_test(za, zb), not(crease_met(za, zb, k)));
#else
    return pair_test(za, zb);
#endif
}

// One sample `z` of the narrow range: clamped to z_centre - mu r when in front by more than
// lambda r, else (when `use`d) it grows the accepted range around itself; returns the value
// the sample adds.
vec4 narrow_range_sample(vec4 z, bvec4 use) {
    bvec4 in_front = lessThan(z, g_lower);
    z = mix(z, g_lower_clamp, in_front);
    bvec4 grow = both(use, not(in_front));
    g_upper = mix(g_upper, max(g_upper, z + u_nr_threshold), grow);
    g_lower = mix(g_lower, min(g_lower, z - u_nr_threshold), grow);
    return z;
}
#endif

#if FILTER != FILTER_NARROW_RANGE
// The Gaussian's or the bilateral's taps at +-k of spatial weight w: added to the sums; which
// were taken in use_a, use_b (not: no surface, or past the image's end, which reads 0), their
// weights in wa, wb (0 where not taken). Shared with image_border_taps.glsl, so both add the
// same bits.
void spatial_taps(vec4 w, bvec4 in_reach, vec4 za, vec4 zb, out vec4 wa, out vec4 wb,
                  out bvec4 use_a, out bvec4 use_b) {
    use_a = both(in_reach, greaterThan(za, vec4(0.0)));
    use_b = both(in_reach, greaterThan(zb, vec4(0.0)));
    wa = w;
    wb = w;
#if FILTER == FILTER_BILATERAL
    float inv_two_range2 = 1.0 / (2.0 * u_range_sigma * u_range_sigma);
    vec4 da = za - g_center;
    vec4 db = zb - g_center;
    wa *= exp(-da * da * inv_two_range2);
    wb *= exp(-db * db * inv_two_range2);
#endif
    g_sum += mix(vec4(0.0), wa * za, use_a) + mix(vec4(0.0), wb * zb, use_b);
    g_weight_sum += mix(vec4(0.0), wa, use_a) + mix(vec4(0.0), wb, use_b);
    wa = mix(vec4(0.0), wa, use_a);
    wb = mix(vec4(0.0), wb, use_b);
}
#endif

#include "common/border_fit.glsl"

#if NORMAL_GUIDE
// Decodes four lanes of guide_normals.frag.glsl's normals (three 8-bit components per float).
void guide_normal_decode(vec4 v, out vec4 nx, out vec4 ny, out vec4 nz) {
    v = abs(v);  // negative: a rim pixel
#if GUIDE_FLAT
    // guide_flat.frag.glsl's: 7 bits a component under two flag bits
    v -= floor(v / 2097152.0) * 2097152.0;
    vec4 a = floor(v / 16384.0);
    vec4 rest = v - a * 16384.0;
    vec4 b = floor(rest / 128.0);
    vec4 c = rest - b * 128.0;
    nx = a / 63.5 - 1.0;
    ny = b / 63.5 - 1.0;
    nz = c / 63.5 - 1.0;
#else
    vec4 a = floor(v / 65536.0);
    vec4 rest = v - a * 65536.0;
    vec4 b = floor(rest / 256.0);
    vec4 c = rest - b * 256.0;
    nx = a / 127.5 - 1.0;
    ny = b / 127.5 - 1.0;
    nz = c / 127.5 - 1.0;
#endif
}

#if GUIDE_FLAT
// 1 where guide_flat.frag.glsl found the pilot flat past the tap, away from the centre (the
// tap at +k: its +AXIS flag; at -k: its -AXIS flag).
vec4 guide_flat_past(vec4 encoded, float signed_k) {
    vec4 flags = floor(abs(encoded) / 2097152.0);  // 0..3
    vec4 minus = floor(flags / 2.0);
    vec4 plus = flags - 2.0 * minus;
    return signed_k > 0.0 ? plus : minus;
}
#endif

// The guide's weight of the tap at signed offset k, depth z, whose encoded pilot normal is
// `encoded`: 1 - smoothstep over the turn between it and the centre's (a box edge is cut, a
// slow turn passes), the turn's square taken as 2 (1 - cos) (within 10% up to 60 degrees).
vec4 guide_weight(vec4 encoded, vec4 z, float signed_k) {
    vec4 nx;
    vec4 ny;
    vec4 nz;
    guide_normal_decode(encoded, nx, ny, nz);
    // the decoded normals are unit within the 8-bit steps only: renormalized, or a normal
    // would turn from itself by up to 9 degrees
    vec4 inverse_norm = inversesqrt(max(nx * nx + ny * ny + nz * nz, vec4(1e-6)));
    vec4 cosine = (nx * g_normal_x + ny * g_normal_y + nz * g_normal_z) * inverse_norm;
    vec4 turn2 = 2.0 - 2.0 * cosine;
#if NORMAL_GUIDE == 3
    // on the centre's pilot tangent plane: the distance to the tap, and the tap normal's tilt
    // towards it (positive: the surface turns away, convex)
    vec4 tolerated2 = u_guide_turn2 * (signed_k * signed_k) * g_tangent_scale2;
    vec4 t = clamp((turn2 - tolerated2) * u_guide_ramp.x + u_guide_ramp.y, 0.0, 1.0);
    vec4 cut = t * t * (3.0 - 2.0 * t);
    vec4 tilt = sign(signed_k) * ((AXIS == 0 ? nx : ny) * g_tangent_axis + nz * g_tangent_z);
    vec4 c = clamp(tilt * u_guide_convex.x + u_guide_convex.y, 0.0, 1.0);
    cut *= c * c * (3.0 - 2.0 * c);
    return 1.0 - g_guide_on * cut;
#else
    // the tap's view position less the centre's
    float shift = signed_k / u_px_per_unit;
    vec4 dz = z - g_center;
    vec4 dx = g_ray_x * dz + (AXIS == 0 ? shift : 0.0) * z;
    vec4 dy = g_ray_y * dz + (AXIS == 1 ? shift : 0.0) * z;
    vec4 distance2 = dx * dx + dy * dy + dz * dz;
    vec4 excess = turn2 - u_guide_turn2 * distance2;
    vec4 t = clamp(excess * u_guide_ramp.x + u_guide_ramp.y, 0.0, 1.0);
    vec4 cut = t * t * (3.0 - 2.0 * t);
#if NORMAL_GUIDE == 2
    vec4 behind = -(dz * g_normal_ray + (shift * z) * g_normal_axis)
                  * inversesqrt(max(distance2, vec4(1e-30)));
    vec4 c = clamp(behind * u_guide_convex.x + u_guide_convex.y, 0.0, 1.0);
    cut *= c * c * (3.0 - 2.0 * c);
#endif
#if GUIDE_FLAT
    cut *= guide_flat_past(encoded, signed_k);
#endif
    return 1.0 - g_guide_on * cut;
#endif
}

#if GUIDE_LIMITS
// The guide's weight of the taps at signed offset k: 1 within the lanes' limit on that side,
// falling to 0 over the pixel past it (guide_limits.frag.glsl).
vec4 guide_limit_weight(float signed_k) {
    vec4 limit = signed_k > 0.0 ? g_limit_plus : g_limit_minus;
    vec4 w = clamp(limit - abs(signed_k) + 0.5, 0.0, 1.0);
    return 1.0 - g_guide_on * (1.0 - w);
}
#endif

// Sets the lanes' view positions over their depth (the view space of guide_normals.frag.glsl;
// u_image_size_px: common/border_fit.glsl) and what guide_weight needs of the centre normals.
void guide_start(ivec2 texel) {
    vec2 centre = 0.5 * vec2(u_image_size_px);
    vec4 px = vec4(float(4 * texel.x)) + vec4(0.0, 1.0, 2.0, 3.0);
    g_ray_x = (px + 0.5 - centre.x) / u_px_per_unit;
    g_ray_y = (float(texel.y) + 0.5 - centre.y) / u_px_per_unit;
    g_normal_ray = g_normal_x * g_ray_x + g_normal_y * g_ray_y + g_normal_z;
    g_normal_axis = AXIS == 0 ? g_normal_x : g_normal_y;
    // the unit tangent (n_z, 0, -n_x) / |.| (AXIS 0) turned to point along +AXIS
    vec4 facing = max(abs(g_normal_z), vec4(0.05));
    vec4 inverse_length = inversesqrt(g_normal_z * g_normal_z + g_normal_axis * g_normal_axis);
    g_tangent_axis = facing * inverse_length;
    g_tangent_z = -sign(g_normal_z) * g_normal_axis * inverse_length;
    // a pixel of offset along AXIS is z / f across, 1 / (|n_z| |tangent|) times that along it
    vec4 across = g_center / u_px_per_unit;
    g_tangent_scale2 = across * across / (facing * facing * inverse_length * inverse_length);
}
#endif

#if IMAGE_BORDER || NORMAL_GUIDE
#include "image_border_taps.glsl"
#else
// The taps at offsets +k (za) and -k (zb) of the four pixels (the value arguments repeat them).
void tap_pair(int k, vec4 za, vec4 zb, vec4 value_a, vec4 value_b) {
    vec4 w = gaussian_next();
    bvec4 in_reach = lessThanEqual(vec4(float(k)), g_reach);
#if FILTER == FILTER_NARROW_RANGE
    // Truong & Yuksel 2018: samples behind the centre by more than lambda*r are dropped, with
    // their mirror sample (no one-sided bias); samples in front by more than lambda*r are
    // clamped to z - mu*r; the accepted range grows around every accepted sample.
    bvec4 valid_a = both(greaterThan(za, vec4(0.0)), lessThanEqual(za, g_upper));
    bvec4 valid_b = both(greaterThan(zb, vec4(0.0)), lessThanEqual(zb, g_upper));
    bvec4 accept = both(both(in_reach, both(valid_a, valid_b)), pair_kept(za, zb, float(k)));
    za = narrow_range_sample(za, accept);
    zb = narrow_range_sample(zb, accept);
    g_sum += mix(vec4(0.0), w * (inverse_depth(za) + inverse_depth(zb)), accept);
    g_weight_sum += mix(vec4(0.0), 2.0 * w, accept);
#else
    vec4 wa;
    vec4 wb;
    bvec4 use_a;
    bvec4 use_b;
    spatial_taps(w, in_reach, za, zb, wa, wb, use_a, use_b);
#endif
}
#endif

#include "common/packed_taps.glsl"

// The lanes' kernel radii in pixels for the wanted `sigma`, and the texel's tap spacing past
// the cap: 3 sigma within [kernel_min_px, kernel_max_px x kernel_max_stride]. A kernel takes
// every pixel out to kernel_max_px; close-ups, whose 3 sigma lies past it, go on with every
// stride-th pixel (each tap standing for `stride` pixels) out to 3 sigma, stride =
// ceil(reach / kernel_max_px): fewer than 2 kernel_max_px taps, and sigma stays kernel_scale
// radii where a hard cap would shrink it and leave the particles' ripple. Spread taps only
// where the Gaussian's tail lies: near the centre they would alias the detail finer than the
// stride (spread from the first tap on: 3.2 deg on the spatter pool at stride 2, against 1.3
// capped). The stride follows the texel's smallest surface lane; the other lanes are cut to
// kernel_max_px x it (a lane at a discontinuity keeps that kernel). Spread taps never reach
// past the image's ends (the border variant's one-sided fit is the cap's): a kernel ends at
// the lane's room to them, which shrinks it continuously to the cap as a lane nears an end.
vec4 kernel_reach(ivec2 texel, vec4 sigma, bvec4 surface, out int stride) {
    float cap = float(u_kernel_max_px);
    vec4 limit = vec4(cap * float(u_kernel_max_stride));
#if IMAGE_BORDER
    limit = vec4(cap);
#else
    vec4 room_ahead;
    vec4 room_behind;
    image_end_room(texel, room_ahead, room_behind);
    limit = min(limit, max(vec4(cap), min(room_ahead, room_behind)));
#endif
    vec4 reach = min(max(ceil(3.0 * sigma), vec4(float(u_kernel_min_px))), limit);  // clamp
    vec4 lane_stride = ceil(reach / cap);
    vec4 smallest = mix(vec4(float(u_kernel_max_stride)), lane_stride, surface);
    stride = int(max(min(min(smallest.x, smallest.y), min(smallest.z, smallest.w)), 1.0));
    return min(reach, vec4(cap * float(stride)));
}

#if NORMAL_GUIDE && GUIDE_LIMITS && GUIDE_SCALE > 1
// The limits of reduced pixel `reduced` (clamped to the reduced image) in full pixels, each
// measured from the full pixel `offset` pixels past its block's centre along +AXIS.
void reduced_limits(ivec2 reduced, float offset, out float plus, out float minus) {
    ivec2 size = ivec2((u_image_size_px + GUIDE_SCALE - 1) / GUIDE_SCALE);
    reduced = clamp(reduced, ivec2(0), size - 1);
    float code = texelFetch(u_guide_limits, ivec2(reduced.x >> 2, reduced.y), 0)[reduced.x & 3];
    float code_plus = floor(code / 4096.0);
    float code_minus = code - code_plus * 4096.0;
    float scale = float(GUIDE_SCALE) / 8.0;
    plus = code_plus >= 4095.0 ? 3e4 : code_plus * scale - offset;
    minus = code_minus >= 4095.0 ? 3e4 : code_minus * scale + offset;
}

// Two limits' blend by `f`, or the nearer one's where either is no limit (the ends of a crease).
float blend_limits(float a, float b, float f) {
    return max(a, b) >= 3e4 ? (f < 0.5 ? a : b) : mix(a, b, f);
}

// g_limit_plus / g_limit_minus from the reduced limits: along AXIS the lane's own block, its
// offset from the block's centre taken off; across AXIS blended between the two nearest
// reduced rows (AXIS 0) or columns (AXIS 1), so a slanted crease does not step every block.
void guide_limits_scaled(ivec2 texel) {
    for (int i = 0; i < 4; ++i) {
        ivec2 pixel = ivec2(4 * texel.x + i, texel.y);
        int along = AXIS == 0 ? pixel.x : pixel.y;
        float across = (float(AXIS == 0 ? pixel.y : pixel.x) + 0.5) / float(GUIDE_SCALE) - 0.5;
        float offset = float(along - (along / GUIDE_SCALE) * GUIDE_SCALE)
                       + 0.5 - 0.5 * float(GUIDE_SCALE);
        int first = int(floor(across));
        float f = across - float(first);
        ivec2 a = AXIS == 0 ? ivec2(along / GUIDE_SCALE, first) : ivec2(first, along / GUIDE_SCALE);
        ivec2 b = a + (AXIS == 0 ? ivec2(0, 1) : ivec2(1, 0));
        float plus_a;
        float minus_a;
        float plus_b;
        float minus_b;
        reduced_limits(a, offset, plus_a, minus_a);
        reduced_limits(b, offset, plus_b, minus_b);
        g_limit_plus[i] = blend_limits(plus_a, plus_b, f);
        g_limit_minus[i] = blend_limits(minus_a, minus_b, f);
    }
}
#endif

void main() {
    ivec2 texel = ivec2(gl_FragCoord.xy);
    vec4 zc = fetch_packed(u_packed_depth, texel);
    bvec4 surface = greaterThan(zc, vec4(0.0));
    if (!any(surface)) {
        out_packed_depth = vec4(0.0);
        return;
    }
    vec4 z = mix(vec4(1.0), zc, surface);  // background lanes get harmless values, reach 0
#if KERNEL_SIZE == KERNEL_SIZE_PROJECTED_RADIUS
    vec4 sigma = u_kernel_scale * (u_particle_radius * u_px_per_unit / z);
#else
    // Thesis eq 25, read as a continuous decline (see smooth_depth.frag.glsl).
    vec4 sigma = u_falloff_sigma_px - max(z - u_falloff_depth, 0.0) * u_falloff_rate / 3.0;
#endif
    sigma *= u_sigma_scale;
    int stride;
    vec4 reach = kernel_reach(texel, sigma, surface, stride);
    sigma = max(min(sigma, reach / 3.0), 1e-3);
    g_center = zc;
    g_reach = mix(vec4(0.0), reach, surface);
    gaussian_start(sigma);
#if FILTER == FILTER_NARROW_RANGE
    g_sum = inverse_depth(z);
#else
    g_sum = zc;
#endif
    g_weight_sum = vec4(1.0);
#if FILTER == FILTER_NARROW_RANGE
    g_upper = zc + u_nr_threshold;
    g_lower = zc - u_nr_threshold;
    g_lower_clamp = zc - u_nr_clamp;
#if CREASE_TEST
    g_run_start = vec4(-1.0);
    g_crease = bvec4(false);
    g_radius_px = u_particle_radius * u_px_per_unit / z;
#endif
#endif
    int radius = int(max(max(g_reach.x, g_reach.y), max(g_reach.z, g_reach.w)));

#if IMAGE_BORDER || NORMAL_GUIDE
    start_image_border(texel);
#endif
    int dense = min(radius, u_kernel_max_px);
#if NORMAL_GUIDE && GUIDE_LIMITS
#if GUIDE_SCALE > 1
    guide_limits_scaled(texel);
#else
    vec4 limits = fetch_packed(u_guide_limits, texel);
    float limit_scale = 1.0 / 8.0;
    vec4 code_plus = floor(limits / 4096.0);
    g_limit_plus = code_plus * limit_scale;
    g_limit_minus = (limits - code_plus * 4096.0) * limit_scale;
#endif
    g_guide_on = vec4(u_guide_on);
    g_limit_plus = mix(vec4(3e4), g_limit_plus, g_guide_on);
    g_limit_minus = mix(vec4(3e4), g_limit_minus, g_guide_on);
    g_inverse_centre = inverse_depth(g_center);
    walk_packed_taps(u_packed_depth, u_packed_depth, texel, zc, zc, dense);
#elif NORMAL_GUIDE
    vec4 centre_normal = fetch_packed(u_guide_normals, texel);
    guide_normal_decode(centre_normal, g_normal_x, g_normal_y, g_normal_z);
    vec4 centre_norm = inversesqrt(max(g_normal_x * g_normal_x + g_normal_y * g_normal_y
                                       + g_normal_z * g_normal_z, vec4(1e-6)));
    g_normal_x *= centre_norm;
    g_normal_y *= centre_norm;
    g_normal_z *= centre_norm;
    g_guide_on = mix(vec4(u_guide_on), vec4(0.0), lessThan(centre_normal, vec4(0.0)));
    guide_start(texel);
    walk_packed_taps(u_packed_depth, u_guide_normals, texel, zc, centre_normal, dense);
#else
    walk_packed_taps(u_packed_depth, u_packed_depth, texel, zc, zc, dense);
#endif
    // every pixel out to the cap (along rows, whole texels: to the next multiple of 4), then
    // the spread taps (close-ups; kernel_reach)
    int dense_end = AXIS == 0 ? (dense + 3) / 4 * 4 : dense;
    if (radius > dense_end) {
        gaussian_spread(sigma, float(dense_end), float(stride));
#if NORMAL_GUIDE && !GUIDE_LIMITS
        walk_strided_valued_taps(u_packed_depth, u_guide_normals, texel, dense_end + stride,
                                 radius, stride);
#else
        walk_strided_taps(u_packed_depth, texel, dense_end + stride, radius, stride);
#endif
    }
    vec4 smoothed = g_sum / g_weight_sum;
#if IMAGE_BORDER || NORMAL_GUIDE
    smoothed = image_border_fit(smoothed);
#endif
#if FILTER == FILTER_NARROW_RANGE
    smoothed = 1.0 / smoothed;
#endif
    out_packed_depth = mix(vec4(0.0), smoothed, surface);
}
