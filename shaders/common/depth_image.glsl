// Access to an eye-depth image: R32F, positive eye depth along the view axis, 0 = no surface.

// Depth at pixel p, or 0 outside the image or where there is no surface.
float fetch_depth(sampler2D depth_image, ivec2 p) {
    ivec2 size = textureSize(depth_image, 0);
    if (any(lessThan(p, ivec2(0))) || any(greaterThanEqual(p, size))) {
        return 0.0;
    }
    return texelFetch(depth_image, p, 0).r;
}

// View-space position of pixel p's centre at eye depth z (camera looks down -z).
// tan_half_fov = (tan(fov_y / 2) * aspect, tan(fov_y / 2)).
vec3 view_position(ivec2 p, ivec2 size, vec2 tan_half_fov, float z) {
    vec2 ndc = (vec2(p) + 0.5) / vec2(size) * 2.0 - 1.0;
    return vec3(ndc * tan_half_fov * z, -z);
}
