// Irradiance from 9 spherical-harmonic radiance coefficients (thesis eq 40-49; Ramamoorthi &
// Hanrahan 2001, eq 13). Coefficient order: L00, L1-1, L10, L11, L2-2, L2-1, L20, L21, L22, in the
// frame where (x, y, z) are the components of the (environment-frame) normal. Note L22 goes with
// c1 (a common bug uses c3).

vec3 sh9_irradiance(vec3 sh[9], vec3 n) {
    const float c1 = 0.429043;
    const float c2 = 0.511664;
    const float c3 = 0.743125;
    const float c4 = 0.886227;
    const float c5 = 0.247708;
    float x = n.x;
    float y = n.y;
    float z = n.z;
    return c1 * sh[8] * (x * x - y * y) + c3 * sh[6] * z * z + c4 * sh[0] - c5 * sh[6]
        + 2.0 * c1 * (sh[4] * x * y + sh[7] * x * z + sh[5] * y * z)
        + 2.0 * c2 * (sh[3] * x + sh[1] * y + sh[2] * z);
}
