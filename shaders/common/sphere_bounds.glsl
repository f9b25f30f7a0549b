// A sphere's silhouette rectangle in pixels, as geometry/occlusion.py sphere_bounds computes it
// on the CPU (float64): for the float32 sphere the splat draws, the inclusive pixel interval
// along one axis whose centre rays can hit it, with one pixel of margin each side. Valid only
// for spheres in front of the eye plane with some room (`has_bounds`).

bool has_bounds(double depth, double r) {
    return depth - r > 1e-6 * max(depth, 1e-300);
}

// In the plane of this axis and the view axis the sphere is a circle at (lateral, depth) of
// radius r; the lines through the eye touching it have slopes
// (a d -+ r sqrt(a^2 + d^2 - r^2)) / (d^2 - r^2) (occlusion._tangent_extent).
ivec2 pixel_interval(double lateral, double depth, double r, double tan_half, int size, ivec2 image) {
    double d2_r2 = (depth - r) * (depth + r);
    double spread = r * sqrt(lateral * lateral + d2_r2);
    double scale = 0.5 * double(size) / tan_half;
    double centre = 0.5 * double(size);
    double limit = 4.0 * double(max(image.x, image.y));  // keeps the integer casts in range
    double lo = clamp((lateral * depth - spread) / d2_r2 * scale + centre, -limit, limit);
    double hi = clamp((lateral * depth + spread) / d2_r2 * scale + centre, -limit, limit);
    return ivec2(int(ceil(lo - 0.5)) - 1, int(floor(hi - 0.5)) + 1);
}

// The rectangle (x0, y0, x1, y1) of a view-space sphere; false when it has none.
bool sphere_rectangle(vec4 sphere, dvec2 tan_half_fov, ivec2 image, out ivec4 rect) {
    dvec3 c = dvec3(sphere.xyz);
    double r = double(abs(sphere.w));
    double depth = -c.z;
    if (!has_bounds(depth, r)) {
        rect = ivec4(0);
        return false;
    }
    ivec2 x = pixel_interval(c.x, depth, r, tan_half_fov.x, image.x, image);
    ivec2 y = pixel_interval(c.y, depth, r, tan_half_fov.y, image.y, image);
    rect = ivec4(x.x, y.x, x.y, y.y);
    return true;
}
