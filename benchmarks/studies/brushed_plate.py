"""The brushed plate: what the `[finish]` section costs and how it looks (the repository's
REPORT.md). A flat plate of lattice particles (three layers, 12k particles) under the workshop
environment and one point light, seen obliquely at 960x540 with the balanced preset; frame
times for the finish off, the anisotropic lobe, the surface detail, and both (and sampled IBL,
which pays the anisotropic lobe per sample), measured interleaved in one run, with their ratio
to off. A before/after crop shows the plate off and with both.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, read_scene_toml, scene_from_dict

RADIUS = 0.01
EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "brushed_plate.toml"
BRUSHED = {"anisotropy": 0.8, "brush_direction": [1.0, 0.0, 0.0]}
DETAIL = {
    "detail": "brushed",
    "detail_scale": 0.004,
    "detail_normal_strength": 0.2,
    "detail_roughness_strength": 0.1,
}
#: Per measured setting: name, the scene's [shading] over the balanced preset, its [finish].
SAMPLED = {"ibl_mode": "sampled", "ibl_samples": 64}
SETTINGS: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("prefiltered, finish off", {}, {}),
    ("prefiltered, anisotropic", {}, BRUSHED),
    ("prefiltered, detail", {}, DETAIL),
    ("prefiltered, anisotropic + detail", {}, {**BRUSHED, **DETAIL}),
    ("sampled 64, finish off", SAMPLED, {}),
    ("sampled 64, anisotropic", SAMPLED, BRUSHED),
]
#: The crop of the 960x540 image, (top, left, height, width): the highlight and the far edge.
WINDOW = (90, 300, 300, 360)


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
        "### Brushed plate: what the finish costs",
        "",
        "A flat plate of lattice particles (3 layers, 12k particles, r = 0.01) under the workshop "
        "environment and a point light, 960x540, seen obliquely ([examples/brushed_plate.toml]"
        "(../examples/brushed_plate.toml)). Anisotropic: `finish.anisotropy` 0.8; detail: "
        "`finish.detail` brushed (normal and roughness); balanced preset, IBL prefiltered or "
        "sampled with 64 samples. The fastest of interleaved frames; the ratio is to the same "
        "IBL mode with the finish off.",
        "",
        "| setting | frame ms | / off | normals + shade ms | / off | shade ms | / off |",
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
    ]
    return lines


def write_crop(renderer: SurfaceRenderer, out: Path) -> Path:
    """Finish off (left) and anisotropic + detail (right), side by side, as
    `out / crops / crop-brushed-plate.png`."""
    from sphrender.server.output.encoders import write_png

    frame = plate_frame()
    top, left, height, width = WINDOW
    halves = [
        renderer.render(frame, plate_scene({}, finish))[0].rgba[
            top : top + height, left : left + width
        ]
        for finish in ({}, {**BRUSHED, **DETAIL})
    ]
    gap = np.ones((height, 4, 4), np.float32)
    image = np.concatenate([halves[0], gap, halves[1]], axis=1)
    path = out / "crops" / "crop-brushed-plate.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(RenderedFrame(image), path)
    return path
