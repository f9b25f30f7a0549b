#version 430 core
// The field gradient as the blend pass computes it (field_gradient of field/field_normals.glsl:
// each invocation walks the rows of grid cells around its own point and gathers their
// centres), one invocation per pixel of the image. benchmarks/bench_field_gradient.py times it against
// field_gradient_tiled.comp.glsl.

layout(local_size_x = 8, local_size_y = 8) in;

#include "studies/field_gradient_io.glsl"

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(p, imageSize(u_points)))) {
        return;
    }
    vec4 point = imageLoad(u_points, p);
    imageStore(u_gradient, p, point.w != 0.0 ? field_gradient(point.xyz) : vec4(0.0));
}
