"""Rendered depth, normals and coverage against analytic ground truth (real EGL context).

Tolerances:
* Exact geometry (one particle, no filter): the impostor's depth is a float32 ray-sphere
  intersection, so |dz| <= 1e-4 r; coverage is decided at pixel centres by the same test in
  numpy and GLSL, so the masks are identical. One-sided differences over one pixel measure the
  slope half a pixel off-centre: per image axis the normal is off by 0.5 / (R_px cos(theta))
  radians (R_px = projected radius, theta = angle between normal and view), at most sqrt(2) x
  that over both axes. Averaged over the projected disc with cos(theta) >= 0.3 the mean of
  1 / cos(theta) is 2 (1 - 0.3) / 0.91 = 1.54, so mean <= 1.54 sqrt(2) atan(0.5 / R_px) and
  max <= sqrt(2) * 0.5 / (0.3 R_px).
* Smoothed surfaces (ball, slab): the issue fixes the default preset's bounds on the 90k ball
  (mean <= 3 deg, p95 <= 8 deg, IoU >= 0.97). Per filter, the bounds are the values measured on
  llvmpipe with these seeds (in the comments) plus ~30%, so a regression of a few tenths of a
  degree is caught while another GL driver's rounding is not.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from sphrender.client.frame import make_frame
from sphrender.server.bench.analytic import (
    angle_deg,
    ball_errors,
    reconstruct_world_positions,
    sphere_hits,
)
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

BALL_PARTICLE_RADIUS = 0.01
BALL_RADIUS = 0.556  # ~90k particles at lattice spacing 2r
OFFSET = np.array([1e5, 1e5, -1e5])


def ball_scene(offset: np.ndarray | None = None, **quality: Any) -> Scene:
    shift = np.zeros(3) if offset is None else offset
    return scene_from_dict(
        {
            "image": {"width": 640, "height": 360},
            "camera": {
                "eye": list(np.array([1.3, 1.0, 1.7]) + shift),
                "target": list(shift),
                "fov_y": 40.0,
            },
            "particles": {"radius": BALL_PARTICLE_RADIUS},
            "quality": quality,
        }
    )


@pytest.fixture(scope="module")
def ball() -> np.ndarray:
    return jittered_lattice_ball(BALL_RADIUS, BALL_PARTICLE_RADIUS, seed=0)


def render_ball_errors(
    renderer: SurfaceRenderer, positions: np.ndarray, scene: Scene, center: np.ndarray
) -> Any:
    frame, stats = renderer.render(make_frame(positions), scene, depth=True, normals=True)
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    errors = ball_errors(frame, camera, center, BALL_RADIUS + BALL_PARTICLE_RADIUS)
    print(f"{scene.quality.filter}: {errors}; {stats.stage_ms}")
    return errors


def test_default_quality_on_90k_ball_meets_issue_bounds(
    renderer: SurfaceRenderer, ball: np.ndarray
) -> None:
    assert 85_000 < len(ball) < 95_000
    errors = render_ball_errors(renderer, ball, ball_scene(), np.zeros(3))  # 1.65 / 4.19 / 0.982
    assert errors.evaluated_pixels > 30_000
    assert errors.mean_deg <= 3.0
    assert errors.p95_deg <= 8.0
    assert errors.silhouette_iou >= 0.97


def test_ball_far_from_origin_gives_the_same_figures(
    renderer: SurfaceRenderer, ball: np.ndarray
) -> None:
    near = render_ball_errors(renderer, ball, ball_scene(), np.zeros(3))
    far = render_ball_errors(renderer, ball + OFFSET, ball_scene(OFFSET), OFFSET)
    assert far.mean_deg <= 3.0 and far.p95_deg <= 8.0 and far.silhouette_iou >= 0.97
    assert abs(far.mean_deg - near.mean_deg) < 0.02
    assert abs(far.p95_deg - near.p95_deg) < 0.05
    assert abs(far.silhouette_iou - near.silhouette_iou) < 1e-3


def test_ball_renders_identically_after_translation(
    renderer: SurfaceRenderer, ball: np.ndarray
) -> None:
    """Float64 eye-relative positions: at 1e5 the float32 images agree to float32 noise of the
    eye-relative values (~1e-7 relative), not to float32 noise of 1e5 (~1e-2 absolute)."""
    a, _ = renderer.render(make_frame(ball), ball_scene(), depth=True, normals=True)
    b, _ = renderer.render(make_frame(ball + OFFSET), ball_scene(OFFSET), depth=True, normals=True)
    assert a.depth is not None and b.depth is not None and a.normals is not None
    assert b.normals is not None
    assert np.array_equal(np.isfinite(a.depth), np.isfinite(b.depth))
    surface = np.isfinite(a.depth)
    assert np.abs(a.depth[surface] - b.depth[surface]).max() < 1e-5
    assert np.abs(a.normals - b.normals).max() < 1e-3


# filter -> (mean, p95) bounds; measured on llvmpipe in the comment
PER_FILTER_BALL_BOUNDS: dict[str, tuple[dict[str, Any], float, float]] = {
    "narrow_range": ({}, 2.2, 5.4),  # 1.65 / 4.19
    "narrow_range-2d": ({"separable": False}, 2.1, 5.2),  # 1.57 / 3.93
    "bilateral": ({}, 3.4, 9.2),  # 2.57 / 7.11
    "gaussian": ({}, 3.4, 14.1),  # 2.55 / 10.89 (background-renormalised edges)
}


@pytest.mark.parametrize("name", list(PER_FILTER_BALL_BOUNDS))
def test_each_filter_on_ball(renderer: SurfaceRenderer, ball: np.ndarray, name: str) -> None:
    extra, mean_bound, p95_bound = PER_FILTER_BALL_BOUNDS[name]
    scene = ball_scene(filter=name.removesuffix("-2d"), **extra)
    errors = render_ball_errors(renderer, ball, scene, np.zeros(3))
    assert errors.mean_deg <= mean_bound
    assert errors.p95_deg <= p95_bound
    assert errors.silhouette_iou >= 0.97


def test_unsmoothed_ball_is_far_from_the_bounds(
    renderer: SurfaceRenderer, ball: np.ndarray
) -> None:
    """The ball metric can fail: raw sphere impostors are bumpy (measured 41.6 deg mean)."""
    errors = render_ball_errors(renderer, ball, ball_scene(filter="none"), np.zeros(3))
    assert errors.mean_deg > 20.0


def single_particle_scene(filter_name: str, radius: float = 0.05) -> Scene:
    return scene_from_dict(
        {
            "image": {"width": 200, "height": 150},
            "camera": {"eye": [0.2, 0.15, 0.45], "target": [0.02, 0.01, 0.0], "fov_y": 30.0},
            "particles": {"radius": radius},
            # The filters themselves are under test: the lone particle is not split off as a
            # droplet (that path is tests/test_surfaces.py's).
            "quality": {"filter": filter_name, "exact_droplets": False},
        }
    )


def test_one_particle_is_an_exact_sphere_without_filter(renderer: SurfaceRenderer) -> None:
    r = 0.05
    scene = single_particle_scene("none", r)
    frame, _ = renderer.render(make_frame(np.zeros((1, 3))), scene, depth=True, normals=True)
    camera = Camera.from_config(scene.camera, 200, 150)
    hit, true_depth = sphere_hits(camera, np.zeros(3), r)
    assert frame.depth is not None
    covered = np.isfinite(frame.depth)  # a surface at the pixel centre (alpha is sub-pixel)
    assert hit.sum() > 2000
    assert np.array_equal(covered, hit)
    assert frame.depth is not None
    assert np.abs(frame.depth[hit] - true_depth[hit]).max() <= 1e-4 * r
    assert np.all(np.isinf(frame.depth[~hit]))
    radius_px = camera.projected_radius_px(r, float(np.linalg.norm(camera.eye)))
    mean_bound = 1.54 * math.sqrt(2.0) * math.degrees(math.atan(0.5 / radius_px))
    max_bound = math.degrees(math.sqrt(2.0) * 0.5 / (0.3 * radius_px))
    errors = ball_errors(frame, camera, np.zeros(3), r)
    print(errors, f"bounds: mean {mean_bound:.2f}, max {max_bound:.2f}")  # 1.61 / 2.85 measured
    assert errors.mean_deg <= mean_bound
    assert errors.max_deg <= max_bound


def test_one_particle_keeps_its_outline_under_default_filter(renderer: SurfaceRenderer) -> None:
    """Filters change depth, never coverage: the isolated particle is still the disc of a sphere
    of radius r, and its depth moves by less than r (measured 0.42 r)."""
    r = 0.05
    scene = single_particle_scene("narrow_range", r)
    frame, _ = renderer.render(make_frame(np.zeros((1, 3))), scene, depth=True, normals=True)
    camera = Camera.from_config(scene.camera, 200, 150)
    hit, true_depth = sphere_hits(camera, np.zeros(3), r)
    assert frame.depth is not None
    assert np.array_equal(np.isfinite(frame.depth), hit)  # coverage at pixel centres
    assert np.abs(frame.depth[hit] - true_depth[hit]).max() < 0.6 * r


@pytest.mark.parametrize(
    ("filter_name", "mean_bound", "p95_bound"),
    # measured: narrow_range 0.43 / 0.95, bilateral 3.03 / 21.7, gaussian 3.06 / 22.0. Where the
    # view runs along the lattice rows, rays slip between spheres into lower layers (a brute-force
    # ray cast agrees pixel for pixel); only the narrow-range filter drops those far samples.
    [("narrow_range", 0.6, 1.3), ("bilateral", 4.0, 28.0), ("gaussian", 4.0, 28.0)],
)
def test_slab_normals_point_up(
    renderer: SurfaceRenderer, filter_name: str, mean_bound: float, p95_bound: float
) -> None:
    """A 3-layer lattice slab seen obliquely: normals -> +y away from the slab's edges."""
    r = 0.01
    positions = lattice_slab(1.0, 1.0, 3, r)
    scene = scene_from_dict(
        {
            "image": {"width": 320, "height": 180},
            "camera": {"eye": [0.2, 0.5, 0.6], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
            "particles": {"radius": r},
            "quality": {"filter": filter_name},
        }
    )
    frame, _ = renderer.render(make_frame(positions), scene, depth=True, normals=True)
    camera = Camera.from_config(scene.camera, 320, 180)
    world = reconstruct_world_positions(frame, camera)
    assert frame.normals is not None
    assert frame.depth is not None
    covered = np.isfinite(frame.depth)
    interior = covered & (np.abs(world[..., 0]) < 0.3) & (np.abs(world[..., 2]) < 0.3)
    assert interior.sum() > 10_000
    errors = angle_deg(frame.normals[interior].astype(np.float64), np.array([0.0, 1.0, 0.0]))
    print(filter_name, errors.mean(), np.percentile(errors, 95))
    assert errors.mean() <= mean_bound
    assert np.percentile(errors, 95) <= p95_bound


def test_per_particle_radii_override_scene_radius(renderer: SurfaceRenderer) -> None:
    scene = replace(single_particle_scene("none", 0.05))
    small = make_frame(np.zeros((1, 3)), radii=np.array([0.02]))
    frame, _ = renderer.render(small, scene, depth=True)
    camera = Camera.from_config(scene.camera, 200, 150)
    hit, _ = sphere_hits(camera, np.zeros(3), 0.02)
    assert frame.depth is not None
    assert np.array_equal(np.isfinite(frame.depth), hit)
