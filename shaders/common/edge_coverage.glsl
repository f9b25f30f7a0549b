// The share of a square pixel (side 1) on the inner side of a straight edge at signed distance
// s from the pixel centre (s > 0: the centre is inside), whose normal in the image is n
// (|n| = 1): the convolution of two boxes of widths a = max(|n.x|, |n.y|) and
// b = min(|n.x|, |n.y|) evaluated at s, exact for any orientation: linear (0.5 + s / a) for
// |s| <= (a - b) / 2, quadratic corners up to |s| = (a + b) / 2, then 0 or 1.
float edge_coverage(float s, vec2 n) {
    vec2 m = abs(n);
    float a = max(m.x, m.y);
    float b = min(m.x, m.y);
    float inner = 0.5 * (a - b);
    float outer = 0.5 * (a + b);
    float d = abs(s);
    float share;
    if (d >= outer) {
        share = 1.0;
    } else if (d <= inner) {
        share = 0.5 + d / max(a, 1e-6);
    } else {
        share = 1.0 - (outer - d) * (outer - d) / max(2.0 * a * b, 1e-12);
    }
    return s >= 0.0 ? share : 1.0 - share;
}
