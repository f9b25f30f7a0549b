#version 330 core
// Surface detail on the normals: each surface pixel's world normal tilted by the brushed
// pattern fixed in world space (detail/surface_detail.glsl); depth passes through, and pixels
// without a surface stay as they are. The shade pass and the N AOV both read the result.

#include "common/depth_image.glsl"
#include "detail/surface_detail.glsl"

uniform sampler2D u_normal_depth;   // world normal xyz, eye depth w (0 = no surface)
uniform vec2 u_tan_half_fov;
uniform mat3 u_view_to_world;

layout(location = 0) out vec4 out_normal_depth;

void main() {
    ivec2 pixel = ivec2(gl_FragCoord.xy);
    vec4 normal_depth = texelFetch(u_normal_depth, pixel, 0);
    if (normal_depth.w <= 0.0) {
        out_normal_depth = normal_depth;
        return;
    }
    ivec2 size = textureSize(u_normal_depth, 0);
    vec3 position = u_view_to_world * view_position(pixel, size, u_tan_half_fov, normal_depth.w);
    vec3 n = detail_normal(normalize(normal_depth.xyz), position);
    out_normal_depth = vec4(n, normal_depth.w);
}
