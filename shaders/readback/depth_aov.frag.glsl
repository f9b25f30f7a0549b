#version 330 core
// The Z AOV as the frame contract has it (frame_output.py): eye depth where there is a surface,
// +inf where there is none. The normal + depth target keeps 0 for "no surface" (every pass tests
// depth > 0); this one-channel copy lets the read-back hand the driver's bytes over as they are,
// with no per-pixel work on the host.

uniform sampler2D u_normal_depth;  // xyz = world normal, w = eye depth, 0 = no surface

layout(location = 0) out float out_depth;

void main() {
    float depth = texelFetch(u_normal_depth, ivec2(gl_FragCoord.xy), 0).w;
    out_depth = depth > 0.0 ? depth : uintBitsToFloat(0x7F800000u);  // +inf
}
