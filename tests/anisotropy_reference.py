"""Independent float64 reference of the anisotropic particles (Yu & Turk 2013, as specified in
``shaders/sph/anisotropy.cl``'s header): cKDTree pairs, float64 sums, ``numpy.linalg.eigh``.

Shares no code with the engine: pairs from scipy (`sph_reference.reference_pairs`), weighted
mean and covariance about the mean computed directly (two passes, not the kernel's one-pass
shifted sums), axes from numpy's eigen-decomposition.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from sph_reference import reference_pairs

F64 = npt.NDArray[np.float64]

#: The kernel's DEGENERATE_VARIANCE (units of R^2) and the module's RAMP_FRACTION, restated.
DEGENERATE_VARIANCE = 1e-6
RAMP_FRACTION = 0.5


@dataclass(frozen=True)
class ReferenceAnisotropy:
    centers: F64  # (N, 3)
    axes: F64  # (N, 3, 3), columns = semi-axes, world units
    is_sphere: npt.NDArray[np.bool_]
    neighbour_count: npt.NDArray[np.int64]
    covariance: F64  # (N, 3, 3), world units^2
    ramp: F64  # t in [0, 1]


def reference_anisotropy(
    positions: F64,
    radius: float,
    *,
    max_ratio: float,
    min_neighbours: int,
    smoothing: float,
    particle_radius: float | F64,
) -> ReferenceAnisotropy:
    x = np.asarray(positions, dtype=np.float64)
    n = len(x)
    pairs = reference_pairs(x, radius)  # i, j with |x_i - x_j| < R, self included
    w = 1.0 - (pairs.distance / radius) ** 3
    sum_w = np.bincount(pairs.i, weights=w, minlength=n)
    mean = (
        np.stack(
            [np.bincount(pairs.i, weights=w * x[pairs.j, k], minlength=n) for k in range(3)], 1
        )
        / sum_w[:, None]
    )
    dev = x[pairs.j] - mean[pairs.i]
    outer = w[:, None, None] * dev[:, :, None] * dev[:, None, :]
    cov = np.zeros((n, 3, 3))
    np.add.at(cov, pairs.i, outer)
    cov /= sum_w[:, None, None]
    count = np.bincount(pairs.i, minlength=n) - 1
    ramp_width = max(1.0, RAMP_FRACTION * min_neighbours)
    t = np.where(
        count < min_neighbours, 0.0, np.minimum(1.0, (count - min_neighbours + 1) / ramp_width)
    )

    values, vectors = np.linalg.eigh(cov)  # ascending
    values, vectors = values[:, ::-1], vectors[:, :, ::-1]
    sphere = (t == 0.0) | (values[:, 0] <= DEGENERATE_VARIANCE * radius**2)
    clamped = np.maximum(values, values[:, :1] / max_ratio)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_g = np.log(clamped).mean(axis=1, keepdims=True)
        lengths = np.exp(t[:, None] * (np.log(clamped) - log_g))
    r = np.broadcast_to(np.asarray(particle_radius, dtype=np.float64), (n,))
    axes = vectors * lengths[:, None, :] * r[:, None, None]
    axes[sphere] = np.eye(3) * r[sphere, None, None]
    shift = (smoothing * t)[:, None] * (mean - x)
    shift[sphere] = 0.0
    return ReferenceAnisotropy(x + shift, axes, sphere, count, cov, t)


def shape_tensor(axes: npt.ArrayLike) -> F64:
    """A A^T: the ellipsoid's invariant (independent of the axes' signs and, for repeated
    lengths, of the basis chosen); the ellipsoid is { y : (y - c)^T (A A^T)^-1 (y - c) <= 1 }."""
    a = np.asarray(axes, dtype=np.float64)
    return np.einsum("nij,nkj->nik", a, a)
