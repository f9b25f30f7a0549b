"""Before/after crop of the rings the field normals drew on a pool around each exact droplet
(benchmarks/crops/crop-droplet-rings.png): the dam break's frame 9 in a close-up at 1280x720,
balanced, with the droplets taken as rims of the pool behind them (before: the normals pass
not given the bulk's depth under the droplets) and as today (after), composited over a white
page, 3x nearest-neighbour. Prints how far the normals within 5 px of the exact droplets lie
from those of the same frame rendered without the droplets (the surface behind goes on),
away from that surface's own rims.

Needs ../shared/data (the SPlisHSPlasH frames). Usage:
    .venv/bin/python benchmarks/crops/crop_droplet_rings.py [-o OUT.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from crop_pinholes import over_white, side_by_side
from scipy import ndimage

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.core.readers import read_particles
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.passes.normals import NormalsPass
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

FRAME = Path(__file__).resolve().parents[2] / "shared/data/dambreak-splishsplash/vtk"
RADIUS = 0.015
SCENE = {
    "image": {"width": 1280, "height": 720},
    "camera": {"eye": [0.2, 0.6, 1.2], "target": [0.5, 0.1, 0.0], "fov_y": 40.0},
    "particles": {"radius": RADIUS},
}
#: The crop: two droplet pairs over the pool (x, y, width, height).
BOX = (700, 300, 280, 180)


def render(renderer: SurfaceRenderer, frame: Any, *, rings: bool) -> Any:
    """The close-up; `rings`: the droplets' depth alone for the field normals' rims."""
    run = NormalsPass.run
    if rings:
        NormalsPass.run = lambda self, *a, **k: run(self, *a, **{**k, "bulk": None})  # type: ignore
    try:
        return renderer.render(frame, scene_from_dict(SCENE), depth=True, normals=True)[0]
    finally:
        NormalsPass.run = run  # type: ignore


def without_droplets(frame: ParticleFrame) -> ParticleFrame:
    """The frame less its droplets (the split's rule at the scene's defaults)."""
    scene = scene_from_dict(SCENE)
    assert frame.densities is not None
    bulk = frame.densities >= scene.quality.droplet_density * scene.sph.rest_density
    return make_frame(frame.positions[bulk], densities=frame.densities[bulk])


def own_rims(depth: npt.NDArray[np.float32]) -> npt.NDArray[np.bool_]:
    """Pixels without surface, or next to a depth step of more than 8 r."""
    z = np.where(np.isfinite(depth), depth, 0.0)
    rims = ~np.isfinite(depth)
    for axis in (0, 1):
        step = np.abs(np.diff(z, axis=axis)) > 8 * RADIUS
        pad = [(0, 0), (0, 0)]
        pad[axis] = (0, 1)
        rims |= np.pad(step, pad)
        pad[axis] = (1, 0)
        rims |= np.pad(step, pad)
    return rims


def angles_deg(a: npt.NDArray[np.float32], b: npt.NDArray[np.float32]) -> npt.NDArray[np.float64]:
    cos = np.sum(a.astype(np.float64) * b.astype(np.float64), axis=-1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("-o", "--output", default="benchmarks/crops/crop-droplet-rings.png")
    out = parser.parse_args().output
    frame = read_particles(FRAME / "ParticleData_Fluid_9.vtk")
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            before = render(renderer, frame, rings=True)
            after = render(renderer, frame, rings=False)
            pool = render(renderer, without_droplets(frame), rings=False)
        finally:
            renderer.release()
    # The exact droplets' pixels: a surface nearer than the frame without them, or where it
    # has none; beside them, the surface that frame shows (it goes on behind the droplets).
    near = after.depth < np.where(np.isfinite(pool.depth), pool.depth, np.inf) * (1 - 1e-6)
    drops = np.isfinite(after.depth) & near
    beside = np.isfinite(pool.depth) & ~drops & (ndimage.distance_transform_edt(~drops) <= 5)
    # ... away from the rims that surface has of its own (where the field normals act anyway).
    beside &= ndimage.distance_transform_edt(~own_rims(pool.depth)) > 6
    print(f"{int(drops.sum())} pixels of exact droplets, {int(beside.sum())} beside them")
    for name, image in (("before", before), ("after", after)):
        change = angles_deg(image.normals[beside], pool.normals[beside])
        print(
            f"{name}: the surface beside the droplets {change.mean():.2f} deg mean, "
            f"{np.percentile(change, 95):.2f} p95 off the frame without them"
        )
    x, y, w, h = BOX
    crops = [over_white(f.rgba)[y : y + h, x : x + w] for f in (before, after)]
    side_by_side(crops, 3).save(out)
    print("wrote", out)


if __name__ == "__main__":
    main()
