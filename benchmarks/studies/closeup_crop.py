"""Before/after crops of a close-up of the real dam-break frame (the repository's REPORT.md):
what the bench's distance does not show, such as the streaks the separable filter leaves along
silhouettes when kernels are long (`quality.last_pass_sigma`, `quality.destreak`).

The frame is SPlisHSPlasH output outside this repository (`scenes.dambreak_frame`); without it
nothing is written. The camera looks down at the front's rim, 1.0-1.7 units away in the crop
(median 1.2): about 6 px per particle radius at 640x360, so the kernel (sigma 2 radii)
reaches ~37 px.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.bench.scenes import DAMBREAK_RADIUS, dambreak_frame
from sphrender.server.bench.surface_bench import CROPS, SurfaceResults
from sphrender.server.bench.sweep import Setting, scene_for
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.renderer import SurfaceRenderer

#: Above the front of frame 5, looking down at its rim (the streaks show on its right).
CLOSEUP_CAMERA = {"eye": [-0.4, 0.9, 0.9], "target": [-0.6, 0.3, 0.0], "fov_y": 40.0}
#: The crop of the 640x360 image, (top, left, height, width): the rim and the surface inside it.
CLOSEUP_WINDOW = (60, 380, 300, 260)
#: balanced with the separable filter's passes all at one sigma (before last_pass_sigma).
EQUAL_PASSES = Setting("balanced, equal passes", {"quality": {"last_pass_sigma": 1.0}}, "balanced")
#: balanced with best's light last pass across the last.
BALANCED_DESTREAK = Setting("balanced + destreak 0.25", {"quality": {"destreak": 0.25}}, "balanced")


def write_closeup_crop(
    renderer: SurfaceRenderer,
    out: Path,
    results: SurfaceResults,
    *,
    before: Setting,
    after: Setting,
    name: str = "crop-closeup-dambreak.png",
) -> None:
    """`before` (left) and `after` (right) on the close-up, side by side, as
    `out / CROPS / name`; its caption joins `results.crops`. Nothing without the data set."""
    from sphrender.core.readers import read_particles
    from sphrender.server.output.encoders import write_png

    path = dambreak_frame()
    if path is None:
        return
    particles = read_particles(path)
    frame = make_frame(particles.positions, densities=particles.densities)
    base = {
        "image": {"width": 640, "height": 360},
        "camera": CLOSEUP_CAMERA,
        "particles": {"radius": DAMBREAK_RADIUS},
        "shading": {"background": "environment"},
    }
    top, left, height, width = CLOSEUP_WINDOW
    halves = [
        renderer.render(frame, scene_for(s, base))[0].rgba[top : top + height, left : left + width]
        for s in (before, after)
    ]
    gap = np.ones((height, 4, 4), np.float32)
    image = np.concatenate([halves[0], gap, halves[1]], axis=1)
    (out / CROPS).mkdir(parents=True, exist_ok=True)
    write_png(RenderedFrame(image), out / CROPS / name)
    caption = f"dam break frame 5, close-up: {before.name} (left) / {after.name} (right)"
    results.crops.append((caption, f"{CROPS}/{name}"))
