"""Glare and motion blur: each one's cost and error (REPORT.md, "Glare and motion blur").

* Glare on the built-in demo (the weld bead, its scene's exposure): the frame time with and
  without, the light conserved (sum of premultiplied RGB after / before), and the L1 distance of
  the glared image to a numpy FFT convolution of the same excess light with Spencer et al.'s PSF,
  per unit of spread light, beside the bound the pyramid fit guarantees (`PyramidFit.l1_bound`).
* Motion blur on hot spatter (droplets flying 1-3 m/s, 20 ms shutter): the frame time with and
  without, the number of sub-frames, and the RMSE to the average of 64 still renders at
  positions + v t_i, beside the bound tests/test_motion_blur.py derives (V (1/N + 1/64)).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.signal import fftconvolve

from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.content.demo import demo_frame, demo_scene_dict
from sphrender.server.engine.geometry import motion
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.passes.glare_psf import (
    degrees_per_pixel,
    fit_pyramid,
    level_count,
    psf_kernel,
)
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import render_for_output
from sphrender.server.scene import Scene, scene_from_dict

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
SHUTTER = 0.02


@dataclass(frozen=True)
class Row:
    feature: str
    scene: str
    off_ms: float
    on_ms: float
    error: str
    bound: str


def _best_ms(render: Callable[[], object], frames: int) -> float:
    """The best of `frames` timed frames after a warm-up (the machine is shared: the best is
    what the work costs, the others what the neighbours cost)."""
    render()  # warm-up: programs, targets, fits
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        render()
        times.append((time.perf_counter() - start) * 1e3)
    return min(times)


def _premultiplied(rgba: np.ndarray) -> np.ndarray:
    a = np.asarray(rgba, np.float64)
    return np.concatenate([a[..., :3] * a[..., 3:], a[..., 3:]], axis=-1)


def glare_row(renderer: SurfaceRenderer, width: int, height: int, frames: int) -> Row:
    data = demo_scene_dict()
    data["image"] = {"width": width, "height": height}
    plain = scene_from_dict(data)
    glare = scene_from_dict({**data, "glare": {"enabled": True, "exr": True}})
    frame = demo_frame()
    off = _best_ms(lambda: render_for_output(renderer, frame, plain, "png"), frames)
    on = _best_ms(lambda: render_for_output(renderer, frame, glare, "png"), frames)
    before = _premultiplied(render_for_output(renderer, frame, plain, "exr")[0].rgba)[..., :3]
    after = _premultiplied(render_for_output(renderer, frame, glare, "exr")[0].rgba)[..., :3]
    scale = 2.0**plain.output.exposure
    y = before @ LUMINANCE
    threshold = glare.glare.threshold / scale
    kept = np.where(y > threshold, threshold / np.maximum(y, 1e-300), 1.0)
    spread = before * (1.0 - kept)[..., None]
    deg = degrees_per_pixel(plain.camera.fov_y, height)
    fit = fit_pyramid(round(deg, 9), level_count(deg, width, height))
    kernel = psf_kernel(deg)
    reference = before - spread
    reference += np.stack([fftconvolve(spread[..., c], kernel, mode="same") for c in range(3)], -1)
    l1 = np.abs(after - reference).sum() / max(spread.sum(), 1e-300)
    kept_light = after.sum() / before.sum()
    return Row(
        "glare",
        f"demo {width}x{height}, {spread.sum() / before.sum():.1%} of the light spread",
        off,
        on,
        f"L1 {l1:.3f} of spread light; light kept {kept_light:.4f}",
        f"L1 {fit.l1_bound:.3f}",
    )


def spatter_frame(seed: int = 4, count: int = 60) -> ParticleFrame:
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-0.25, 0.25, (count, 3)) * (1.0, 0.6, 0.4)
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    velocities = (direction * rng.uniform(1.0, 3.0, (count, 1))).astype(np.float32)
    temperatures = rng.uniform(1800.0, 2600.0, count).astype(np.float32)
    return make_frame(positions, temperatures=temperatures, velocities=velocities)


def _spatter_scene(width: int, height: int, shutter: float) -> Scene:
    return scene_from_dict(
        {
            "image": {"width": width, "height": height},
            "camera": {"eye": [0.0, 0.0, 1.0], "shutter": shutter},
            "particles": {"radius": 0.008},
        }
    )


def motion_rows(renderer: SurfaceRenderer, width: int, height: int, frames: int) -> list[Row]:
    """One row per sub-frame spacing (1 px is the product's; 2 and 4 px what coarser would
    give), against one 64-sub-frame reference."""
    frame = spatter_frame()
    assert frame.velocities is not None
    still, blurred = _spatter_scene(width, height, 0.0), _spatter_scene(width, height, SHUTTER)
    off = _best_ms(lambda: renderer.render(frame, still), frames)
    subframes = []
    for i in range(64):
        t = ((i + 0.5) / 64 - 0.5) * SHUTTER
        moved = make_frame(frame.positions + frame.velocities * t, temperatures=frame.temperatures)
        subframes.append(_premultiplied(renderer.render(moved, still)[0].rgba))
    stack = np.stack(subframes)
    reference = stack.mean(axis=0)
    variation = np.abs(np.diff(stack, axis=0)).sum(axis=0)
    still_rmse = np.sqrt(np.mean((subframes[32] - reference) ** 2))
    camera = Camera.from_config(still.camera, width, height)
    rows = []
    product = motion.SUBFRAME_SPACING_PX
    try:
        for spacing in (1.0, 2.0, 4.0):
            motion.SUBFRAME_SPACING_PX = spacing
            on = _best_ms(lambda: renderer.render(frame, blurred), frames)
            got = _premultiplied(renderer.render(frame, blurred)[0].rgba)
            plan = motion.plan_motion(frame, camera, SHUTTER)
            assert plan is not None
            count = len(plan.times)
            bound = np.sqrt(np.mean((variation * (1.0 / count + 1.0 / 64)) ** 2))
            rmse = np.sqrt(np.mean((got - reference) ** 2))
            rows.append(
                Row(
                    f"motion blur, {spacing:.0f} px apart" + (" (product)" if spacing == 1 else ""),
                    f"{frame.count} hot droplets, {width}x{height}, {count} sub-frames "
                    f"(streaks up to {plan.longest_streak_px:.0f} px)",
                    off,
                    on,
                    f"RMSE {rmse:.3g} (a still: {still_rmse:.3g})",
                    f"RMSE {bound:.3g}",
                )
            )
    finally:
        motion.SUBFRAME_SPACING_PX = product
    return rows


def post_effects_section(rows: list[Row]) -> list[str]:
    lines = [
        "## Glare and motion blur: cost and error",
        "",
        "Frame times in one run, best of 3 after a warm-up "
        "(benchmarks/studies/post_effects.py). Glare's error is against a numpy FFT "
        "convolution with Spencer et al.'s 1995 photopic PSF; motion blur's "
        "against the average of 64 still renders at positions + v t_i (tests/test_glare.py, "
        "tests/test_motion_blur.py derive the bounds).",
        "",
        "| feature | scene | off ms | on ms | on / off | error | bound |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.feature} | {r.scene} | {r.off_ms:.1f} | {r.on_ms:.1f} | "
            f"{r.on_ms / r.off_ms:.2f}x | {r.error} | {r.bound} |"
        )
    return lines


def run_post_effects(
    renderer: SurfaceRenderer, width: int, height: int, frames: int = 3
) -> list[str]:
    return post_effects_section(
        [
            glare_row(renderer, width, height, frames),
            *motion_rows(renderer, width // 2, height // 2, frames),
        ]
    )
