"""Plain numpy/python implementations of the depth filters in `smooth_depth.frag.glsl`.

Written from the equations, pixel by pixel, for small images only. They mirror the shader's
documented rules (kernel size from the projected radius, background never read, narrow-range
drop/clamp/extend with mirrored drops over inverse depths, one-sided with a line or plane fit
past the image's ends) so the GPU result can be compared value by value.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from sphrender.server.scene import QualityConfig

F32 = npt.NDArray[np.float32]


def _wanted_sigma(
    zc: float, radius: float, px_per_unit: float, q: QualityConfig, scale: float = 1.0
) -> float:
    """The kernel's sigma in pixels before any cap, in the shader's float32 maths (times
    `scale`: the separable filter's u_sigma_scale, quality.destreak on its last light pass)."""
    if q.kernel_size == "depth_falloff":
        beyond = max(np.float32(zc) - np.float32(q.falloff_depth), np.float32(0.0))
        decline = beyond * np.float32(q.falloff_rate) / np.float32(3)
        sigma32 = np.float32(q.falloff_sigma_px) - decline
    else:
        r_px = np.float32(radius) * np.float32(px_per_unit) / np.float32(zc)
        sigma32 = np.float32(q.kernel_scale) * r_px
    return float(sigma32 * np.float32(scale))


def _clamped_reach(sigma: float, q: QualityConfig, limit: float) -> float:
    return float(np.clip(np.ceil(np.float32(3.0) * np.float32(sigma)), q.kernel_min_px, limit))


def kernel(zc: float, radius: float, px_per_unit: float, q: QualityConfig) -> tuple[int, float]:
    """(reach in pixels, sigma in pixels) of the 2-D kernel, exactly as the shader derives
    them (float32 maths): 3 sigma within [kernel_min_px, kernel_max_px], sigma shrunk to
    reach / 3 when the cap bites."""
    sigma32 = _wanted_sigma(zc, radius, px_per_unit, q)
    reach = _clamped_reach(sigma32, q, q.kernel_max_px)
    return int(reach), max(min(sigma32, reach / 3.0), 1e-3)


def separable_kernels(
    depth: F32, axis: int, radius: float, px_per_unit: float, q: QualityConfig, scale: float = 1.0
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Per pixel of a 1-D pass along `axis` (0: rows, 1: columns): the reach and sigma in
    pixels and the tap spacing beyond kernel_max_px, as smooth_depth_separable.frag.glsl
    `kernel_reach` derives them for the four pixels 4x .. 4x+3 of a row it filters together:
    3 sigma within [kernel_min_px, limit], the limit kernel_max_px x kernel_max_stride, in the
    strips that passes/smooth.py gives the image-end variant kernel_max_px, elsewhere no more
    than the pixel's room to the image's ends (but at least kernel_max_px); the spacing the
    group's smallest ceil(reach / kernel_max_px), each reach then at most kernel_max_px x it."""
    from sphrender.server.engine.geometry.screen_box import packed_border_split

    h, w = depth.shape
    cap = q.kernel_max_px
    inside, _ = packed_border_split((w, h), axis, max(cap, q.kernel_min_px))
    reach = np.zeros((h, w), np.int64)
    sigma = np.ones((h, w))
    stride = np.ones((h, w), np.int64)
    for row in range(h):
        gl_y = h - 1 - row  # the shader's texel row (GL's y points up)
        for group in range(0, w, 4):
            cols = [c for c in range(group, min(group + 4, w)) if depth[row, c] > 0.0]
            plain = inside is not None and (
                inside[0] <= group // 4 < inside[0] + inside[2]
                and inside[1] <= gl_y < inside[1] + inside[3]
            )
            wanted, lanes = {}, {}
            for col in cols:
                wanted[col] = _wanted_sigma(float(depth[row, col]), radius, px_per_unit, q, scale)
                limit = float(cap)
                if plain:
                    room = min(col, w - 1 - col) if axis == 0 else min(gl_y, h - 1 - gl_y)
                    limit = min(cap * q.kernel_max_stride, max(cap, room))
                lanes[col] = _clamped_reach(wanted[col], q, limit)
            spacing = max(1, min((math.ceil(r / cap) for r in lanes.values()), default=1))
            for col in cols:
                reach_px = min(lanes[col], cap * spacing)
                reach[row, col] = int(reach_px)
                sigma[row, col] = max(min(wanted[col], reach_px / 3.0), 1e-3)
                stride[row, col] = spacing
    return reach, sigma, stride


def tap_offsets(reach: int, stride: int, q: QualityConfig, axis: int) -> list[tuple[int, float]]:
    """The 1-D kernel's offsets k = 1, 2, ... and the pixels each stands for: every pixel out
    to kernel_max_px (the packed row walk's whole texels: out to the next multiple of 4), then
    every stride-th out to the reach."""
    dense_end = min(reach, q.kernel_max_px)
    if stride > 1 and axis == 0:
        dense_end = (dense_end + 3) // 4 * 4
    dense = [(k, 1.0) for k in range(1, min(reach, dense_end) + 1)]
    return dense + [(k, float(stride)) for k in range(dense_end + stride, reach + 1, stride)]


def ambiguous_reach(zc: float, radius: float, px_per_unit: float, q: QualityConfig) -> bool:
    """True where 3 sigma of the first pass, which reads this depth, is so close to an integer
    that float rounding may change the reach (later passes read smoothed depths this cannot
    foresee; a rounding there would show as a mismatch, and has not)."""
    if q.kernel_size == "depth_falloff":
        three_sigma = 3.0 * q.falloff_sigma_px - max(zc - q.falloff_depth, 0.0) * q.falloff_rate
    else:
        three_sigma = 3.0 * q.kernel_scale * radius * px_per_unit / zc
    if q.separable:
        three_sigma *= _separable_passes(q)[0][1]
    return abs(three_sigma - round(three_sigma)) < 1e-4


def _separable_passes(q: QualityConfig) -> list[tuple[tuple[int, int], float]]:
    """The separable filter's 1-D passes: (direction, sigma scale). x then y, y then x on the
    next iteration, ...; with quality.last_pass_sigma s < 1 and two passes or more along the
    last pass's axis, that axis's last pass at s and its first at sqrt(2 - s^2) (their
    variances sum as two equal passes'); with quality.destreak one more pass across the last,
    at sigma x destreak."""
    directions = [
        direction
        for iteration in range(q.iterations)
        for direction in (((1, 0), (0, 1)) if iteration % 2 == 0 else ((0, 1), (1, 0)))
    ]
    scales = [1.0] * len(directions)
    last = directions[-1]
    along = [i for i, direction in enumerate(directions) if direction == last]
    if q.last_pass_sigma < 1.0 and len(along) >= 2:
        scales[along[0]] = math.sqrt(2.0 - q.last_pass_sigma**2)
        scales[along[-1]] = q.last_pass_sigma
    passes = list(zip(directions, scales, strict=True))
    if q.destreak > 0.0:
        passes.append(((last[1], last[0]), q.destreak))
    return passes


def _fetch(depth: F32, y: int, x: int) -> float:
    h, w = depth.shape
    if 0 <= y < h and 0 <= x < w:
        return float(depth[y, x])
    return 0.0


def _ring_offsets(k: int) -> list[tuple[int, int]]:
    """Half of the square ring at Chebyshev distance k, in the shader's order (x, y)."""
    top = [(i - k, k) for i in range(2 * k + 1)]
    right = [(k, j) for j in range(k)]
    left = [(-k, j) for j in range(1, k)]
    return top + right + left


def _pass(
    depth: F32,
    directions: list[tuple[int, int]] | None,
    radius: float,
    px_per_unit: float,
    q: QualityConfig,
    box: bool = False,
    scale: float = 1.0,
    pair_limit: float | None = None,
    crease_limit: float | None = None,
) -> F32:
    """One filter pass. `directions` = [(dx, dy)] for a 1-D pass, None for the 2-D kernel;
    `scale` multiplies a 1-D pass's sigma; `pair_limit` (scene units): the narrow range's pair
    test on this pass (None: off); `crease_limit` (radians): its crease test (None: off).
    Offsets are (x, y) in image coordinates with y pointing *up* (GL), rows stored top first."""
    h, w = depth.shape
    out = np.zeros_like(depth)
    if directions is not None:
        axis = 0 if directions[0][0] else 1
        reaches, sigmas, strides = separable_kernels(depth, axis, radius, px_per_unit, q, scale)
    for row in range(h):
        for col in range(w):
            zc = float(depth[row, col])
            if zc <= 0.0:
                continue
            if directions is None:
                reach, sigma = kernel(zc, radius, px_per_unit, q)
                taps = None
            else:
                reach, sigma = int(reaches[row, col]), float(sigmas[row, col])
                taps = tap_offsets(reach, int(strides[row, col]), q, axis)
            inv2s2 = 1.0 / (2.0 * sigma * sigma)

            def spatial(off: tuple[int, int], inv2s2: float = inv2s2) -> float:
                return 1.0 if box else math.exp(-(off[0] ** 2 + off[1] ** 2) * inv2s2)

            if q.filter == "narrow_range":
                crease = None
                if crease_limit is not None:
                    crease = Crease(crease_limit, px_per_unit, radius * px_per_unit / zc)
                out[row, col] = _narrow_range(
                    depth, row, col, directions, reach, taps, spatial, radius, q, pair_limit, crease
                )
                continue
            out[row, col] = _gaussian_or_bilateral(
                depth, row, col, directions, reach, taps, spatial, radius, q
            )
    return out


def _gaussian_or_bilateral(
    depth: F32,
    row: int,
    col: int,
    directions: list[tuple[int, int]] | None,
    reach: int,
    taps: list[tuple[int, float]] | None,
    spatial: Callable[[tuple[int, int]], float],
    radius: float,
    q: QualityConfig,
) -> float:
    """The Gaussian (eq 17-21) or bilateral (eq 22-24) weighted mean of z at one pixel over
    the surface samples in reach; where a sample lay past the image's end, the intercept of
    the weighted line (1-D) or plane (2-D) fit through the samples taken, kept within their
    range widened by its width."""
    h, w = depth.shape
    zc = float(depth[row, col])
    if directions is not None and taps is not None:
        dx, dy = directions[0]
        offsets = [((sign * k * dx, sign * k * dy), n) for k, n in taps for sign in (1, -1)]
    else:
        offsets = [
            ((x, y), 1.0)
            for y in range(-reach, reach + 1)
            for x in range(-reach, reach + 1)
            if x * x + y * y <= reach * reach and (x, y) != (0, 0)
        ]
    range_inv = 1.0 / (2.0 * (q.bilateral_depth_sigma * radius) ** 2)
    taken: list[tuple[float, float, tuple[int, int]]] = [(1.0, zc, (0, 0))]
    crossed = False
    for off, pixels in offsets:
        if not (0 <= row - off[1] < h and 0 <= col + off[0] < w):
            crossed = True
            continue
        z = _fetch(depth, row - off[1], col + off[0])
        if z <= 0.0:
            continue
        wgt = pixels * spatial(off)
        if q.filter == "bilateral":
            wgt *= math.exp(-((z - zc) ** 2) * range_inv)
        taken.append((wgt, z, off))
    weights = np.array([t[0] for t in taken])
    z_taken = np.array([t[1] for t in taken])
    mean = float((weights * z_taken).sum() / weights.sum())
    if not crossed:
        return mean
    offsets_px = np.array([t[2] for t in taken], dtype=np.float64)
    fit = _fit_intercept(weights, z_taken - zc, offsets_px, directions, mean - zc) + zc
    low, high = float(z_taken.min()), float(z_taken.max())
    return min(max(fit, 2.0 * low - high), 2.0 * high - low)


def _narrow_range(
    depth: F32,
    row: int,
    col: int,
    directions: list[tuple[int, int]] | None,
    reach: int,
    taps: list[tuple[int, float]] | None,
    spatial: Callable[[tuple[int, int]], float],
    radius: float,
    q: QualityConfig,
    pair_limit: float | None = None,
    crease: Crease | None = None,
) -> float:
    """Truong & Yuksel's narrow range at one pixel: a sample behind the centre by more than
    lambda r drops its mirror too, one in front by more is clamped to z - mu r, the range grows
    around each accepted sample, walking outwards; the samples' inverse depths are averaged. A
    sample whose mirror lies past the image's end counts alone, and then the result is the
    intercept at the pixel of the weighted line (1-D) or plane (2-D) fit through the inverse
    depths taken, kept within those the kernel can have taken. With `pair_limit`, a pair
    with both sides inside the image whose midpoint in inverse depth departs from the centre's
    by more than it (as a depth, times zc^2) is dropped (quality.narrow_range_pairs). With
    `crease` (1-D): no pair is taken past the point where the chords to a pair of surface taps
    have turned by more than its limit for a projected radius of offsets (quality.crease_angle)."""
    h, w = depth.shape
    zc = float(depth[row, col])
    thr = q.narrow_range_threshold * radius
    upper, lower = zc + thr, zc - thr
    lower_clamp = zc - q.narrow_range_clamp * radius
    taken: list[tuple[float, float, tuple[int, int]]] = [(1.0, zc, (0, 0))]  # weight, z, offset

    def outside(off: tuple[int, int]) -> bool:
        return not (0 <= row - off[1] < h and 0 <= col + off[0] < w)

    rings = taps if taps is not None else [(k, 1.0) for k in range(1, reach + 1)]
    for k, pixels in rings:
        if directions is not None:
            offsets = [(k * directions[0][0], k * directions[0][1])]
        else:
            offsets = [o for o in _ring_offsets(k) if o[0] ** 2 + o[1] ** 2 <= reach * reach]
        for off in offsets:
            mirror = (-off[0], -off[1])
            za = _fetch(depth, row - off[1], col + off[0])
            zb = _fetch(depth, row - mirror[1], col + mirror[0])
            out_a, out_b = outside(off), outside(mirror)
            valid_a, valid_b = 0.0 < za <= upper, 0.0 < zb <= upper
            use_a = not out_a and valid_a and (valid_b or out_b)
            use_b = not out_b and valid_b and (valid_a or out_a)
            if pair_limit is not None and use_a and use_b:
                mid = (0.5 * (1.0 / za + 1.0 / zb) - 1.0 / zc) * zc * zc
                use_a = use_b = abs(mid) <= pair_limit
            band = lower <= za <= upper and lower <= zb <= upper  # neither dropped nor clamped
            if crease is not None and crease.met(k, za, zb, zc, band):
                use_a = use_b = False
            for z, use, o in ((za, use_a, off), (zb, use_b, mirror)):
                if not use:
                    continue
                if z < lower:
                    z = lower_clamp
                else:
                    upper = max(upper, z + thr)
                    lower = min(lower, z - thr)
                taken.append((pixels * spatial(off), z, o))
    weights = np.array([t[0] for t in taken])
    u = 1.0 / np.array([t[1] for t in taken])  # the narrow range averages inverse depth
    offsets_px = np.array([t[2] for t in taken], dtype=np.float64)
    mean = float((weights * u).sum() / weights.sum())
    if not (weights[:, None] * offsets_px).sum(axis=0).any():
        return 1.0 / mean  # every sample paired with its mirror: the plain weighted mean
    uc = 1.0 / zc
    fit = _fit_intercept(weights, u - uc, offsets_px, directions, mean - uc) + uc
    nearest = min(lower, lower_clamp)
    u_max = 1.0 / nearest if nearest > 0.0 else math.inf
    return 1.0 / min(max(fit, 1.0 / upper), u_max)


class Crease:
    """The crease test's state along one pixel's 1-D kernel (smooth_depth_separable.frag.glsl,
    crease_met): sticky once met."""

    def __init__(self, limit: float, px_per_unit: float, radius_px: float) -> None:
        self.limit, self.px_per_unit, self.radius_px = limit, px_per_unit, radius_px
        self.run_start: float | None = None
        self.crease = False

    def met(self, k: float, za: float, zb: float, zc: float, on_surface: bool) -> bool:
        # in float32 and in the shader's form (|da - db| step > tan(L) (step^2 + da db): the
        # chords' turn passes L), so that a turn within rounding of L flips neither alone
        f = np.float32
        step = f(k) * f(zc) / f(self.px_per_unit)
        da, db = f(za) - f(zc), f(zc) - f(zb)
        excess = abs(da - db) * step - f(math.tan(self.limit)) * (step * step + da * db)
        if on_surface and excess > 0.0:
            self.run_start = k if self.run_start is None else self.run_start
            self.crease = self.crease or k - self.run_start >= self.radius_px
        else:
            self.run_start = None
        return self.crease


def _fit_intercept(
    weights: npt.NDArray[np.float64],
    d: npt.NDArray[np.float64],
    offsets: npt.NDArray[np.float64],
    directions: list[tuple[int, int]] | None,
    d_mean: float,
) -> float:
    """The weighted least-squares intercept at offset 0 of `d` over the offsets: a line along
    the 1-D pass's axis (variance floored at 1e-6 px^2), or a plane (covariance ridge-damped by
    1e-3 px^2), as the shaders compute it."""
    total = weights.sum()
    if directions is not None:
        k = offsets @ np.array(directions[0], dtype=np.float64)
        k_mean = (weights * k).sum() / total
        variance = (weights * k * k).sum() / total - k_mean**2
        covariance = (weights * k * d).sum() / total - k_mean * d_mean
        return d_mean - covariance / max(variance, 1e-6) * k_mean
    o_mean = (weights[:, None] * offsets).sum(axis=0) / total
    second = np.einsum("i,ij,ik->jk", weights, offsets, offsets) / total
    c = second - np.outer(o_mean, o_mean) + 1e-3 * np.eye(2)
    cd = (weights[:, None] * offsets * d[:, None]).sum(axis=0) / total - o_mean * d_mean
    return float(d_mean - np.linalg.solve(c, cd) @ o_mean)


def filter_depth(
    depth: F32, radius: float, px_per_unit: float, q: QualityConfig, *, box: bool = False
) -> F32:
    """The whole smoothing step: the separable passes (`_separable_passes`) or iterations x
    2-D pass."""
    image = depth.astype(np.float32)
    if not q.separable:
        for _ in range(q.iterations):
            image = _pass(image, None, radius, px_per_unit, q, box)
        return image
    limit = q.narrow_range_pairs * radius if q.narrow_range_pairs > 0.0 else None
    crease = math.radians(q.crease_angle) if q.crease_angle > 0.0 else None
    for index, (direction, scale) in enumerate(_separable_passes(q)):
        # neither test on the first pass (the raw splat)
        pair_limit = limit if index > 0 else None
        crease_limit = crease if index > 0 else None
        image = _pass(
            image, [direction], radius, px_per_unit, q, box, scale, pair_limit, crease_limit
        )
    return image


def _kelvin_at(taken: list[tuple[float, float, int]], crossed: bool) -> float:
    """The weighted mean of the (weight, kelvin, offset) samples, or where a tap fell past the
    image's end the intercept of their weighted line fit, kept within their range widened by
    its width (common/border_fit.glsl)."""
    weights = np.array([t[0] for t in taken])
    kelvin = np.array([t[1] for t in taken])
    mean = float((weights * kelvin).sum() / weights.sum())
    if not crossed:
        return mean
    offsets = np.array([[t[2], 0] for t in taken], dtype=np.float64)
    centre = kelvin[0]
    fit = _fit_intercept(weights, kelvin - centre, offsets, [(1, 0)], mean - centre) + centre
    low, high = float(kelvin.min()), float(kelvin.max())
    return min(max(fit, 2.0 * low - high), 2.0 * high - low)


def temperature_blur(
    temperature: F32,
    depth: F32,
    radius_px_at_unit_depth: float,
    sigma_radii: float,
    max_reach_px: int,
    depth_range: float,
) -> F32:
    """The depth-aware separable temperature blur (x pass, then y pass), pixel by pixel.

    Per pixel with a surface: sigma = max(sigma_radii * r_px(z), 0.5) with r_px(z) =
    radius_px_at_unit_depth / z, reach = min(ceil(3 sigma), max_reach_px), sigma shrunk to
    reach / 3 when the cap bites; a tap counts when it has a surface within depth_range of the
    centre's depth; where a tap fell past the image's end, a line fit's intercept (`_kelvin_at`).
    Pixels without a surface give 0."""
    h, w = depth.shape
    image = temperature.astype(np.float64)
    for dx, dy in ((1, 0), (0, 1)):
        out = np.zeros((h, w))
        for row in range(h):
            for col in range(w):
                zc = float(depth[row, col])
                if zc <= 0.0:
                    continue
                sigma32 = max(
                    np.float32(sigma_radii) * np.float32(radius_px_at_unit_depth) / np.float32(zc),
                    np.float32(0.5),
                )
                reach = min(int(np.ceil(np.float32(3.0) * sigma32)), max_reach_px)
                sigma = min(float(sigma32), max(reach, 1) / 3.0)
                inv = 1.0 / (2.0 * sigma * sigma)
                taken = [(1.0, float(image[row, col]), 0)]  # weight, kelvin, offset
                crossed = False
                for k in range(-reach, reach + 1):
                    if k == 0:
                        continue
                    # rows of these arrays are top first; the shader's +y is one row up
                    r, c = row - k * dy, col + k * dx
                    if not (0 <= r < h and 0 <= c < w):
                        crossed = True
                        continue
                    z = _fetch(depth, r, c)
                    if z <= 0.0 or abs(z - zc) > depth_range:
                        continue
                    taken.append((math.exp(-k * k * inv), float(image[r, c]), k))
                out[row, col] = _kelvin_at(taken, crossed)
        image = out
    return image.astype(np.float32)
