"""The brushed plate: what the `[finish]` section costs and how it looks (the repository's
REPORT.md). A flat plate of lattice particles (three layers, 12k particles) under the workshop
environment and one point light, seen obliquely at 960x540 with the balanced preset; frame
times for the finish off, the anisotropic lobe, the procedural surface detail, the image
detail (examples/ground_plate.toml's grinding marks), and both (and sampled IBL, which pays the
anisotropic lobe per sample), measured interleaved in one run, with their ratio to off.
Before/after crops show the plate off and with the procedural finish, and with the image's. The
renderer must have `write_marks`' directory among its environment directories.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.content.marks import grinding_marks, write_height_map
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, read_scene_toml, scene_from_dict

RADIUS = 0.01
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "brushed_plate.toml"
GROUND = Path(__file__).resolve().parents[2] / "examples" / "ground_plate.toml"
BRUSHED = {"anisotropy": 0.8, "brush_direction": [1.0, 0.0, 0.0]}
DETAIL = {
    "detail": "brushed",
    "detail_scale": 0.004,
    "detail_normal_strength": 0.2,
    "detail_roughness_strength": 0.1,
}
#: The ground plate's image detail, without its brushed lobe.
IMAGE = {k: v for k, v in read_scene_toml(GROUND)["finish"].items() if k.startswith("detail")}
#: Per measured setting: name, the scene's [shading] over the balanced preset, its [finish].
SAMPLED = {"ibl_mode": "sampled", "ibl_samples": 64}
SETTINGS: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("prefiltered, finish off", {}, {}),
    ("prefiltered, anisotropic", {}, BRUSHED),
    ("prefiltered, detail", {}, DETAIL),
    ("prefiltered, anisotropic + detail", {}, {**BRUSHED, **DETAIL}),
    ("prefiltered, image detail", {}, IMAGE),
    ("prefiltered, anisotropic + image detail", {}, {**BRUSHED, **IMAGE}),
    ("sampled 64, finish off", SAMPLED, {}),
    ("sampled 64, anisotropic", SAMPLED, BRUSHED),
]
#: The crop of the 960x540 image, (top, left, height, width): the highlight and the far edge.
WINDOW = (90, 300, 300, 360)


def write_marks(directory: Path) -> Path:
    """The ground plate's height map, `IMAGE`'s file, written into `directory`."""
    return write_height_map(directory / str(IMAGE["detail_image"]), grinding_marks())


def plate_frame() -> ParticleFrame:
    return make_frame(lattice_slab(1.6, 1.0, 3, RADIUS))


def plate_scene(shading: dict[str, Any], finish: dict[str, Any]) -> Scene:
    """The example's scene with `finish` in place of its own and `shading` over its own."""
    base = read_scene_toml(EXAMPLE)
    return scene_from_dict({**base, "shading": {**base["shading"], **shading}, "finish": finish})


def measure(
    renderer: SurfaceRenderer, frames: int = 5, log: Callable[[str], None] = print
) -> list[tuple[str, float, float, float]]:
    """(setting, frame ms, normals + shade ms, shade ms) per setting: the fastest of `frames`,
    the one other processes disturbed least, frames interleaved so every setting sees the same
    load."""
    frame = plate_frame()
    scenes = [(name, plate_scene(shading, finish)) for name, shading, finish in SETTINGS]
    for _, scene in scenes:  # warm: programs, IBL resources, targets
        renderer.render(frame, scene)
    times: dict[str, list[tuple[float, float, float]]] = {name: [] for name, _ in scenes}
    for i in range(frames):
        log(f"brushed plate: round {i + 1} of {frames}")
        for name, scene in scenes:
            start = time.perf_counter()
            _, stats = renderer.render(frame, scene)
            wall_ms = (time.perf_counter() - start) * 1e3
            shade_ms = stats.stage_ms.get("shade", 0.0)
            times[name].append((wall_ms, stats.stage_ms.get("normals", 0.0) + shade_ms, shade_ms))
    return [
        (name, min(t[0] for t in v), min(t[1] for t in v), min(t[2] for t in v))
        for name, v in times.items()
    ]


def section(rows: list[tuple[str, float, float, float]]) -> list[str]:
    """The report's section: the table of `measure` with ratios to each preset's finish off."""
    lines = [
        "## Brushed plate: what the finish costs",
        "",
        "A flat plate of lattice particles (3 layers, 12k particles, r = 0.01) under the workshop "
        "environment and a point light, 960x540, seen obliquely ([examples/brushed_plate.toml]"
        "(../examples/brushed_plate.toml)). Anisotropic: `finish.anisotropy` 0.8; detail: "
        "`finish.detail` brushed (normal and roughness); image detail: `finish.detail_image`, "
        "the grinding marks of [examples/ground_plate.toml](../examples/ground_plate.toml) (a "
        "256 x 256 height map, normal and roughness); balanced preset, IBL prefiltered or "
        "sampled with 64 samples. The fastest of interleaved frames; the ratio is to the same "
        "IBL mode with the finish off.",
        "",
        "| setting | frame ms | / off | normals + shade (+ detail) ms | / off "
        "| shade (+ detail) ms | / off |",
        "|---|---|---|---|---|---|---|",
    ]
    offs = {name.split(",")[0]: values for name, *values in rows if name.endswith("finish off")}
    for name, *values in rows:
        off = offs[name.split(",")[0]]
        cells = " | ".join(f"{v:.1f} | {v / o:.2f}" for v, o in zip(values, off, strict=True))
        lines.append(f"| {name} | {cells} |")
    lines += ["", "![brushed plate](crops/crop-brushed-plate.png)", ""]
    lines += [
        "Brushed plate, balanced: finish off (left) / anisotropic + detail (right).",
        "",
        "![ground plate](crops/crop-ground-plate.png)",
        "",
        "Ground plate, balanced: finish off (left) / anisotropic + image detail (right).",
        "",
    ]
    return lines


def write_crop(renderer: SurfaceRenderer, out: Path) -> list[Path]:
    """Finish off (left) and anisotropic + detail (right), side by side, as
    `out / crops / crop-brushed-plate.png`; the same with the image detail as
    `crop-ground-plate.png`."""
    from sphrender.server.output.encoders import write_png

    frame = plate_frame()
    top, left, height, width = WINDOW
    paths = []
    for name, finish in (("brushed", DETAIL), ("ground", IMAGE)):
        halves = [
            renderer.render(frame, plate_scene({}, f))[0].rgba[
                top : top + height, left : left + width
            ]
            for f in ({}, {**BRUSHED, **finish})
        ]
        gap = np.ones((height, 4, 4), np.float32)
        image = np.concatenate([halves[0], gap, halves[1]], axis=1)
        path = out / "crops" / f"crop-{name}-plate.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_png(RenderedFrame(image), path)
        paths.append(path)
    return paths
