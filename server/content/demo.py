"""The built-in demo scene: a weld bead with ripples on a steel plate, plus a few spatter droplets,
still glowing behind the arc.

Generated procedurally (no downloads). Units are millimetres, particle radius 0.4 mm.
Temperatures follow a moving-heat-source picture (Rosenthal): a liquid pool at ~2500 K where the
arc is (GTA pools on stainless reach 2000-2800 K, validation-data.md), a long hot trail behind it
along the bead, a short steep fall ahead and sideways, and the plate at room temperature away
from it. The frame carries each particle's peak temperature too: the field moved with the arc
from the bead's start, so a particle's peak is the field where the arc passed closest to it; the
heat tint (configs/demo.toml sets material.heat_tint) reads it as temper-colour bands beside the
bead, behind the molten pool (material.molten). Hot spatter leaves the pool with velocities
(1-4 m/s, as high-speed footage of GMA spatter shows): the demo's open shutter draws them as
streaks, and the arc above the pool (a sphere light in configs/demo.toml) casts the shadows.
"""

from __future__ import annotations

import importlib.resources
import tomllib
from typing import Any

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.scene import Scene, scene_from_dict

PARTICLE_RADIUS = 0.4
#: Where the arc is (mm): near the end of the bead, which the torch travels towards (+x).
ARC_POSITION = (24.0, 3.0, 0.0)
#: Where the torch started (x, mm): the bead's start.
ARC_START_X = -30.0
POOL_KELVIN = 2500.0
ROOM_KELVIN = 300.0
#: The temperature excess over room temperature is the sum of a small, hot pool (1/e radius
#: POOL_LENGTH mm, POOL_SHARE of the excess) and a long trail that cools behind the arc (1/e
#: length TRAIL_LENGTH mm along -x, TRAIL_WIDTH mm across); ahead of the arc both fall off
#: AHEAD_FACTOR times faster. Along the bead this gives ~1700 K (solidus) 6 mm behind the arc,
#: 1250 K at 15 mm and 900 K at 30 mm: white pool, orange then dull red trail, grey bead.
POOL_SHARE = 0.35
POOL_LENGTH = 4.0
TRAIL_LENGTH = 50.0
TRAIL_WIDTH = 14.0
AHEAD_FACTOR = 2.0


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


#: Droplets in flight: how many, their speed range (mm/s) and temperature range (K).
FLYING_COUNT = 24
FLYING_SPEED = (1000.0, 4000.0)
FLYING_KELVIN = (1700.0, 2200.0)


def flying_spatter(
    seed: int = 11,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """Positions, velocities (mm/s) and kelvin of hot droplets thrown up and out of the pool:
    each on a ray from the arc, 3-14 mm out, moving along it."""
    rng = np.random.default_rng(seed)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, FLYING_COUNT)
    elevation = rng.uniform(0.25, 1.1, FLYING_COUNT)  # radians above the plate
    direction = np.stack(
        [
            np.cos(elevation) * np.cos(azimuth),
            np.sin(elevation),
            np.cos(elevation) * np.sin(azimuth),
        ],
        axis=1,
    )
    distance = rng.uniform(3.0, 14.0, FLYING_COUNT)[:, None]
    positions = np.asarray(ARC_POSITION) + direction * distance
    speed = rng.uniform(*FLYING_SPEED, FLYING_COUNT)[:, None]
    kelvin = rng.uniform(*FLYING_KELVIN, FLYING_COUNT)
    return positions, (direction * speed).astype(np.float32), kelvin.astype(np.float32)


def weld_temperatures(
    positions: npt.NDArray[np.float64], arc_x: float | npt.NDArray[np.float64] = ARC_POSITION[0]
) -> npt.NDArray[np.float32]:
    """Kelvin per particle: POOL_KELVIN at the arc, a pool term plus a long trail behind it;
    `arc_x`: where the arc is along x (per particle, for the peak)."""
    offset = positions - np.asarray(ARC_POSITION)
    along = positions[:, 0] - arc_x
    ahead = along > 0.0
    behind_scale = np.where(ahead, 1.0 / AHEAD_FACTOR, 1.0)
    across = np.hypot(offset[:, 1], offset[:, 2])
    pool = np.hypot(along / (POOL_LENGTH * behind_scale), across / POOL_LENGTH)
    trail = np.hypot(along / (TRAIL_LENGTH * behind_scale), across / TRAIL_WIDTH)
    excess = POOL_SHARE * np.exp(-pool) + (1.0 - POOL_SHARE) * np.exp(-trail)
    kelvin = ROOM_KELVIN + (POOL_KELVIN - ROOM_KELVIN) * excess
    return kelvin.astype(np.float32)


def weld_peak_temperatures(positions: npt.NDArray[np.float64]) -> npt.NDArray[np.float32]:
    """Kelvin per particle: the hottest the moving field made it while the arc travelled from
    ARC_START_X to the arc. The field falls monotonically with |along| on both sides, so the
    peak is where the arc passed closest: along the travel, clipped to the particle's x."""
    closest = np.clip(positions[:, 0], ARC_START_X, ARC_POSITION[0])
    return weld_temperatures(positions, closest)


def demo_scene_dict() -> dict[str, Any]:
    """``configs/demo.toml`` as a mapping (unvalidated)."""
    text = importlib.resources.files("sphrender.configs").joinpath("demo.toml").read_text()
    return tomllib.loads(text)


def demo_scene() -> Scene:
    return scene_from_dict(demo_scene_dict())


def demo_frame() -> ParticleFrame:
    """The plate, the bead and its spatter at rest, and the droplets in flight."""
    still = weld_bead_positions()
    flying, velocities, flying_kelvin = flying_spatter()
    kelvin = np.concatenate([weld_temperatures(still), flying_kelvin])
    return make_frame(
        np.concatenate([still, flying]),
        temperatures=kelvin,
        peak_temperatures=np.concatenate([weld_peak_temperatures(still), flying_kelvin]),
        velocities=np.concatenate([np.zeros((len(still), 3), np.float32), velocities]),
    )
