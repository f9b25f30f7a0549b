// Surface detail from an image, tiled in world space on the same axis planes as the grooves:
// on plane k the tile's u runs along world axis k+1, v along k+2 (x: y, z; y: z, x; z: x, y),
// blended by detail_plane_weights. The texels hold the height's slope per tile (taken on the
// host), so a level of the mip chain is the mean slope of the texels it covers; the level is
// the pixel's footprint in texels. The eye's position in tiles (modulo 1) comes from the host
// in float64, so the tiles stay put at 1e5 scene units. Included by detail/surface_detail.glsl
// after its uniforms (u_detail_pixel_angle).

uniform sampler2D u_detail_image;  // d height / du, d height / dv (per tile, / slope scale),
                                   // height, roughness
uniform float u_detail_image_slope_scale;
uniform vec3 u_detail_image_offset;    // the eye's world position in tiles, modulo 1
uniform float u_detail_image_size;     // a tile's side, scene units
uniform float u_detail_image_depth;    // height of image value 1, scene units
uniform float u_detail_image_roughness;
uniform float u_detail_image_texels;   // texels along the tile's longer side

// Planes weighing less are not read (a slope error under 0.1 % of the detail's; a face mostly
// reads one plane, so this saves most lookups).
const float DETAIL_IMAGE_MIN_WEIGHT = 1e-3;

// The mip level whose texels are a pixel's footprint on the surface (widened edge-on).
float detail_image_lod(vec3 n, vec3 position) {
    float distance = length(position);
    float nv = max(abs(dot(n, position)) / max(distance, 1e-30), 0.25);
    float footprint = distance * u_detail_pixel_angle / nv;
    return log2(max(footprint * u_detail_image_texels / u_detail_image_size, 1e-30));
}

vec4 detail_image_texel(int k, vec3 position, float lod) {
    vec3 p = position / u_detail_image_size + u_detail_image_offset;
    return textureLod(u_detail_image, vec2(p[(k + 1) % 3], p[(k + 2) % 3]), lod);
}

// The image's height slope at eye-relative world `position` (d height / d world, per axis).
vec3 detail_image_slope(vec3 weights, vec3 n, vec3 position) {
    float lod = detail_image_lod(n, position);
    vec3 slope = vec3(0.0);
    for (int k = 0; k < 3; ++k) {
        if (weights[k] < DETAIL_IMAGE_MIN_WEIGHT) {
            continue;
        }
        vec2 g = detail_image_texel(k, position, lod).xy * weights[k];
        slope[(k + 1) % 3] += g.x;
        slope[(k + 2) % 3] += g.y;
    }
    return slope * (u_detail_image_slope_scale * u_detail_image_depth / u_detail_image_size);
}

// Roughness moved by u_detail_image_roughness x (2 g - 1), g the roughness map.
float detail_image_roughness(float roughness, vec3 weights, vec3 n, vec3 position) {
    float lod = detail_image_lod(n, position);
    float g = 0.0;
    for (int k = 0; k < 3; ++k) {
        if (weights[k] >= DETAIL_IMAGE_MIN_WEIGHT) {
            g += weights[k] * detail_image_texel(k, position, lod).w;
        }
    }
    return clamp(roughness + u_detail_image_roughness * (2.0 * g - 1.0), 0.0, 1.0);
}
