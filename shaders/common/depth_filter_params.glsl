// Parameters of the depth filters (smooth/smooth_depth*.frag.glsl), set by passes/smooth.py from
// [quality]; which of them a filter reads depends on its FILTER and KERNEL_SIZE defines.

uniform float u_particle_radius;   // scene units
uniform float u_px_per_unit;       // (H / 2) / tan(fov_y / 2)
uniform float u_kernel_scale;
uniform int u_kernel_min_px;
uniform int u_kernel_max_px;
uniform int u_kernel_max_stride;   // separable taps up to this many pixels apart (close-ups)
uniform float u_range_sigma;       // bilateral: sigma of the depth difference, scene units
uniform float u_nr_threshold;      // narrow range: lambda * r, scene units
uniform float u_nr_clamp;          // narrow range: mu * r, scene units
uniform float u_falloff_sigma_px;  // depth_falloff (eq 25): sigma (pixels) up to falloff_depth
uniform float u_falloff_depth;     // depth_falloff: eye depth where the decline starts, scene units
uniform float u_falloff_rate;      // depth_falloff: kernel pixels lost per scene unit beyond it
