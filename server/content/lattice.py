"""Particle lattices: the building blocks of the demo and of the reference scenes.

Plain numpy, no GL. `sphrender.server.bench.analytic` holds the known answers (ray-cast truth,
error metrics) for scenes built from these.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


def jittered_lattice_ball(
    ball_radius: float,
    particle_radius: float,
    *,
    center: tuple[float, float, float] = (0.0, 0.0, 0.0),
    jitter: float = 0.1,
    seed: int = 0,
) -> F64:
    """Particles on a cubic lattice of spacing 2r inside a ball, each moved by up to
    ``jitter * r`` per axis. The union of the particle spheres lies within ``ball_radius + r``."""
    spacing = 2.0 * particle_radius
    n = int(np.ceil(ball_radius / spacing))
    axis = np.arange(-n, n + 1) * spacing
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    grid = grid + rng.uniform(-jitter, jitter, grid.shape) * particle_radius
    inside = np.linalg.norm(grid, axis=1) <= ball_radius
    return grid[inside] + np.asarray(center, dtype=np.float64)


def lattice_slab(
    size_x: float, size_z: float, layers: int, particle_radius: float, *, top_y: float = 0.0
) -> F64:
    """A slab of `layers` lattice layers (spacing 2r) whose top particle centres lie at `top_y`."""
    spacing = 2.0 * particle_radius
    xs = np.arange(-size_x / 2, size_x / 2 + 1e-12, spacing)
    zs = np.arange(-size_z / 2, size_z / 2 + 1e-12, spacing)
    ys = top_y - np.arange(layers) * spacing
    grid = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    return grid
