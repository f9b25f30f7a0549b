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

// Goes on from offset `last` (the weights so far were those of every pixel) to taps `stride`
// pixels apart, at last + stride, last + 2 stride, ..., each standing for `stride` pixels:
// w = stride exp(-o^2 / (2 sigma^2)), its ratios growing geometrically as above.
void gaussian_spread(vec4 sigma, float last, float stride) {
    vec4 inv_two_sigma2 = 1.0 / (2.0 * sigma * sigma);
    g_gaussian_weight = stride * exp(-last * last * inv_two_sigma2);
    g_gaussian_step = exp(-(2.0 * last + stride) * stride * inv_two_sigma2);
    g_gaussian_growth = exp(-2.0 * stride * stride * inv_two_sigma2);
}
