"""Shadow cost per light and error against the ray-traced truth, for REPORT.md ("Shadows").

Cost: the ball over the plate (server/bench/shadow_scene.py) at 2 x 2 x the particles of the
tests' scene, 320 x 320, median of timed frames after a warm-up; each light with shadows against
the same light without, measured in the same run. Error: the tests' scene (160 x 160, r 0.05) at
each map size: IoU of the plate's shadow against the truth (point, directional) and the
penumbra's full width against similar triangles (sphere).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from sphrender.core.frame import ParticleFrame
from sphrender.server.bench.shadow_scene import BallOverPlate, penumbra, render_both, shadow_iou
from sphrender.server.engine.renderer import SurfaceRenderer

TRAVEL = [0.4, -1.0, 0.5]
LIGHTS: dict[str, dict[str, Any]] = {
    "point": {"type": "point", "position": [-0.5, 3.0, -0.7], "intensity": 8.0},
    "sphere r 0.35": {
        "type": "sphere",
        "position": [0.0, 3.0, 0.0],
        "radius": 0.35,
        "intensity": 8.0,
    },
    "directional": {"type": "directional", "direction": TRAVEL, "intensity": 3.0},
    "sun 8 deg": {
        "type": "directional",
        "direction": [0.0, -1.0, 0.0],
        "angular_radius_deg": 8.0,
        "intensity": 3.0,
    },
}
MAP_SIZES = (256, 512, 1024)


def frame_ms(
    renderer: SurfaceRenderer, setup: BallOverPlate, lights: list[dict[str, Any]], frames: int
) -> tuple[float, float]:
    """Median wall ms of a frame and of its shadow stage."""
    plain, _, stage = paired_ms(renderer, setup, lights, lights, frames)
    return plain, stage


def paired_ms(
    renderer: SurfaceRenderer,
    setup: BallOverPlate,
    first: list[dict[str, Any]],
    second: list[dict[str, Any]],
    frames: int,
) -> tuple[float, float, float]:
    """Median wall ms of frames under lights `first` and `second`, drawn alternately (so both
    see the same load on a shared machine), and of the second's shadow stage."""
    frame = ParticleFrame(setup.positions())
    scenes = (setup.scene(first), setup.scene(second))
    for scene in scenes:
        renderer.render(frame, scene)
    walls: tuple[list[float], list[float]] = ([], [])
    stages = []
    for _ in range(frames):
        for k, scene in enumerate(scenes):
            start = time.perf_counter()
            _, stats = renderer.render(frame, scene)
            walls[k].append((time.perf_counter() - start) * 1e3)
        stages.append(stats.stage_ms.get("shadow", 0.0))
    return float(np.median(walls[0])), float(np.median(walls[1])), float(np.median(stages))


def error(renderer: SurfaceRenderer, name: str, size: int) -> str:
    light = dict(LIGHTS[name], shadow_map_size=size)
    if light["type"] == "sphere":
        setup = BallOverPlate(ball_y=1.2)
        found = penumbra(render_both(renderer, light, setup), 3.0, 0.35, 1.2, setup.radius)
        return f"penumbra width {100 * found.error:+.1f} %"
    if light.get("angular_radius_deg"):
        setup = BallOverPlate(ball_y=1.2, turned=True)
        disc = 1e3 * np.tan(np.radians(light["angular_radius_deg"]))
        found = penumbra(render_both(renderer, light, setup), 1e3, disc, 1.2, setup.radius)
        return f"penumbra width {100 * found.error:+.1f} %"
    setup = BallOverPlate()
    result = render_both(renderer, light, setup)
    if light["type"] == "directional":
        travel = np.asarray(TRAVEL) / np.linalg.norm(TRAVEL)
        target = result.world - 10.0 * travel
    else:
        target = np.asarray(light["position"], dtype=np.float64)
    score, _ = shadow_iou(result, target, setup.radius)
    return f"IoU {score:.4f}"


def shadows_section(
    renderer: SurfaceRenderer, frames: int = 7, log: Callable[[str], None] = print
) -> list[str]:
    heavy = BallOverPlate(radius=0.025, size=320)
    particles = heavy.positions().shape[0]
    lines = [
        "## Shadows",
        "",
        f"Ball over plate, {particles:,} particles, 320x320, median of {frames} frames "
        "(`benchmarks/bench_shadows.py`; llvmpipe on 2 shared cores unless noted). Cost: the "
        "same light without and with shadows, frames alternating; error: the tests' scene "
        "(tests/test_shadows.py) against the ray-traced truth at each map size.",
        "",
        "| light | map | frame ms, no shadows | with shadows | ratio | shadow stage ms | error |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, light in LIGHTS.items():
        for size in MAP_SIZES:
            log(f"shadows: {name}, map {size}")
            shadowed = dict(light, shadows=True, shadow_map_size=size)
            plain, wall, stage = paired_ms(renderer, heavy, [light], [shadowed], frames)
            lines.append(
                f"| {name} | {size} | {plain:.1f} | {wall:.1f} | {wall / plain:.2f} | "
                f"{stage:.1f} | {error(renderer, name, size)} |"
            )
    return [*lines, ""]
