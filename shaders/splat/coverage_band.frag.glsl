#version 400 core
// The pixels whose sub-pixel coverage the shade pass reads (passes/coverage_band.py): a pixel
// without a surface next to one with a surface (it shows that surface, blended by coverage),
// and a pixel with a surface next to one without (its alpha is its coverage); 8-neighbours, as
// shade_pbr.frag.glsl's nearest_neighbour_surface (neighbours outside the image left out) and
// next_to_background (clamped to the image) look at them, here in four gathers (5.7 -> 2.9 ms
// against nine fetches on the 100k ball at 1280x720 on llvmpipe, the same mask). Everywhere
// else the shade pass ignores the coverage (1 inside a surface, background elsewhere), so the
// coverage pass rejects its fragments there before any work: the band goes out as depth (1 in
// the band, 0 elsewhere) into the depth buffer the coverage draws test against (depth less
// than that: every quad's fragment passes in the band and none outside). Colour: the coverage
// target's start, 1 inside a surface (the shade pass then needs no neighbour test there), 0
// elsewhere.

uniform sampler2D u_depth;  // the splat's eye depth, 0 = no surface

layout(location = 0) out float out_coverage;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec2 texel = 1.0 / vec2(textureSize(u_depth, 0));
    // The 3 x 3 around p as four 2 x 2 gathers at p's corners; outside the image the texture
    // clamps to its edge, which gives a pixel with surface the clamped neighbours it tests and
    // one without only itself and its neighbours inside again (no surface added).
    vec2 corner = vec2(p) * texel;
    vec4 a = textureGather(u_depth, corner);
    vec4 b = textureGather(u_depth, corner + vec2(texel.x, 0.0));
    vec4 c = textureGather(u_depth, corner + vec2(0.0, texel.y));
    vec4 d = textureGather(u_depth, corner + texel);
    bool surface = texelFetch(u_depth, p, 0).r > 0.0;
    bvec4 open_a = lessThanEqual(a, vec4(0.0));
    bvec4 open_b = lessThanEqual(b, vec4(0.0));
    bvec4 open_c = lessThanEqual(c, vec4(0.0));
    bvec4 open_d = lessThanEqual(d, vec4(0.0));
    bool band = surface ? any(open_a) || any(open_b) || any(open_c) || any(open_d)
                        : !(all(open_a) && all(open_b) && all(open_c) && all(open_d));
    gl_FragDepth = band ? 1.0 : 0.0;
    out_coverage = surface && !band ? 1.0 : 0.0;
}
