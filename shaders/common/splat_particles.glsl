// Vertex pulling for the splat (passes/splat.py, passes/particle_buffers.py): the vertex stage
// reads its particle from storage buffers, so a particle is uploaded once (not once per quad
// corner) and the device prepare pass (splat/particles_to_view.comp.glsl) can write it in place.
//
// Quad q is drawn from the vertices 4q .. 4q + 3 (the index buffer holds 4q + {0, 1, 2, 2, 1, 3},
// so gl_VertexID is that value); its particle is splat_ids[q] when u_use_ids (a subset chosen by
// the occlusion culling) and q otherwise. A sphere is (view-space centre, radius): w > 0 belongs
// to the bulk, w < 0 to the exact droplets (|w| is the radius), w = 0 was culled; a draw shows
// the particles whose sign is u_class. Ellipsoids carry their world semi-axes, rotated to view
// space here with u_view_rotation.

layout(std430, binding = 0) readonly buffer SplatSpheres { vec4 splat_spheres[]; };
layout(std430, binding = 1) readonly buffer SplatIds { uint splat_ids[]; };
layout(std430, binding = 2) readonly buffer SplatTemperatures { float splat_temperatures[]; };
layout(std430, binding = 3) readonly buffer SplatAxes { float splat_axes[]; };  // 9 per particle, row-major 3x3, columns = semi-axes
layout(std430, binding = 8) readonly buffer SplatFlags { uint splat_flags[]; };  // device culling
layout(std430, binding = 25) readonly buffer SplatPeaks { float splat_peaks[]; };

uniform bool u_use_ids;
uniform float u_class;           // 1: bulk (w > 0), -1: droplets (w < 0)
uniform bool u_has_temperature;  // splat_temperatures is bound
uniform bool u_has_peak;         // splat_peaks is bound (the frame carries peak temperatures)
uniform mat3 u_view_rotation;    // world -> view (ellipsoid axes)
uniform uint u_flag_mask;        // 0: every particle of the class; else those with one of these
                                 // device-culling flags (splat/occlusion_cull.comp.glsl)

// Outside the clip volume: every triangle of a culled quad is discarded before rasterising.
const vec4 SPLAT_CULLED = vec4(2.0, 2.0, 2.0, 1.0);

uint splat_particle() {
    uint quad = uint(gl_VertexID) >> 2;
    return u_use_ids ? splat_ids[quad] : quad;
}

vec2 splat_corner() {
    int v = gl_VertexID & 3;
    return vec2((v & 1) != 0 ? 1.0 : -1.0, (v & 2) != 0 ? 1.0 : -1.0);
}

// The particle's sphere (view-space centre, radius >= 0) and whether this draw shows it.
bool splat_sphere(uint particle, out vec4 sphere) {
    vec4 s = splat_spheres[particle];
    sphere = vec4(s.xyz, abs(s.w));
    if (u_flag_mask != 0u && (splat_flags[particle] & u_flag_mask) == 0u) {
        return false;
    }
    return u_class * s.w > 0.0;
}

float splat_temperature(uint particle) {
    return u_has_temperature ? splat_temperatures[particle] : 0.0;
}

// (kelvin, peak kelvin) of the particle; the peak is 0 when the frame has none.
vec2 splat_kelvin(uint particle) {
    return vec2(splat_temperature(particle), u_has_peak ? splat_peaks[particle] : 0.0);
}

// Semi-axis k (a column of A) of an ellipsoid, in view space.
vec3 splat_axis(uint particle, int k) {
    uint base = particle * 9u + uint(k);
    return u_view_rotation * vec3(splat_axes[base], splat_axes[base + 3u], splat_axes[base + 6u]);
}
