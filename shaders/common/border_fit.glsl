// The end of a 1-D kernel at an image edge (smooth/image_border_taps.glsl, the temperature
// blur): where taps past the image's end left the kernel one-sided, the weighted mean of the
// values taken lies off any slope by the slope times the taps' mean offset. The intercept at
// the pixel of the weighted least-squares line v = a + b k through the same samples does not.
// Four lanes at once; `k_sum`, `kk_sum`, `kd_sum` are the sums of w k, w k^2 and
// w k (v - centre) over the samples taken (the centre itself at k = 0 in `weight_sum` only).
// The variance floor keeps a lone near sample finite; the result is kept within [low, high];
// lanes not `one_sided` keep `mean` exactly.
uniform ivec2 u_image_size_px;  // the unpacked image (the packed texture's last texel may pad)

// The pixels between each of a packed texel's four lanes and the image's end along +AXIS
// (`ahead`) and -AXIS (`behind`); the including shader defines AXIS (0: rows, 1: columns).
void image_end_room(ivec2 texel, out vec4 ahead, out vec4 behind) {
#if AXIS == 0
    behind = vec4(float(4 * texel.x)) + vec4(0.0, 1.0, 2.0, 3.0);
    ahead = vec4(float(u_image_size_px.x - 1)) - behind;
#else
    behind = vec4(float(texel.y));
    ahead = vec4(float(u_image_size_px.y - 1)) - behind;
#endif
}

vec4 border_line_fit(vec4 mean, vec4 centre, vec4 weight_sum, vec4 k_sum, vec4 kk_sum,
                     vec4 kd_sum, vec4 low, vec4 high, bvec4 one_sided) {
    vec4 k_mean = k_sum / weight_sum;
    vec4 variance = kk_sum / weight_sum - k_mean * k_mean;
    vec4 covariance = kd_sum / weight_sum - k_mean * (mean - centre);
    vec4 slope = covariance / max(variance, 1e-6);
    vec4 fit = clamp(mean - slope * k_mean, low, high);
    return mix(mean, fit, one_sided);
}
