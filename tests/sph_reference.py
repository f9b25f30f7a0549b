"""Independent float64 reference of the SPH quantities: scipy cKDTree pairs + numpy sums.

Shares no code with `sphrender.server.engine.sph.engine` or the OpenCL kernels: the pair search is
scipy's k-d tree, the kernel is written out again from the issue's formula, and every sum is a
float64 `np.bincount`. Used by the tests and by `benchmarks/bench_sph.py` (the "scipy
reference" the OpenCL pass is timed against).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

F64 = npt.NDArray[np.float64]


def cubic_spline(q: F64, h: float) -> F64:
    """W(q) = 8/(pi h^3) (6(q^3 - q^2) + 1) for q <= 1/2, 2(1 - q)^3 for 1/2 < q <= 1, else 0."""
    sigma = 8.0 / (np.pi * h**3)
    inner = 6.0 * (q**3 - q**2) + 1.0
    outer = 2.0 * np.clip(1.0 - q, 0.0, None) ** 3
    return sigma * np.where(q <= 0.5, inner, np.where(q <= 1.0, outer, 0.0))


def cubic_spline_derivative(q: F64, h: float) -> F64:
    """dW/dr (per unit length) of `cubic_spline`."""
    sigma = 8.0 / (np.pi * h**3)
    inner = 6.0 * (3.0 * q**2 - 2.0 * q)
    outer = -6.0 * np.clip(1.0 - q, 0.0, None) ** 2
    return sigma / h * np.where(q <= 0.5, inner, np.where(q <= 1.0, outer, 0.0))


@dataclass(frozen=True)
class ReferencePairs:
    """All ordered pairs (i, j) with |x_i - x_j| < h, self pairs (i, i) included."""

    i: npt.NDArray[np.int64]
    j: npt.NDArray[np.int64]
    distance: F64
    offset: F64  # x_i - x_j, (P, 3)


def reference_pairs(positions: F64, h: float) -> ReferencePairs:
    positions = np.asarray(positions, dtype=np.float64)
    n = positions.shape[0]
    tree = cKDTree(positions)
    pairs = tree.query_pairs(h, output_type="ndarray")  # unordered, i < j, distance <= h
    a = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
    b = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
    offset = positions[a] - positions[b]
    distance = np.sqrt(np.einsum("ij,ij->i", offset, offset))
    keep = distance < h
    return ReferencePairs(a[keep], b[keep], distance[keep], offset[keep])


def neighbour_sets(positions: F64, h: float) -> list[set[int]]:
    """Neighbours j != i with |x_i - x_j| < h, by brute force pairs from cKDTree."""
    pairs = reference_pairs(positions, h)
    sets: list[set[int]] = [set() for _ in range(len(positions))]
    for i, j in zip(pairs.i.tolist(), pairs.j.tolist(), strict=True):
        if i != j:
            sets[i].add(j)
    return sets


@dataclass(frozen=True)
class ReferenceSph:
    density: F64
    color_field: F64
    color_gradient: F64  # (N, 3)
    gradient_abs_sum: F64  # sum_j |V_j grad W_ij|: the scale float32 rounding is relative to


def reference_sph(
    positions: F64, h: float, mass: float, densities: F64 | None = None
) -> ReferenceSph:
    """Density (self included), colour field and its gradient, all in float64.

    `densities`, when given, are used for the volumes m/rho_j (as the renderer does with client
    densities); otherwise the computed densities are."""
    n = len(positions)
    pairs = reference_pairs(positions, h)
    q = pairs.distance / h
    w = cubic_spline(q, h)
    rho = mass * np.bincount(pairs.i, weights=w, minlength=n)
    rho_used = rho if densities is None else np.asarray(densities, dtype=np.float64)
    volume = mass / rho_used[pairs.j]
    color = np.bincount(pairs.i, weights=volume * w, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit = np.where(pairs.distance[:, None] > 0, pairs.offset / pairs.distance[:, None], 0.0)
    term = (volume * cubic_spline_derivative(q, h))[:, None] * unit
    gradient = np.stack(
        [np.bincount(pairs.i, weights=term[:, k], minlength=n) for k in range(3)], 1
    )
    abs_sum = np.bincount(pairs.i, weights=np.linalg.norm(term, axis=1), minlength=n)
    return ReferenceSph(*(np.asarray(a, dtype=np.float64) for a in (rho, color, gradient, abs_sum)))
