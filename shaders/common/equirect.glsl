// Equirectangular environment lookups; convention of sphrender.server.engine.environment (and
// Mitsuba 3's envmap): +y up, u = atan2(x, -z) / 2pi, v = acos(y) / pi, texture row 0 = zenith.

vec2 equirect_uv(vec3 d) {
    // u may be negative: the textures repeat in u, and lookups use explicit LODs, so the wrap
    // needs no derivative care.
    return vec2(atan(d.x, -d.z) * (0.5 / 3.14159265358979),
                acos(clamp(d.y, -1.0, 1.0)) * (1.0 / 3.14159265358979));
}

vec3 equirect_direction(vec2 uv) {
    float phi = 2.0 * 3.14159265358979 * uv.x;
    float theta = 3.14159265358979 * uv.y;
    return vec3(sin(theta) * sin(phi), cos(theta), -sin(theta) * cos(phi));
}

// Solid angle of one level-0 texel of a W x H equirect image in direction d:
// (2 pi / W) (pi / H) sin(theta); sin(theta) is floored at half a row so poles do not give 0.
float equirect_texel_solid_angle(vec3 d, vec2 size) {
    float sin_theta = max(sqrt(max(1.0 - d.y * d.y, 0.0)), 1.5707963 / size.y);
    return (2.0 * 3.14159265358979 * 3.14159265358979) / (size.x * size.y) * sin_theta;
}
