"""Numpy reference of the gap pass (shaders/gaps/close_gaps.frag.glsl), written from the rule
in the shader's header, without its tile bounds (which must not change the result): per pixel
and direction, walk both ways to the first nearer surface within GAP_MAX_PX steps (reached by a
jump, not a slope), check the span and the depth agreement, count enclosing directions, fill
from the shortest one."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
STEPS = ((1, 0), (0, 1), (1, 1), (1, -1))  # (x, y), the shader's order


def close_gaps_reference(
    depth: npt.NDArray[np.floating],
    *,
    focal_px: float,
    particle_radius: float,
    gap_radii: float,
    edge_jump: float,
    max_px: int = 16,
    temperature: npt.NDArray[np.floating] | None = None,
) -> tuple[F64, npt.NDArray[np.bool_], F64 | None]:
    """The closed depth (rows as given; 0 = background), which pixels changed, and with a
    kelvin image the kelvin filled alike (None without)."""
    z = np.asarray(depth, np.float64)
    height, width = z.shape
    tolerance = gap_radii * particle_radius
    limit_px = tolerance * focal_px
    padded = np.pad(z, max_px)  # 0 outside the image, as fetch_depth
    kelvin = np.zeros_like(z) if temperature is None else np.asarray(temperature, np.float64)
    padded_kelvin = np.pad(kelvin, max_px)
    zc = z

    def nearer(q: F64) -> npt.NDArray[np.bool_]:
        return (q > 0.0) & ((zc <= 0.0) | (q < zc - edge_jump))

    def first_nearer(dx: int, dy: int) -> tuple[npt.NDArray[np.intp], F64, F64]:
        """Step and depth of the first nearer pixel, when it is a jump from the pixel before
        it (0 and 0 where none is, or where the walk climbs a slope onto a nearer surface), and
        its kelvin."""
        k_hit = np.zeros((height, width), np.intp)
        z_hit = np.zeros((height, width))
        t_hit = np.zeros((height, width))
        walking = np.ones((height, width), bool)
        previous = zc.copy()
        for k in range(1, max_px + 1):
            ys = max_px + k * dy
            xs = max_px + k * dx
            q = padded[ys : ys + height, xs : xs + width]
            arrived = walking & nearer(q)
            jump = (previous <= 0.0) | (q < previous - edge_jump)
            hit = arrived & jump
            k_hit[hit] = k
            z_hit[hit] = q[hit]
            t_hit[hit] = padded_kelvin[ys : ys + height, xs : xs + width][hit]
            walking &= ~arrived
            previous = q
        return k_hit, z_hit, t_hit

    enclosing = np.zeros((height, width), np.intp)
    best = np.full((height, width), np.inf)
    fill = zc.copy()
    fill_kelvin = kelvin.copy()
    for dx, dy in STEPS:
        # Rows here are the image's rows; the shader's y runs the other way, which only swaps
        # which diagonal is which: the set of four directions is the same.
        ka, za, ta = first_nearer(dx, dy)
        kb, zb, tb = first_nearer(-dx, -dy)
        length = 1.0 if dx == 0 or dy == 0 else np.sqrt(2.0)
        found = (ka > 0) & (kb > 0) & (ka + kb <= max_px)
        span = (ka + kb) * length
        zmin = np.where(found, np.minimum(za, zb), 1.0)
        ok = found & (span <= limit_px / zmin) & (np.abs(za - zb) <= tolerance)
        enclosing += ok
        better = ok & (span < best)
        best = np.where(better, span, best)
        frac = np.where(found, ka / np.maximum(ka + kb, 1), 0.0)
        fill = np.where(better, za + (zb - za) * frac, fill)
        fill_kelvin = np.where(better, ta + (tb - ta) * frac, fill_kelvin)
    need = np.where(zc > 0.0, 1, 2)
    changed = enclosing >= need
    filled_kelvin = None if temperature is None else np.where(changed, fill_kelvin, kelvin)
    return np.where(changed, fill, zc), changed, filled_kelvin
