"""Height maps of worked metal for `[finish] detail_image`: grinding marks, the arcs an angle
grinder's disc leaves, as a tile that repeats without seams. Numpy; `write_height_map` writes
one with OpenImageIO for the example and the finish bench.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]


def grinding_marks(
    texels: int = 256, marks: int = 70, seed: int = 1, sweep_deg: float = 20.0
) -> F32:
    """(texels, texels, 1) heights in [0, 1] (1 = the unworked surface): `marks` shallow arcs
    of radius 0.8-2.5 tiles and length 0.15-0.6 tile, 1-3 texels wide, running along v (world
    x on a +y face) within +-`sweep_deg`. Distances are taken on the torus (each mark's
    offsets wrapped to half a tile), so the tile's edges meet."""
    rng = np.random.default_rng(seed)
    centres = (np.arange(texels) + 0.5) / texels
    u, v = np.meshgrid(centres, centres)
    depth = np.zeros((texels, texels))
    for _ in range(marks):
        anchor = rng.random(2)
        angle = np.radians(90.0 + rng.uniform(-sweep_deg, sweep_deg))
        tangent = np.array([np.cos(angle), np.sin(angle)])
        normal = np.array([-tangent[1], tangent[0]]) * rng.choice([-1.0, 1.0])
        radius = rng.uniform(0.8, 2.5)
        length = rng.uniform(0.15, 0.6)
        width = rng.uniform(1.0, 3.0) / texels
        du = (u - anchor[0] + 0.5) % 1.0 - 0.5
        dv = (v - anchor[1] + 0.5) % 1.0 - 0.5
        along = du * tangent[0] + dv * tangent[1]
        off_centre = np.hypot(du - radius * normal[0], dv - radius * normal[1])
        across = off_centre - radius
        taper = np.clip(1.0 - (2.0 * along / length) ** 4, 0.0, 1.0)
        depth += rng.uniform(0.2, 1.0) * taper * np.exp(-((across / width) ** 2))
    heights = 1.0 - np.clip(depth, 0.0, 1.0)
    return heights[..., None].astype(np.float32)


def write_height_map(path: Path, heights: F32) -> Path:
    """`heights` (H, W, 1) as a one-channel float image at `path` (format from its suffix)."""
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise ValueError(f"OpenImageIO cannot write {path.name}")
    out.open(str(path), oiio.ImageSpec(heights.shape[1], heights.shape[0], 1, "float"))
    out.write_image(heights)
    out.close()
    return path
