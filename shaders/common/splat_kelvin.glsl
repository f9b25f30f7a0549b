// What a splat fragment writes into the kelvin target (passes/splat.py): the front particle's
// kelvin, and with HAS_PEAK (an RG32F target) its peak kelvin beside it. The vertex stage always
// passes both (common/splat_particles.glsl's splat_kelvin; the peak is 0 without peaks).

#define HAS_PEAK 0

#if HAS_PEAK
#define SPLAT_KELVIN vec2
#define SPLAT_KELVIN_OF(value) (value)
#else
#define SPLAT_KELVIN float
#define SPLAT_KELVIN_OF(value) (value).x
#endif
