// Packed images: RGBA32F, texel (x, y) holds pixels 4x .. 4x+3 of row y in .xyzw (see
// depth_pack.frag.glsl), so one fragment works on four horizontally adjacent pixels at once.

// Four pixels at packed texel p, or 0 outside the image.
vec4 fetch_packed(sampler2D image, ivec2 p) {
    ivec2 size = textureSize(image, 0);
    if (any(lessThan(p, ivec2(0))) || any(greaterThanEqual(p, size))) {
        return vec4(0.0);
    }
    return texelFetch(image, p, 0);
}

// Component-wise a || b.
bvec4 either(bvec4 a, bvec4 b) {
    return bvec4(ivec4(a) | ivec4(b));
}

// Component-wise a && b (GLSL has no && for bvec4).
bvec4 both(bvec4 a, bvec4 b) {
    return bvec4(ivec4(a) & ivec4(b));
}
