"""Ray-traced truth for shadows (tests/test_shadows.py, benchmarks/bench_shadows.py): numpy only;
the product never imports it.

`occluded`: does the segment from each point to a point light hit any particle sphere?
`visible_fraction`: the fraction of a sphere light's disc (as seen from each point) whose rays
reach the point, by quadrature over the disc. `penumbra_edges`: the analytic penumbra of a
sphere occluder under a sphere light straight above it, by similar triangles.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def occluded(
    points: F64, light: F64, centres: F64, radius: float, chunk: int = 2048
) -> npt.NDArray[np.bool_]:
    """(N,) whether the segment points[i] -> light (one point, or one per point) meets any
    sphere (centres, radius)."""
    out = np.zeros(points.shape[0], dtype=bool)
    lights = np.broadcast_to(light, points.shape)
    for start in range(0, points.shape[0], chunk):
        p = points[start : start + chunk]
        seg = lights[start : start + chunk] - p
        length = np.linalg.norm(seg, axis=1)
        d = seg / length[:, None]
        oc = centres[None, :, :] - p[:, None, :]  # (n, m, 3)
        b = np.einsum("nmk,nk->nm", oc, d)
        perp2 = np.einsum("nmk,nmk->nm", oc, oc) - b * b
        hit = (perp2 <= radius * radius) & (b > 0.0) & (b < length[:, None])
        out[start : start + chunk] = hit.any(axis=1)
    return out


def disc_samples(count: int) -> F64:
    """`count` points of a Vogel spiral over the unit disc (equal areas)."""
    k = np.arange(count) + 0.5
    r = np.sqrt(k / count)
    a = k * 2.399963229728653
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def visible_fraction(
    points: F64, light: F64, light_radius: float, centres: F64, radius: float, samples: int = 256
) -> F64:
    """(N,) fraction of the sphere light's disc, seen from each point, that the point sees."""
    disc = disc_samples(samples)
    out = np.empty(points.shape[0])
    for i, p in enumerate(points):
        axis = light - p
        axis /= np.linalg.norm(axis)
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(axis, helper)
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        targets = light + light_radius * (disc[:, :1] * u + disc[:, 1:] * v)
        out[i] = 1.0 - occluded(targets, p, centres, radius).mean()
    return out


def penumbra_edges(
    light_height: float, light_radius: float, ball_height: float, ball_radius: float, plane: float
) -> tuple[float, float]:
    """(umbra edge, outer penumbra edge) radii on the plane y = `plane` for a sphere light
    centred at height `light_height` straight above a sphere occluder (similar triangles in the
    vertical cross-section: the external and internal common tangents of the two circles)."""
    a, b, big_h, h = light_radius, ball_radius, light_height, ball_height
    gap = big_h - h
    # Internal tangents cross the axis where the distances to the centres are in ratio a : b.
    cross_y = h + gap * b / (a + b)
    sin_out = b / (cross_y - h)
    outer = (cross_y - plane) * sin_out / np.sqrt(1.0 - sin_out**2)
    if a < b:  # external tangents meet above the light: the umbra widens downwards
        apex = big_h + gap * a / (b - a)
        sin_in = b / (apex - h)
        inner = (apex - plane) * sin_in / np.sqrt(1.0 - sin_in**2)
    elif a > b:  # they meet below the occluder: the umbra narrows down to that apex
        apex = h - gap * b / (a - b)
        sin_in = b / (h - apex)
        inner = max(plane - apex, 0.0) * sin_in / np.sqrt(1.0 - sin_in**2)
    else:  # a cylinder
        inner = b
    return float(inner), float(outer)
