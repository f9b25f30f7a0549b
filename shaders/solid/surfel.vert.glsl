#version 330 core
// One flat disc per instance: a quad in its face's plane (view space, float64 eye subtraction on
// the host), half-size = the disc radius. The face normal and up to three clip planes (the
// particle's other faces) pass to the fragment shader, which cuts the quad to the disc and the
// planes: neighbouring discs then meet at the faces' crease (geometry/solid_surfels.py).
uniform mat4 u_projection;
uniform float u_disc_radius;

in vec2 in_corner;           // per vertex: the quad's corner in [-1, 1]^2
in vec3 in_center;           // per instance: view-space centre, on the face plane
in vec3 in_normal;           // view-space unit normal
in vec3 in_world_normal;
in vec4 in_clip0;            // view-space planes: keep n . x <= w
in vec4 in_clip1;
in vec4 in_clip2;
in vec2 in_temperature;  // kelvin, peak kelvin

out vec3 v_view_position;
out vec2 v_local;
flat out vec3 v_world_normal;
flat out vec4 v_clip0;
flat out vec4 v_clip1;
flat out vec4 v_clip2;
flat out vec2 v_temperature;

void main() {
    vec3 n = in_normal;
    vec3 helper = abs(n.y) < 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
    vec3 u = normalize(cross(helper, n));
    vec3 v = cross(n, u);
    vec3 corner = in_center + (in_corner.x * u + in_corner.y * v) * u_disc_radius;
    v_view_position = corner;
    v_local = in_corner;
    v_world_normal = in_world_normal;
    v_clip0 = in_clip0;
    v_clip1 = in_clip1;
    v_clip2 = in_clip2;
    v_temperature = in_temperature;
    gl_Position = u_projection * vec4(corner, 1.0);
}
