"""The built-in demo scene: a weld bead with ripples on a steel plate, plus a few spatter droplets.

Generated procedurally (no downloads). Units are millimetres, particle radius 0.4 mm.
"""

from __future__ import annotations

import importlib.resources
import tomllib

import numpy as np
import numpy.typing as npt

from sphrender.client.frame import ParticleFrame, make_frame
from sphrender.server.analytic_scenes import lattice_slab
from sphrender.server.scene import Scene, scene_from_dict

PARTICLE_RADIUS = 0.4


def weld_bead_positions(seed: int = 7) -> npt.NDArray[np.float64]:
    r = PARTICLE_RADIUS
    spacing = 2.0 * r
    rng = np.random.default_rng(seed)
    plate = lattice_slab(70.0, 44.0, layers=3, particle_radius=r, top_y=0.0)
    # Bead: elliptic half-cylinder along x whose width and height ripple like solidified
    # weld ripples, ending in a rounder crater where the arc stopped.
    xs = np.arange(-30.0, 30.0 + 1e-9, spacing)
    ys = np.arange(spacing, 7.0, spacing)
    zs = np.arange(-8.0, 8.0 + 1e-9, spacing)
    grid = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    x, y, z = grid[:, 0], grid[:, 1], grid[:, 2]
    ripple = 1.0 + 0.08 * np.sin(2.0 * np.pi * x / 4.0)
    taper = np.clip((30.0 - np.abs(x)) / 6.0, 0.0, 1.0) ** 0.5
    half_width = 6.5 * ripple * taper
    height = 4.5 * ripple * taper
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = (z / half_width) ** 2 + (y / height) ** 2 <= 1.0
    bead = grid[inside & (half_width > 0)]
    bead += rng.uniform(-0.08, 0.08, bead.shape) * r
    # Spatter: small droplets scattered beside the bead.
    count = 40
    angle = rng.uniform(0.0, 2.0 * np.pi, count)
    dist = rng.uniform(9.0, 20.0, count)
    spatter = np.stack(
        [rng.uniform(-26.0, 26.0, count), np.full(count, r), np.sin(angle) * dist], axis=1
    )
    return np.concatenate([plate, bead, spatter])


def demo_scene() -> Scene:
    text = importlib.resources.files("sphrender.configs").joinpath("demo.toml").read_text()
    return scene_from_dict(tomllib.loads(text))


def demo_frame() -> ParticleFrame:
    return make_frame(weld_bead_positions())
