"""The report's normal-guide crops: balanced without the guide (left) and balanced (right),
whole 640x360 images, on the bench's slab, its fluid block against a solid wall (the wall
flagged solid) and the demo (configs/demo.toml), where the edges run across the frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.bench.scenes import slab_scene
from sphrender.server.bench.solid_scenes import wall_scene
from sphrender.server.bench.sweep import (
    NO_GUIDE,
    Setting,
    bench_scene_dict,
    preset_setting,
    scene_for,
)
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.renderer import SurfaceRenderer

WIDTH, HEIGHT = 640, 360


def write_guide_crops(
    renderer: SurfaceRenderer, out: Path, folder: str = "crops"
) -> list[tuple[str, str]]:
    """Writes out/folder/crop-guide-<name>.png for each case; returns (caption, file) pairs."""
    from sphrender.server.content.demo import demo_frame, demo_scene_dict
    from sphrender.server.output.encoders import write_png

    settings: tuple[Setting, Setting] = (NO_GUIDE, preset_setting("balanced"))
    cases = []
    for bench in (slab_scene(1.2, 4), wall_scene()):
        frame = make_frame(bench.positions, solid=bench.solid_flags())
        cases.append((bench.name, frame, bench_scene_dict(bench, WIDTH, HEIGHT)))
    demo = demo_scene_dict()
    for section in ("quality", "sph"):  # the setting decides these
        demo.pop(section, None)
    demo["image"] = {"width": WIDTH, "height": HEIGHT}
    cases.append(("demo", demo_frame(), demo))
    files = []
    for name, frame, sections in cases:
        halves = [renderer.render(frame, scene_for(s, sections))[0].rgba for s in settings]
        gap = np.ones((HEIGHT, 4, 4), np.float32)
        file = f"{folder}/crop-guide-{name}.png"
        (out / folder).mkdir(parents=True, exist_ok=True)
        write_png(RenderedFrame(np.concatenate([halves[0], gap, halves[1]], axis=1)), out / file)
        caption = f"{name}, whole image: {settings[0].name} (left) / {settings[1].name} (right)"
        files.append((caption, file))
    return files
