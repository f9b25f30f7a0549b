"""Before/after crop of the lone droplets SPlisHSPlasH's densities hide
(benchmarks/crops/crop-lone-droplets.png): the dam break's frame 9 in a close-up at 1280x720,
balanced without `quality.droplet_lone_density` (before: the frame's densities alone, which
count the simulator's walls, so a lone particle by a wall reads bulk and is smoothed into a
lens) and with it (after, the default since 2026-12-03), composited over a white page, 2x
nearest-neighbour. Prints how many particles the rule adds to the droplets.

Needs ../shared/data (the SPlisHSPlasH frames). Usage:
    .venv/bin/python benchmarks/crops/crop_lone_droplets.py [-o OUT.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from crop_pinholes import over_white, side_by_side

from sphrender.core.readers import read_particles
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.engine.sph.frame import SphStage
from sphrender.server.scene import scene_from_dict

FRAME = Path(__file__).resolve().parents[2] / "shared/data/dambreak-splishsplash/vtk"
SCENE: dict[str, Any] = {
    "image": {"width": 1280, "height": 720},
    "camera": {"eye": [0.2, 0.6, 1.2], "target": [0.5, 0.1, 0.0], "fov_y": 40.0},
    "particles": {"radius": 0.015},
}
#: The crop: droplets over the pool by the left wall (x, y, width, height).
BOX = (20, 230, 400, 240)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("-o", "--output", default="benchmarks/crops/crop-lone-droplets.png")
    out = parser.parse_args().output
    frame = read_particles(FRAME / "ParticleData_Fluid_9.vtk")
    before_scene = scene_from_dict({**SCENE, "quality": {"droplet_lone_density": 0.0}})
    after_scene = scene_from_dict(SCENE)
    stage = SphStage()
    try:
        before_mask = stage.run(frame, before_scene).droplets
        after_mask = stage.run(frame, after_scene).droplets
    finally:
        stage.release()
    assert before_mask is not None and after_mask is not None
    print(
        f"droplets: {int(before_mask.sum())} by the frame's densities, "
        f"{int(after_mask.sum())} with the lone particles"
    )
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            before = renderer.render(frame, before_scene)[0]
            after = renderer.render(frame, after_scene)[0]
        finally:
            renderer.release()
    x, y, w, h = BOX
    crops = [over_white(f.rgba)[y : y + h, x : x + w] for f in (before, after)]
    side_by_side(crops, 2).save(out)
    print("wrote", out)


if __name__ == "__main__":
    main()
