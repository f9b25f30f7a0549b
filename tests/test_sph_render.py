"""The SPH stage inside the renderer (real EGL + real PoCL): adaptive radii, surface-only splatting,
and that the stage runs only when the scene needs it.

Ground truth:
* Adaptive radius: an isolated droplet's density is m W(0) = rest_density / pi with the default
  m and h, far below the surface average of the ball (~800), so eq 29 clamps it to
  min_radius * r. With `filter = "none"` the coverage of a sphere impostor is decided at pixel
  centres by the same ray-sphere test as `sphere_hits`, so each droplet's covered pixels must be
  the analytic disc of the *shrunk* sphere.
* Surface-only splatting: the depth test keeps the front-most fragment of every pixel, so
  dropping particles that never win it leaves the splat image bit-identical; a difference means a
  dropped particle was visible. The colour field sees the surface at the resolution h, so a
  crevice narrower than h between two fluid parts is not "surface" and its floor is dropped:
  there the image shows the fluid behind (never the background). So coverage must be identical,
  and the share of pixels whose depth moves by more than 1% is bounded by the measured share
  (llvmpipe, 640x360: ball 0.015%; the vendored slabs of the dam break, tests/data/: frame 5
  0.097%, frame 11 0.014%) with ~3x margin. A cube of lattice particles (frame 1) has no
  crevice and renders bit-identically. The drawn share is bounded at the measured one + 0.03
  (frame 1 0.617, 5 0.770, 11 0.925): a slab 8 layers thick keeps little interior to drop,
  since everything within h (2 layers) of its faces is splatted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sphrender.core.frame import make_frame
from sphrender.core.readers import read_particles
from sphrender.server.bench.analytic import sphere_hits
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

RADIUS = 0.08
BALL_RADIUS = 0.6
DROPLETS = np.array([[1.1, y, 0.0] for y in (-0.6, -0.2, 0.2, 0.6)] + [[1.5, 0.0, 0.3]])


def droplet_scene(quality: dict[str, object] | None = None, **sph: object) -> Scene:
    return scene_from_dict(
        {
            "image": {"width": 400, "height": 250},
            "camera": {"eye": [0.45, 0.0, 2.4], "target": [0.45, 0.0, 0.0], "fov_y": 40.0},
            "particles": {"radius": RADIUS},
            "quality": quality or {"filter": "none"},
            "sph": sph,
        }
    )


def ball_with_droplets() -> np.ndarray:
    ball = jittered_lattice_ball(BALL_RADIUS, RADIUS, jitter=0.0)
    return np.concatenate([ball, DROPLETS])


def droplet_disc_mask(scene: Scene, radius: float) -> np.ndarray:
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    mask = np.zeros((scene.image.height, scene.image.width), bool)
    for center in DROPLETS:
        mask |= sphere_hits(camera, center, radius)[0]
    return mask


def test_sph_stage_runs_only_when_needed(renderer: SurfaceRenderer) -> None:
    frame = make_frame(ball_with_droplets())
    _, plain = renderer.render(frame, droplet_scene())
    assert "sph" not in plain.stage_ms
    _, adaptive = renderer.render(frame, droplet_scene(adaptive_radius=True))
    assert "sph" in adaptive.stage_ms
    _, surface_only = renderer.render(frame, droplet_scene(surface_only=True))
    assert "sph" in surface_only.stage_ms


def test_adaptive_radius_thins_isolated_droplets(renderer: SurfaceRenderer) -> None:
    frame = make_frame(ball_with_droplets())
    scene_off = droplet_scene()
    scene_on = droplet_scene(adaptive_radius=True, min_radius=0.5)
    off, _ = renderer.render(frame, scene_off, depth=True)
    on, _ = renderer.render(frame, scene_on, depth=True)
    assert off.depth is not None and on.depth is not None
    covered_off = np.isfinite(off.depth)  # a surface at the pixel centre (alpha is sub-pixel)
    covered_on = np.isfinite(on.depth)
    full = droplet_disc_mask(scene_off, RADIUS)
    shrunk = droplet_disc_mask(scene_off, 0.5 * RADIUS)
    # The droplets lie right of the ball's silhouette: compare only that part of the image.
    camera = Camera.from_config(scene_off.camera, 400, 250)
    ball_hit, _ = sphere_hits(camera, np.zeros(3), BALL_RADIUS + RADIUS)
    right = np.zeros_like(full)
    right[:, np.flatnonzero(ball_hit.any(axis=0)).max() + 2 :] = True
    assert full[right].sum() > 5 * 300  # droplets are discs of ~11 px radius
    assert np.array_equal(covered_off & right, full & right)
    assert np.array_equal(covered_on & right, shrunk & right)
    ratio = (covered_on & right).sum() / (covered_off & right).sum()
    assert 0.2 < ratio < 0.3  # (r_min / r)^2 = 0.25 up to pixel discretisation
    # The ball keeps its size: its interior particles are denser than the surface average, and
    # its outer particles shrink by at most a few percent of r.
    ball_off = (covered_off & ~right).sum()
    ball_on = (covered_on & ~right).sum()
    assert 0.95 * ball_off < ball_on <= ball_off


def test_adaptive_radius_uses_client_densities(renderer: SurfaceRenderer) -> None:
    positions = ball_with_droplets()
    # Client says every droplet is as dense as the interior: nothing shrinks there.
    densities = np.full(len(positions), 1000.0)
    densities[: len(positions) - len(DROPLETS)] = 900.0  # the ball, surface included
    scene = droplet_scene(adaptive_radius=True)
    with_client, _ = renderer.render(make_frame(positions, densities=densities), scene)
    computed, _ = renderer.render(make_frame(positions), scene)
    mask = droplet_disc_mask(scene, RADIUS)
    assert (with_client.rgba[:, :, 3] > 0)[mask].all()
    assert (computed.rgba[:, :, 3] > 0)[mask].sum() < 0.5 * mask.sum()


def surface_only_errors(
    renderer: SurfaceRenderer, positions: np.ndarray, scene: Scene
) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(drawn share, share of covered pixels off by > 1% in depth, full depth, partial depth)."""
    frame = make_frame(positions)
    full, full_stats = renderer.render(frame, scene, depth=True)
    only = scene.with_overrides(sph=scene_from_dict({"sph": {"surface_only": True}}).sph)
    part, part_stats = renderer.render(frame, only, depth=True)
    assert full.depth is not None and part.depth is not None
    assert np.array_equal(np.isfinite(full.depth), np.isfinite(part.depth)), "a hole opened"
    covered = np.isfinite(full.depth)
    moved = np.abs(part.depth[covered] - full.depth[covered]) > 1e-2 * full.depth[covered]
    drawn = part_stats.particles_drawn / full_stats.particles_drawn
    return drawn, float(moved.mean()), full.depth, part.depth


