// Shared by the field-gradient kernels of benchmarks/bench_field_gradient.py: the normals pass's
// field code (field/field_normals.glsl: the grid, field_gradient, spline_dw_over_q) with the
// normals pass's own inputs, which these kernels do not use, declared as the includer would;
// each pixel's view point and whether it needs the gradient come in one image, the gradient
// (xyz) and the sum of the terms' magnitudes (w) go out in another (zero where not needed).

uniform sampler2D u_depth;
uniform float u_edge_jump;
uniform float u_edge_jump_px;
uniform float u_focal_px;
uniform float u_particle_radius;

#include "field/field_normals.glsl"

layout(rgba32f, binding = 0) uniform readonly image2D u_points;  // view point, w = 1: needed
layout(rgba32f, binding = 1) uniform writeonly image2D u_gradient;
