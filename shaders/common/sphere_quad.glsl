// The quad of a sphere impostor: perpendicular to the ray from the eye to the sphere centre and
// just large enough to contain the sphere's silhouette cone, half-size s = r d / sqrt(d^2 - r^2)
// with d = |centre|, plus `margin` (view units per unit of distance: pixels / focal length in
// pixels) for passes that also shade the pixels just outside the silhouette.
vec3 sphere_quad_corner(vec3 center, float radius, vec2 corner, float margin) {
    float distance = length(center);
    vec3 axis = center / distance;
    vec3 helper = abs(axis.y) < 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
    vec3 u = normalize(cross(helper, axis));
    vec3 v = cross(axis, u);
    // (d - r)(d + r) keeps precision when d is much larger than r.
    float half_size = radius * distance / sqrt(max((distance - radius) * (distance + radius), 1e-30));
    return center + (corner.x * u + corner.y * v) * (half_size + margin * distance);
}