def real_frame_scene() -> Scene:
    return scene_from_dict(
        {
            "image": {"width": 640, "height": 360},
            "camera": {"eye": [0.5, 2.5, 4.0], "target": [-0.5, 0.4, 0.0], "fov_y": 45.0},
            "particles": {"radius": 0.015},
            # Surface-only against full splatting, like with like: the SPH pass of the
            # surface-only render gives the frame densities, which would split droplets off.
            "quality": {"exact_droplets": False},
        }
    )


def test_surface_only_splatting_on_ball(renderer: SurfaceRenderer) -> None:
    positions = jittered_lattice_ball(0.556, 0.01, seed=0)  # the engine tests' 90k ball
    scene = scene_from_dict(
        {
            "image": {"width": 640, "height": 360},
            "camera": {"eye": [1.3, 1.0, 1.7], "target": [0, 0, 0], "fov_y": 40.0},
            "particles": {"radius": 0.01},
        }
    )
    drawn, moved, _, _ = surface_only_errors(renderer, positions, scene)
    assert drawn < 0.3  # outer shell + safety layer of a 90k ball: 23%
    assert moved < 5e-4


@pytest.mark.parametrize(
    ("name", "max_drawn", "max_moved"), [("1", 0.65, 0.0), ("5", 0.8, 3e-3), ("11", 0.955, 5e-4)]
)
def test_surface_only_splatting_on_real_frames(
    renderer: SurfaceRenderer, dambreak: Path, name: str, max_drawn: float, max_moved: float
) -> None:
    frame = read_particles(dambreak / "vtk" / f"ParticleData_Fluid_{name}.vtk")
    drawn, moved, full, part = surface_only_errors(renderer, frame.positions, real_frame_scene())
    assert drawn < max_drawn
    assert moved <= max_moved
    if max_moved == 0.0:
        assert np.array_equal(full, part)


#: The smoothed chain with the droplet split on the positions' own densities (its pass, or
#: the SPH stage's, over the whole frame before the surface-only subset).
SPLIT: dict[str, object] = {"filter": "narrow_range", "droplet_densities": "computed"}


@pytest.mark.parametrize(("adaptive", "split"), [(False, False), (True, False), (True, True)])
def test_no_nan_reaches_pixels_with_hard_sph_inputs(
    renderer: SurfaceRenderer, adaptive: bool, split: bool
) -> None:
    # Coincident particles, one far outlier (hashed grid), a lone particle in view.
    positions = np.concatenate(
        [
            np.zeros((20, 3)),
            [[0.0, 0.0, 0.0]],
            [[1e4, 1e4, 1e4]],
            [[1.2, 0.4, 0.0]],
            jittered_lattice_ball(0.2, 0.05),
        ]
    )
    scene = droplet_scene(SPLIT if split else None, adaptive_radius=adaptive, surface_only=True)
    image, stats = renderer.render(make_frame(positions), scene, depth=True, normals=True)
    assert "sph" in stats.stage_ms
    assert ("droplets" in stats.stage_ms) == split  # the lone particle in view
    assert np.isfinite(image.rgba).all()
    assert image.normals is not None and np.isfinite(image.normals).all()
    assert (image.rgba[:, :, 3] > 0).any()


@pytest.mark.parametrize("split", [False, True])
@pytest.mark.parametrize("count", [0, 1])
def test_empty_and_single_particle_frames_with_sph(
    renderer: SurfaceRenderer, count: int, split: bool
) -> None:
    scene = droplet_scene(SPLIT if split else None, adaptive_radius=True, surface_only=True)
    image, stats = renderer.render(make_frame(np.zeros((count, 3))), scene)
    assert "sph" in stats.stage_ms and stats.particles_drawn == count
    assert np.isfinite(image.rgba).all()
    assert (image.rgba[:, :, 3] > 0).any() == (count > 0)
