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
  (mean <= 3 deg, p95 <= 8 deg, IoU >= 0.97), in `analytic_scenes.ball_errors`, which compares
  normals with the radial direction at the *rendered* point and so cannot see depth. The tighter
  bounds use `reference_surfaces.sphere_errors`: each pixel's ray meets the true sphere
  (radius R + r), the normal is compared with the true normal there and the depth with the true
  depth. Bound = the value on jitter seed 0 + 4 standard deviations of that value over jitter
  seeds 0-7 (measured on llvmpipe, in BALL_TRUTH_BOUNDS and DEFAULT_TRUTH_BOUNDS): the
  lattice's random jitter moves the figures by that much without any change in quality, so a
  smaller margin would judge the seed;
  a real regression (a Gaussian half as wide, kernel_scale 1: mean 2.23 -> 5.49 deg; normals
  from the forward difference, measured before the narrow range averaged inverse depth:
  2.34 -> 2.59 deg) moves them by 9-100 standard deviations. (Other GL drivers were
  not measured; a driver's float rounding changes depths at the 1e-6 level, far below what a
  jitter seed does.) The depth error of the default preset is 2.8 r, behind the true sphere
  (signed mean asserted positive): every particle centre is inside R, so the union of spheres
  is inside R + r (its bumps lie 2.35 r deep on average unfiltered; the narrow-range filter
  adds 0.48 r).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np
import pytest
from reference_surfaces import SphereErrors, sphere_errors, sphere_truth

