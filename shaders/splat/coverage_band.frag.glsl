#version 330 core
// The pixels whose sub-pixel coverage the shade pass reads (passes/coverage_band.py): a pixel
// without a surface next to one with a surface (it shows that surface, blended by coverage),
// and a pixel with a surface next to one without (its alpha is its coverage); 8-neighbours, as
// shade_pbr.frag.glsl's nearest_neighbour_surface (neighbours outside the image left out) and
// next_to_background (clamped to the image) look at them. Everywhere else the shade pass
// ignores the coverage (1 inside a surface, background elsewhere), so the coverage pass
// rejects its fragments there before any work: the band goes out as depth (1 in the band, 0
// elsewhere) into the depth buffer the coverage draws test against (depth less than that:
// every quad's fragment passes in the band and none outside). Colour: the coverage target's
// start, 1 inside a surface (the shade pass then needs no neighbour test there), 0 elsewhere.

uniform sampler2D u_depth;  // the splat's eye depth, 0 = no surface

layout(location = 0) out float out_coverage;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(u_depth, 0);
    bool surface = texelFetch(u_depth, p, 0).r > 0.0;
    bool band = false;
    for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
            ivec2 q = p + ivec2(dx, dy);
            if (surface) {
                band = band || texelFetch(u_depth, clamp(q, ivec2(0), size - 1), 0).r <= 0.0;
            } else if (all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, size))) {
                band = band || texelFetch(u_depth, q, 0).r > 0.0;
            }
        }
    }
    gl_FragDepth = band ? 1.0 : 0.0;
    out_coverage = surface && !band ? 1.0 : 0.0;
}
