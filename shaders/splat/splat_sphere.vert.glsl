#version 330 core
// Sphere impostors (thesis §3.1) as instanced quads, so a sprite may be any size (point sprites
// are capped at 255 px by llvmpipe). Each quad is perpendicular to the ray from the eye to the
// sphere centre and just large enough to contain the sphere's silhouette cone:
// half-size s = r d / sqrt(d^2 - r^2), d = |centre|. The CPU culls spheres that contain the eye.

in vec2 in_corner;          // per vertex: (+-1, +-1)
in vec4 in_center_radius;   // per particle, on each of its 4 corners: view-space centre (float32 after float64 subtraction), radius
in float in_temperature;    // per particle, kelvin; not bound (constant 0) when the frame has none

uniform mat4 u_projection;

out vec3 v_view_position;   // point on the quad, view space; interpolated perspective-correctly
flat out vec4 v_sphere;     // view-space centre and radius
flat out float v_temperature;

void main() {
    vec3 center = in_center_radius.xyz;
    float radius = in_center_radius.w;
    float distance = length(center);
    vec3 axis = center / distance;
    vec3 helper = abs(axis.y) < 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
    vec3 u = normalize(cross(helper, axis));
    vec3 v = cross(axis, u);
    // (d - r)(d + r) keeps precision when d is much larger than r.
    float half_size = radius * distance / sqrt(max((distance - radius) * (distance + radius), 1e-30));
    vec3 corner = center + (in_corner.x * u + in_corner.y * v) * half_size;
    v_view_position = corner;
    v_sphere = in_center_radius;
    v_temperature = in_temperature;
    gl_Position = u_projection * vec4(corner, 1.0);
}
