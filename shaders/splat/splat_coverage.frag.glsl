#version 430 core
// Sub-pixel coverage of a pixel by a sphere's silhouette (silhouette anti-aliasing): the
// angular distance of the pixel's centre ray from the silhouette cone, in pixels (s > 0 inside),
// and the share of a square pixel on the inner side of a straight edge at that distance whose
// normal in the image runs towards the projected centre (common/edge_coverage.glsl). The pass draws every splatted
// sphere with blending MAX and no depth test, so a pixel gets the coverage of the sphere that
// covers it most: the union's coverage wherever one sphere forms the edge.

#include "common/edge_coverage.glsl"

// The band (coverage_band.frag.glsl) is the target's depth buffer: the depth test rejects the
// fragments outside it before this shader runs (on llvmpipe ~98 % of the quads' fragments on
// the 100k ball; a texture fetch and a discard each, before).
layout(early_fragment_tests) in;

in vec3 v_view_position;
flat in vec4 v_sphere;

uniform float u_near;
uniform float u_focal_px;   // pixels per unit at eye depth 1 (focal length in pixels)

layout(location = 0) out float out_coverage;

void main() {
    vec3 direction = normalize(v_view_position);
    vec3 center = v_sphere.xyz;
    float radius = v_sphere.w;
    float along = dot(direction, center);
    if (along <= 0.0) {
        discard;
    }
    vec3 perpendicular = center - along * direction;
    float miss = length(perpendicular);  // distance from the ray to the centre
    float distance = length(center);
    float angle = atan(miss, along);
    float silhouette = asin(min(radius / distance, 1.0));
    // A step of one pixel turns the ray by about cos(a) / focal at angle a off the view axis.
    float s = (silhouette - angle) * u_focal_px / max(-direction.z, 1e-3);
    vec2 edge_normal = length(perpendicular.xy) > 0.0 ? normalize(perpendicular.xy) : vec2(1.0, 0.0);
    float coverage = edge_coverage(s, edge_normal);
    if (coverage <= 0.0) {
        discard;
    }
    float discriminant = radius * radius - miss * miss;
    if (discriminant >= 0.0 && -((along - sqrt(discriminant)) * direction.z) < u_near) {
        discard;  // the front surface is cut by the near plane here, as in the splat
    }
    out_coverage = coverage;
}
