#version 330 core
// Reference mesh (benchmark only): view-space vertices (float64 eye subtraction on the CPU),
// world normals passed through for the normal AOV.
uniform mat4 u_projection;
in vec3 in_view_position;
in vec3 in_world_normal;
out vec3 v_view_position;
out vec3 v_world_normal;
void main() {
    v_view_position = in_view_position;
    v_world_normal = in_world_normal;
    gl_Position = u_projection * vec4(in_view_position, 1.0);
}
