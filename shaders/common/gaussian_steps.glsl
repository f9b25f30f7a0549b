// Gaussian weights along a 1-D kernel by recurrence, four lanes at once:
// w_k = exp(-k^2 / (2 sigma^2)) = q^(k^2) with q = exp(-1 / (2 sigma^2)), and
// w_k = w_(k-1) q^(2k - 1): two multiplications per tap instead of an exp().
// Call gaussian_start(sigma) once, then gaussian_next() once per k = 1, 2, ... in order.

vec4 g_gaussian_weight;  // w_(k-1) before the call for k, w_k after
vec4 g_gaussian_step;    // q^(2k - 1) before the call for k
vec4 g_gaussian_growth;  // q^2

void gaussian_start(vec4 sigma) {
    vec4 q = exp(-1.0 / (2.0 * sigma * sigma));
    g_gaussian_weight = vec4(1.0);
    g_gaussian_step = q;
    g_gaussian_growth = q * q;
}

vec4 gaussian_next() {
    g_gaussian_weight *= g_gaussian_step;
    g_gaussian_step *= g_gaussian_growth;
    return g_gaussian_weight;
}
