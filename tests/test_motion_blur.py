"""Motion blur (geometry/motion.py + passes/accumulate.py): a blurred frame against the average
of 64 still renders at positions + v t_i, shutter 0 untouched, huge velocities clamped.

Tolerance: the renderer averages N sub-frames at the midpoints of N equal slices of the shutter,
the reference 64. For one pixel whose value f(t) varies by V over the shutter (total variation),
each slice's midpoint differs from the slice's mean by at most that slice's variation, so
|mean_N - integral| <= V / N and likewise V / 64 for the reference: |error| <= V (1/N + 1/64).
V is measured per pixel from the 64 reference sub-frames (sum of |f_{i+1} - f_i|), and the RMSE
bound is the root mean square of that per-pixel bound.
"""

from __future__ import annotations

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.motion import MAX_STREAK_FRACTION, plan_motion
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

WIDTH, HEIGHT = 128, 96
SHUTTER = 0.02


def spatter_scene(shutter: float) -> Scene:
    return scene_from_dict(
        {
            "image": {"width": WIDTH, "height": HEIGHT},
            "camera": {"eye": [0.0, 0.0, 1.2], "shutter": shutter},
            "particles": {"radius": 0.012},
            "quality": {"filter": "none"},
        }
    )


def spatter(seed: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Thirty hot droplets flying 1-3 m/s: 4-12 px streaks over 20 ms."""
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-0.25, 0.25, (30, 3)) * (1.0, 0.75, 0.5)
    direction = rng.normal(size=(30, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    velocities = (direction * rng.uniform(1.0, 3.0, (30, 1))).astype(np.float32)
    temperatures = rng.uniform(1800.0, 2600.0, 30).astype(np.float32)
    return positions, velocities, temperatures


def premultiplied(rgba: np.ndarray) -> np.ndarray:
    a = np.asarray(rgba, np.float64)
    return np.concatenate([a[..., :3] * a[..., 3:], a[..., 3:]], axis=-1)


def test_blur_matches_the_average_of_64_subframes(renderer: SurfaceRenderer) -> None:
    positions, velocities, temperatures = spatter()
    frame = make_frame(positions, temperatures=temperatures, velocities=velocities)
    blurred, stats = renderer.render(frame, spatter_scene(SHUTTER))
    still = spatter_scene(0.0)
    _, still_stats = renderer.render(frame, still)
    assert stats.notes  # the radius note: once, as for a still, not once per sub-frame
    assert [n.field for n in stats.notes] == [n.field for n in still_stats.notes]
    subframes = []
    for i in range(64):
        t = ((i + 0.5) / 64 - 0.5) * SHUTTER
        moved = make_frame(positions + velocities * t, temperatures=temperatures)
        subframes.append(premultiplied(renderer.render(moved, still)[0].rgba))
    stack = np.stack(subframes)
    reference = stack.mean(axis=0)
    camera = Camera.from_config(still.camera, WIDTH, HEIGHT)
    plan = plan_motion(frame, camera, SHUTTER)
    assert plan is not None and 4 <= len(plan.times) <= 64
    variation = np.abs(np.diff(stack, axis=0)).sum(axis=0)
    bound = np.sqrt(np.mean((variation * (1.0 / len(plan.times) + 1.0 / 64)) ** 2))
    error = np.sqrt(np.mean((premultiplied(blurred.rgba) - reference) ** 2))
    assert error <= bound, (error, bound)
    unblurred = np.sqrt(np.mean((subframes[32] - reference) ** 2))
    assert error < 0.5 * unblurred  # the blur is real: far closer than a still
    assert np.isfinite(blurred.rgba).all()


def test_shutter_zero_and_no_velocities_are_stills(renderer: SurfaceRenderer) -> None:
    positions, velocities, temperatures = spatter()
    moving = make_frame(positions, temperatures=temperatures, velocities=velocities)
    plain = make_frame(positions, temperatures=temperatures)
    still, _ = renderer.render(plain, spatter_scene(0.0))
    closed, _ = renderer.render(moving, spatter_scene(0.0))
    unmoving, _ = renderer.render(plain, spatter_scene(SHUTTER))
    assert np.array_equal(closed.rgba, still.rgba)
    assert np.array_equal(unmoving.rgba, still.rgba)


def test_huge_velocities_are_clamped(renderer: SurfaceRenderer) -> None:
    positions, velocities, temperatures = spatter()
    velocities = velocities * np.float32(1e30)
    frame = make_frame(positions, temperatures=temperatures, velocities=velocities)
    scene = spatter_scene(SHUTTER)
    plan = plan_motion(frame, Camera.from_config(scene.camera, WIDTH, HEIGHT), SHUTTER)
    assert plan is not None and len(plan.times) == 32  # 0.25 x 128 px
    assert plan.longest_streak_px <= MAX_STREAK_FRACTION * WIDTH + 1e-9
    assert np.isfinite(plan.velocities).all()
    blurred, stats = renderer.render(frame, scene, depth=True)
    assert np.isfinite(blurred.rgba).all() and blurred.rgba[..., 3].max() > 0.0
    assert "motion" in stats.stage_ms
