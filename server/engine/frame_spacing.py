"""A frame's typical particle spacing, cheaply: the median nearest-neighbour distance of the
particles in three small cubes of the frame's bulk (numpy only, no tree over the whole frame).

1. A random probe of `PROBE` particles finds the bulk: probe particles whose `K`-th nearest
   probe neighbour is nearer than for 40-80 % of the probe (`CENTERS`) sit in the fluid's bulk,
   not in spray, and that distance gives the local number density.
2. A cube around each, sized to hold about `CUBE` particles, is cut from the frame: one pass
   over the x column, then y and z on the slab (resized and cut again when it holds far more or
   fewer than meant).
3. The particles of a cube's inner part (`INNER` of its side, so a neighbour outside the cube
   is farther than any distance that counts) are matched against all of the cube's particles
   by brute force; the median of their nearest-neighbour distances, pooled over the cubes, is
   the spacing.

Cost: the probe and the cubes are bounded (at most 100 x 3000 distances each), so what grows
with N is one pass over the x column per cube.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

#: Particles in the random probe that finds the bulk.
PROBE = 256
#: The probe neighbour whose distance measures the local density.
K = 8
#: The probe particles the cubes are centred on, as quantiles of their K-th neighbour distance:
#: the denser 60 % of the probe (the bulk), never the spray.
CENTERS = (0.2, 0.4, 0.6)
#: Particles a cube is meant to hold, and the bounds beyond which it is cut again.
CUBE = 800
CUBE_RANGE = (250, 3000)
#: Side of the inner cube whose particles are queried, as a fraction of the cube's side.
INNER = 0.6
#: Fewest inner particles a spacing is given from, and most that are queried.
MIN_QUERIES = 32
MAX_QUERIES = 100


def _cube(positions: npt.NDArray[np.float64], center: np.ndarray, side: float) -> np.ndarray:
    """Rows of `positions` within the axis-aligned cube of `side` around `center`."""
    half = side / 2
    rows = np.flatnonzero(np.abs(positions[:, 0] - center[0]) <= half)
    near = np.abs(positions[rows, 1:] - center[1:]) <= half
    return rows[near.all(axis=1)]


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) Euclidean distances, one axis at a time (no (A, B, 3) temporary)."""
    squared = (a[:, None, 0] - b[None, :, 0]) ** 2
    for axis in (1, 2):
        squared += (a[:, None, axis] - b[None, :, axis]) ** 2
    return np.sqrt(squared)


def _cube_nearest(
    positions: npt.NDArray[np.float64], center: np.ndarray, side: float, limit: float
) -> np.ndarray:
    """Nearest-neighbour distances of the inner particles of a cube around `center` whose side
    starts at `side` and is resized until the cube holds about `CUBE` particles."""
    rows = _cube(positions, center, side)
    for _ in range(3):
        if CUBE_RANGE[0] <= rows.size <= CUBE_RANGE[1]:
            break
        side = min(side * (CUBE / max(rows.size, 1)) ** (1.0 / 3.0), limit)
        rows = _cube(positions, center, side)
    cube = positions[rows]
    queries = cube[np.abs(cube - center).max(axis=1) <= INNER * side / 2]
    queries = queries[:: -(-len(queries) // MAX_QUERIES) or 1]  # spread over the inner cube
    if not queries.shape[0]:
        return np.zeros(0)
    return np.partition(_distances(queries, cube), 1, axis=1)[:, 1]  # [:, 0]: itself


def typical_spacing(positions: npt.NDArray[np.float64], seed: int = 0) -> float | None:
    """The frame's median nearest-neighbour distance in its bulk, or None when the frame has too
    few particles (or they all coincide) to tell."""
    n = int(positions.shape[0])
    if n < 2 * K:
        return None
    rng = np.random.default_rng(seed)
    probe = positions[rng.choice(n, min(n, PROBE), replace=False)]
    kth = np.partition(_distances(probe, probe), K, axis=1)[:, K]  # [:, 0]: itself
    order = np.argsort(kth)
    limit = 2.0 * float(np.ptp(probe, axis=0).max()) + float(kth.max())
    nearest: list[np.ndarray] = []
    for quantile in CENTERS:
        index = int(order[int(quantile * (len(order) - 1))])
        reach = float(kth[index])
        if reach <= 0.0:
            continue
        # K probe particles within `reach` stand for K x n / len(probe) of the frame's.
        local = K * n / len(probe) / (4.0 / 3.0 * math.pi * reach**3)
        side = (CUBE / local) ** (1.0 / 3.0)
        nearest.append(_cube_nearest(positions, probe[index], side, limit))
    pooled = np.concatenate(nearest) if nearest else np.zeros(0)
    if pooled.size < MIN_QUERIES:
        return None
    spacing = float(np.median(pooled))
    return spacing if spacing > 0.0 else None
