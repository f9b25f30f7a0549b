"""Before/after crop of the pinholes a view along a lattice plate's channels shows
(benchmarks/crops/crop-pinholes-plate.png): a 3-layer plate at 480x270, balanced, without and with
the gap rule's second run after the smoothing (`GapPass.close_again`), composited over a white
page as a frontend would composite the PNG's straight alpha, 4x nearest-neighbour.

Usage: .venv/bin/python benchmarks/crops/crop_pinholes.py [-o OUT.png]
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image
from scipy import ndimage

from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.passes.gaps import GapPass
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict


def over_white(rgba: npt.NDArray[np.float32]) -> npt.NDArray[np.uint8]:
    """Straight linear RGB + alpha over a white page, sRGB-ish gamma, 8 bits."""
    rgb, alpha = rgba[..., :3].astype(np.float64), rgba[..., 3:].astype(np.float64)
    out = np.clip(rgb * alpha + (1.0 - alpha), 0.0, 1.0) ** (1 / 2.2)
    return (out * 255).astype(np.uint8)


def side_by_side(crops: list[npt.NDArray[np.uint8]], scale: int) -> Image.Image:
    """Two 8-bit RGB crops, each `scale` x nearest-neighbour, 8 white pixels between them."""
    big = [np.kron(c, np.ones((scale, scale, 1), np.uint8)) for c in crops]
    gap = np.full((big[0].shape[0], 8, 3), 255, np.uint8)
    return Image.fromarray(np.concatenate([big[0], gap, big[1]], axis=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="benchmarks/crops/crop-pinholes-plate.png")
    out = parser.parse_args().output
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        plate = make_frame(lattice_slab(0.6, 0.6, 3, 0.01))
        scene = scene_from_dict(
            {
                "image": {"width": 480, "height": 270},
                "camera": {"eye": [0.0, 0.3, 0.4], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
                "particles": {"radius": 0.01},
            }
        )
        after: Any = renderer.render(plate, scene, depth=True)[0]
        close_again = GapPass.close_again
        GapPass.close_again = lambda self, depth, temperature=None: depth  # type: ignore
        try:
            before: Any = renderer.render(plate, scene, depth=True)[0]
        finally:
            GapPass.close_again = close_again  # type: ignore
        renderer.release()
    covered = np.isfinite(before.depth)
    holes = ndimage.binary_fill_holes(covered) & ~covered
    ys, xs = np.nonzero(holes)
    print(f"{len(ys)} pinhole pixels without the second run, {int(ndimage.label(holes)[1])} holes")
    y0, x0 = max(int(np.median(ys)) - 40, 0), max(int(np.median(xs)) - 60, 0)
    crops = [over_white(f.rgba)[y0 : y0 + 80, x0 : x0 + 120] for f in (before, after)]
    side_by_side(crops, 4).save(out)
    print("wrote", out)


if __name__ == "__main__":
    main()