from sphrender.core.frame import make_frame
from sphrender.server.bench.analytic import (
    SurfaceErrors,
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


def render_ball(
    renderer: SurfaceRenderer, positions: np.ndarray, scene: Scene, center: np.ndarray
) -> tuple[SurfaceErrors, SphereErrors]:
    """Both metrics of one render: `ball_errors` (the issue's) and `sphere_errors` (true hit)."""
    frame, stats = renderer.render(make_frame(positions), scene, depth=True, normals=True)
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    surface = BALL_RADIUS + BALL_PARTICLE_RADIUS
    errors = ball_errors(frame, camera, center, surface)
    truth = sphere_errors(frame, camera, center, surface, BALL_PARTICLE_RADIUS)
    print(f"{scene.quality.filter}: {errors}; true sphere: {truth}; {stats.stage_ms}")
    return errors, truth


def render_ball_errors(
    renderer: SurfaceRenderer, positions: np.ndarray, scene: Scene, center: np.ndarray
) -> SurfaceErrors:
    return render_ball(renderer, positions, scene, center)[0]


class TruthBounds(NamedTuple):
    """Upper bounds on `SphereErrors` (see the module docstring for the derivation)."""

    normal_mean_deg: float
    normal_p95_deg: float
    depth_mean_radii: float
    depth_p95_radii: float

    def check(self, errors: SphereErrors) -> None:
        assert errors.normal_mean_deg <= self.normal_mean_deg, errors
        assert errors.normal_p95_deg <= self.normal_p95_deg, errors
        assert errors.depth_mean_radii <= self.depth_mean_radii, errors
        assert errors.depth_p95_radii <= self.depth_p95_radii, errors
        # Nothing lies in front of the true sphere (module docstring): the render is behind it.
        assert errors.depth_bias_radii > 0.0, errors


# filter -> bounds on the true-sphere metric: seed 0 + 4 sd over jitter seeds 0-7, rounded up to
# 0.05. Measured on llvmpipe (seed 0 / sd): normal mean, normal p95 (deg), depth mean, p95 (r).
# The filters are measured with normals from the 1-pixel differences (normal_stencil = 0, the
# default smooth normal_rules) and without the crease test (tests/test_filters.py has its own).
BALL_TRUTH_BOUNDS: dict[str, TruthBounds] = {
    # 2.379/0.027, 4.577/0.082, 2.820/0.005, 4.968/0.029
    "narrow_range": TruthBounds(2.5, 4.95, 2.85, 5.1),
    # 2.335/0.028, 4.321/0.048, 2.807/0.005, 4.926/0.026
    "narrow_range-2d": TruthBounds(2.45, 4.55, 2.85, 5.05),
    # 2.285/0.025, 5.683/0.107, 2.530/0.005, 3.480/0.016
    "bilateral": TruthBounds(2.4, 6.15, 2.55, 3.55),
    # 2.567/0.024, 6.282/0.132, 2.690/0.005, 3.988/0.010
    "gaussian": TruthBounds(2.7, 6.85, 2.75, 4.05),
}

# The default preset (narrow range, normals over a 1-radius stencil of at most 2 px), derived
# alike: 2.384/0.027, 4.585/0.083, 2.820/0.005, 4.968/0.029. The true-hit normal error is not
# the issue's metric (1.47 deg here): the rendered surface lies 2.8 r behind the true sphere, so
# even its exact normals (the radial direction at the rendered point) are 2.12 deg off the true
# hit's on average, and a rule that leans normals towards the viewer hides part of that offset.
# The hard normal_rules' 1-pixel difference (the smaller one-sided slope) does: on seed 0 it
# reads 2.17 deg on this metric against the smooth rules' 2.38, while on the issue's metric it
# is the worse (1.59 / 3.91 against 1.50 / 3.79 deg).
DEFAULT_TRUTH_BOUNDS = TruthBounds(2.5, 4.95, 2.85, 5.1)


def test_default_quality_on_90k_ball_meets_issue_bounds(
    renderer: SurfaceRenderer, ball: np.ndarray
) -> None:
    """The issue's bounds on its metric, then the default preset against the true sphere:
    normals at the true hit and depth after filtering (DEFAULT_TRUTH_BOUNDS)."""
    assert 85_000 < len(ball) < 95_000
    errors, truth = render_ball(renderer, ball, ball_scene(), np.zeros(3))  # 1.48 / 3.75 / 0.982
    assert errors.evaluated_pixels > 30_000
    assert errors.mean_deg <= 3.0
    assert errors.p95_deg <= 8.0
    assert errors.silhouette_iou >= 0.97
    assert truth.pixels > 30_000
    DEFAULT_TRUTH_BOUNDS.check(truth)


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


@pytest.mark.parametrize("name", list(BALL_TRUTH_BOUNDS))
def test_each_filter_on_ball(renderer: SurfaceRenderer, ball: np.ndarray, name: str) -> None:
    extra: dict[str, Any] = {"separable": False} if name.endswith("-2d") else {}
    scene = ball_scene(
        filter=name.removesuffix("-2d"), normal_stencil=0.0, crease_angle=0.0, **extra
    )
    errors, truth = render_ball(renderer, ball, scene, np.zeros(3))
    assert errors.silhouette_iou >= 0.97
    BALL_TRUTH_BOUNDS[name].check(truth)


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


@pytest.mark.parametrize(
    ("quality", "ratio_bound", "floor_deg"),
    [
        ({}, 3.0, 0.0),
        ({"separable": False, "iterations": 1}, 6.0, 0.0),
        ({"filter": "gaussian"}, 0.0, 6.0),
        ({"filter": "bilateral"}, 0.0, 6.0),
    ],
    ids=["default", "narrow-range-2d", "gaussian", "bilateral"],
)
def test_slab_filling_the_image_is_as_smooth_at_the_image_edges_as_inside(
    renderer: SurfaceRenderer, quality: dict[str, Any], ratio_bound: float, floor_deg: float
) -> None:
    """A pool close-up: a lattice slab covers the bottom, left and right ends of the image. The
    kernels there reach past the image; they go on one-sided and fit a line through the values
    inside. Before, the narrow range dropped those taps with their mirrors, which left the
    edge pixels unsmoothed (21 deg mean error within 3 px of those ends, 28 deg for the 2-D
    kernel, against 0.36 deg inside), and the Gaussian and bilateral filters took a one-sided
    mean, which lies off the slope (23 deg). Bounds: a one-sided local-linear fit's intercept
    has about 4x the variance of a centred mean over the same kernel (a boundary kernel), so
    about 2x the normal error: measured 0.64 vs 0.35 deg (1.8x) with the default quality,
    1.59 vs 0.39 deg (4.1x) for one 2-D pass, which fits in both axes at a corner. The Gaussian
    and bilateral filters average z, which curves over a plane in perspective (z = z0 + b k +
    c k^2 across a kernel): a centred mean is off by +c sigma^2, a one-sided fit's intercept by
    -0.75 c sigma^2 (the half-Gaussian's moments), and that change over the last rows tilts the
    normals: measured 3.9 and 4.0 deg, bound 6."""
    r = 0.01
    scene = scene_from_dict(
        {
            "image": {"width": 320, "height": 180},
            "camera": {"eye": [0.0, 0.3, 0.3], "target": [0.0, 0.0, -0.1], "fov_y": 40.0},
            "particles": {"radius": r},
            "quality": quality,
        }
    )
    positions = lattice_slab(1.0, 1.0, 3, r)
    frame, _ = renderer.render(make_frame(positions), scene, depth=True, normals=True)
    assert frame.normals is not None and frame.depth is not None
    covered = np.isfinite(frame.depth)
    error = np.full(covered.shape, np.nan)
    error[covered] = angle_deg(frame.normals[covered].astype(np.float64), np.array([0.0, 1, 0]))
    edges = np.zeros_like(covered)
    edges[-3:, :] = edges[:, :3] = edges[:, -3:] = True
    edges[:40] = False  # the slab's far rim crosses the image's top rows
    inside = np.zeros_like(covered)
    inside[40:-40, 40:-40] = True
    assert (edges & covered).sum() > 0.95 * edges.sum(), "the slab must cover those ends"
    edge_mean, inside_mean = np.nanmean(error[edges]), np.nanmean(error[inside])
    print(quality, f"edges {edge_mean:.2f} deg, inside {inside_mean:.2f} deg")
    assert edge_mean <= max(ratio_bound * inside_mean, floor_deg)


def test_spread_taps_keep_a_close_up_as_smooth_as_the_full_kernel(
    renderer: SurfaceRenderer,
) -> None:
    """A pool close-up whose kernel (3 sigma = 6 projected radii, ~42 px here) is longer than
    kernel_max_px = 14: a hard cap shrinks sigma to a third and leaves the lattice's ripple
    (measured inside: 0.45 deg mean, 1.06 p95, against the uncapped kernel's 0.35 / 0.59);
    every pixel out to the cap and every 3rd beyond it keeps the uncapped kernel's sigma at
    14 + 9 taps per side, and its error (0.35 / 0.64). Bounds: the spread taps only
    resample the Gaussian's tail (past 1 sigma, 3 px apart at sigma 14 px, where the ripple's
    period is 2 r = 14 px), so within 10 % of the uncapped mean and 20 % of its p95; the cap's
    p95 at least 1.5x the uncapped's shows the scene is one where a cap loses."""
    r = 0.01
    positions = lattice_slab(1.0, 1.0, 3, r)

    def inside_errors(quality: dict[str, Any]) -> np.ndarray:
        scene = scene_from_dict(
            {
                "image": {"width": 320, "height": 180},
                "camera": {"eye": [0.0, 0.3, 0.3], "target": [0.0, 0.0, -0.1], "fov_y": 40.0},
                "particles": {"radius": r},
                "quality": quality,
            }
        )
        frame, _ = renderer.render(make_frame(positions), scene, depth=True, normals=True)
        assert frame.normals is not None and frame.depth is not None
        inside = np.zeros(frame.depth.shape, bool)
        inside[40:-40, 40:-40] = True  # >= 40 px from the image's ends: the spread taps' room
        inside &= np.isfinite(frame.depth)
        assert inside.sum() > 0.95 * 240 * 100
        return angle_deg(frame.normals[inside].astype(np.float64), np.array([0.0, 1.0, 0.0]))

    full = inside_errors({"kernel_max_px": 64, "kernel_max_stride": 1})
    capped = inside_errors({"kernel_max_px": 14, "kernel_max_stride": 1})
    spread = inside_errors({"kernel_max_px": 14, "kernel_max_stride": 3})
    stats = [(e.mean(), np.percentile(e, 95)) for e in (full, capped, spread)]
    print("full, capped, spread (mean, p95):", np.round(stats, 3).tolist())
    assert stats[1][1] >= 1.5 * stats[0][1]
    assert stats[2][0] <= 1.1 * stats[0][0]
    assert stats[2][1] <= 1.2 * stats[0][1]


def test_per_particle_radii_override_scene_radius(renderer: SurfaceRenderer) -> None:
    scene = replace(single_particle_scene("none", 0.05))
    small = make_frame(np.zeros((1, 3)), radii=np.array([0.02]))
    frame, _ = renderer.render(small, scene, depth=True)
    camera = Camera.from_config(scene.camera, 200, 150)
    hit, _ = sphere_hits(camera, np.zeros(3), 0.02)
    assert frame.depth is not None
    assert np.array_equal(np.isfinite(frame.depth), hit)


def test_normals_beside_a_nearer_surface_come_from_their_own_surface(
    renderer: SurfaceRenderer,
) -> None:
    """Each axis takes the one-sided difference with the smaller depth change (thesis §3.2.2):
    a pixel of the far sphere whose neighbour belongs to a nearer sphere must difference
    towards its other neighbour, on its own surface. A small sphere in front of a large one,
    no filter; every pixel of either sphere facing the camera (n.v >= 0.5) is compared with its
    own sphere's exact normal, the far sphere's ring around the near one included.

    Bound: a one-sided difference over one pixel measures a chord of the surface, whose
    direction lies between the normals at its two ends; on a sphere of projected radius R_px
    one pixel turns the normal by at most asin(sin(theta) + 1 / R_px) - theta, theta the largest
    angle evaluated (60 deg), and both axes together by sqrt(2) times that. Differencing across
    the depth step instead tilts the normal by up to 90 deg (measured 112 deg worst)."""
    eye = np.array([0.2, 0.15, 0.45])
    far_center, far_r = np.zeros(3), 0.05
    near_center, near_r = 0.45 * eye + np.array([0.012, 0.008, 0.0]), 0.012
    scene = single_particle_scene("none", far_r)
    # The 1-pixel rule under test (the default's wide stencil falls back to it at the step).
    scene = replace(scene, quality=replace(scene.quality, normal_stencil=0.0))
    positions = np.stack([far_center, near_center])
    frame, _ = renderer.render(
        make_frame(positions, radii=np.array([far_r, near_r])), scene, depth=True, normals=True
    )
    assert frame.normals is not None
    camera = Camera.from_config(scene.camera, 200, 150)
    far = sphere_truth(camera, far_center, far_r)
    near = sphere_truth(camera, near_center, near_r)
    far_front = far.hit & (~near.hit | (far.depth < near.depth))
    beside_near = np.zeros_like(far.hit)
    for axis in (0, 1):
        for shift in (-1, 1):
            beside_near |= np.roll(near.hit, shift, axis=axis)
    theta = math.acos(0.5)
    for truth, front, center, radius in (
        (far, far_front, far_center, far_r),
        (near, near.hit, near_center, near_r),
    ):
        mask = front & (truth.facing >= 0.5)
        errors = angle_deg(frame.normals.astype(np.float64)[mask], truth.normals[mask])
        radius_px = camera.projected_radius_px(radius, float(np.linalg.norm(eye - center)))
        turn = math.asin(min(1.0, math.sin(theta) + 1.0 / radius_px)) - theta
        bound = math.degrees(math.sqrt(2.0) * turn)
        print(f"r = {radius}: {mask.sum()} px, max error {errors.max():.2f} deg, bound {bound:.2f}")
        assert errors.max() <= bound
    assert (far_front & (far.facing >= 0.5) & beside_near).sum() >= 30  # the ring is evaluated
