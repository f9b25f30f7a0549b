// Low-discrepancy sampling of the GGX lobe (thesis eq 50-53, corrected per validation-data.md):
// Hammersley points (i / N, van der Corput radical inverse of i) turned into half vectors drawn
// from D(h) (n.h) (Karis 2013), not the thesis's cosine-weighted hemisphere of eq 52.

float radical_inverse_vdc(uint bits) {
    bits = (bits << 16u) | (bits >> 16u);
    bits = ((bits & 0x55555555u) << 1u) | ((bits & 0xAAAAAAAAu) >> 1u);
    bits = ((bits & 0x33333333u) << 2u) | ((bits & 0xCCCCCCCCu) >> 2u);
    bits = ((bits & 0x0F0F0F0Fu) << 4u) | ((bits & 0xF0F0F0F0u) >> 4u);
    bits = ((bits & 0x00FF00FFu) << 8u) | ((bits & 0xFF00FF00u) >> 8u);
    return float(bits) * 2.3283064365386963e-10;  // / 2^32
}

// Point i of N: ((i + 1/2) / N, radical inverse) -- eq 50 with the first coordinate centred in
// its stratum (midpoint rule), which halves the bias of the i / N form at no cost.
vec2 hammersley(int i, int count) {
    return vec2((float(i) + 0.5) / float(count), radical_inverse_vdc(uint(i)));
}

// Orthonormal basis around a unit vector (Duff et al. 2017, branchless).
void tangent_frame(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

// Half vector with pdf D(h) (n.h): cos(theta_h) = sqrt((1 - s) / (1 + (alpha^2 - 1) s)),
// phi = 2 pi t. Returns h in the tangent frame (z = n); `sin2` receives 1 - cos^2 exactly.
vec3 sample_ggx_tangent(vec2 xi, float alpha, out float sin2) {
    float a2 = alpha * alpha;
    float denom = 1.0 + (a2 - 1.0) * xi.x;
    float cos2 = (1.0 - xi.x) / denom;
    sin2 = a2 * xi.x / denom;  // = 1 - cos2, without cancellation
    float cos_t = sqrt(cos2);
    float sin_t = sqrt(sin2);
    float phi = 2.0 * 3.14159265358979 * xi.y;
    return vec3(sin_t * cos(phi), sin_t * sin(phi), cos_t);
}
