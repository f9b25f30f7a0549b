#version 330 core
// Reference mesh (benchmark only): world normal (interpolated vertex normal) + eye depth.
in vec3 v_view_position;
in vec3 v_world_normal;
layout(location = 0) out vec4 out_normal_depth;
void main() {
    out_normal_depth = vec4(normalize(v_world_normal), -v_view_position.z);
}
