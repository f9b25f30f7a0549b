"""Occlusion culling of the splat (`occlusion.py`): its two numpy building blocks against brute
force, then whole renders with and without culling, which must give the same images.

Why "the same" is exact up to one number: a culled particle's nearest point is behind the
largest depth its silhouette could touch, so every fragment it would produce fails the depth
test. The only way a single draw can differ is a tie in the 24-bit depth buffer (eye depth /
far quantised to far / 2**24), where draw order picks the winner; we allow 4 such steps.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sphrender.core.frame import make_frame
from sphrender.core.readers import read_particles
from sphrender.server.bench.sweep import bench_scene_from_dict
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.frame_output import RenderStats
from sphrender.server.engine.geometry import occlusion
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.prepare import prepare_particles
from sphrender.server.engine.geometry.screen_box import screen_box
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import CameraConfig, scene_from_dict

# -- building blocks ----------------------------------------------------------------------------


def brute_force_hits(camera: Camera, center: np.ndarray, radius: float) -> np.ndarray:
    """(H, W) pixels (GL window rows: bottom first) whose centre ray hits the view-space sphere."""
    ys, xs = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    ty = camera.tan_half_fov_y
    dx = ((xs + 0.5) / camera.width * 2 - 1) * ty * camera.aspect
    dy = ((ys + 0.5) / camera.height * 2 - 1) * ty
    directions = np.stack([dx, dy, -np.ones_like(dx)], axis=-1)
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    along = directions @ center
    perpendicular = center[None, None, :] - along[..., None] * directions
    return (along > 0) & (np.einsum("ijk,ijk->ij", perpendicular, perpendicular) <= radius**2)


def test_sphere_bounds_hold_every_hit_pixel_and_are_tight() -> None:
    """Random spheres all over a 97x61 view (edges, off-screen parts, close to the eye): every
    pixel a sphere can cover lies in its rectangle, and the rectangle is at most 2 px (the
    margin) larger than the covered pixels on each side."""
    camera = Camera.from_config(CameraConfig(eye=(0, 0, 0), target=(0, 0, -1), fov_y=50), 97, 61)
    rng = np.random.default_rng(5)
    count = 400
    depth = rng.uniform(0.2, 5.0, count)
    lateral = rng.uniform(-1.3, 1.3, (count, 2)) * depth[:, None] * np.array([0.7, 0.5])
    radius = rng.uniform(0.005, 0.6, count) * depth
    center_radius = np.column_stack([lateral, -depth, radius]).astype(np.float32)
    bounds = occlusion.sphere_bounds(center_radius, camera)
    checked = 0
    for i in range(count):
        center = center_radius[i, :3].astype(np.float64)
        r = float(center_radius[i, 3])
        hits = brute_force_hits(camera, center, r)
        if not bounds.valid[i]:
            assert -center[2] - r <= 1e-6 * -center[2] * 2
            continue
        ys, xs = np.nonzero(hits)
        if xs.size == 0:
            continue
        checked += 1
        assert bounds.x0[i] <= xs.min() and xs.max() <= bounds.x1[i], i
        assert bounds.y0[i] <= ys.min() and ys.max() <= bounds.y1[i], i
        inside_image = (
            xs.min() > 0 and ys.min() > 0 and xs.max() < camera.width - 1
        ) and ys.max() < camera.height - 1
        if inside_image:
            assert xs.min() - bounds.x0[i] <= 2 and bounds.x1[i] - xs.max() <= 2, i
            assert ys.min() - bounds.y0[i] <= 2 and bounds.y1[i] - ys.max() <= 2, i
        assert bounds.near_depth[i] == pytest.approx(-center[2] - r)
    assert checked > 200


def test_depth_max_table_matches_brute_force() -> None:
    """Random depth image with background holes, random rectangles: where the table answers it
    must agree exactly with the maximum over the rectangle; rectangles it cannot answer (outside
    the table, too elongated, too large) count as visible."""
    rng = np.random.default_rng(11)
    height, width = 70, 90
    depth = rng.uniform(1.0, 2.0, (height, width)).astype(np.float32)
    depth[rng.random((height, width)) < 0.003] = 0.0  # background pixels: never occlude
    origin = (13, 7)
    table = occlusion.DepthMaxTable(depth, origin, max_side=32)
    count = 3000
    x0 = rng.integers(-5, width + 3, count)
    y0 = rng.integers(-5, height + 3, count)
    side_x = rng.integers(1, 45, count)
    side_y = np.maximum(side_x + rng.integers(-4, 5, count), 1)
    x1, y1 = x0 + side_x - 1, y0 + side_y - 1
    near = rng.uniform(1.8, 2.4, count)
    bounds = occlusion.SphereBounds(
        x0 + origin[0], x1 + origin[0], y0 + origin[1], y1 + origin[1], near, np.ones(count, bool)
    )
    answer = table.occluded(bounds, np.arange(count))
    # A table that keeps only the level these rectangles need (shorter side 8..15: level 3)
    # gives the same answers for them.
    shorter = np.minimum(side_x, side_y)
    some = np.flatnonzero((shorter >= 8) & (shorter <= 15))
    lean = occlusion.DepthMaxTable(depth, origin, shorter[some], max_side=32)
    assert list(lean.levels) == [3]
    assert np.array_equal(lean.occluded(bounds, some), answer[some])
    assert answer[some].any()
    as_inf = np.where(depth > 0, depth.astype(np.float64), np.inf)
    answered = 0
    for i in range(count):
        inside = x0[i] >= 0 and y0[i] >= 0 and x1[i] < width and y1[i] < height
        truth = inside and near[i] > as_inf[y0[i] : y1[i] + 1, x0[i] : x1[i] + 1].max()
        if answer[i]:
            assert truth, i  # never culls a visible sphere
        shorter = min(side_x[i], side_y[i])
        level = int(np.floor(np.log2(shorter)))
        if inside and level <= 5 and max(side_x[i], side_y[i]) < 2 << level:
            assert answer[i] == truth, i  # and is exact where it answers
            answered += 1
    assert answered > 500
    assert answer.sum() > 100


# -- whole renders ------------------------------------------------------------------------------


def render_both(
    renderer: SurfaceRenderer, positions: np.ndarray, sections: dict[str, Any], **arrays: Any
) -> tuple[RenderStats, RenderStats]:
    """Render with and without culling; assert the same coverage, depth and colour."""
    outputs = []
    for culling in (True, False):
        base = {key: dict(value) for key, value in sections.items()}
        base.setdefault("quality", {})["occlusion_culling"] = culling
        scene = bench_scene_from_dict(base)
        frame, stats = renderer.render(
            make_frame(positions, **arrays), scene, depth=True, normals=True
        )
        outputs.append((frame, stats))
    (culled, culled_stats), (plain, plain_stats) = outputs
    assert culled.depth is not None and plain.depth is not None
    covered = np.isfinite(plain.depth)
    assert np.array_equal(np.isfinite(culled.depth), covered)
    tie = 4 * plain_stats.far / 2**24
    assert np.abs(culled.depth[covered] - plain.depth[covered]).max(initial=0.0) <= tie
    assert np.abs(culled.rgba - plain.rgba).max() <= 1e-3
    assert plain_stats.particles_splatted == plain_stats.particles_drawn
    return culled_stats, plain_stats


def small_scene(eye: list[float], radius: float, **extra: Any) -> dict[str, Any]:
    return {
        "image": {"width": 240, "height": 160},
        "camera": {"eye": eye, "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        "particles": {"radius": radius},
        **extra,
    }


def test_culled_ball_is_identical_and_culls_most_particles(renderer: SurfaceRenderer) -> None:
    r = 0.01
    positions = jittered_lattice_ball(0.3, r)  # ~14k particles
    stats, _ = render_both(renderer, positions, small_scene([0.6, 0.5, 0.8], r))
    assert stats.particles_drawn == len(positions)
    assert stats.particles_splatted < 0.5 * stats.particles_drawn


def test_culled_slab_seen_along_its_rows_is_identical(renderer: SurfaceRenderer) -> None:
    """Rays slip between the lattice rows into lower layers: those particles are visible and
    must not be culled."""
    r = 0.01
    positions = lattice_slab(1.0, 1.0, 4, r)  # 10.4k particles
    stats, _ = render_both(renderer, positions, small_scene([0.0, 0.25, 0.9], r))
    assert stats.particles_splatted < stats.particles_drawn


def test_culled_real_frame_is_identical(renderer: SurfaceRenderer, dambreak: Any) -> None:
    frame = read_particles(dambreak / "vtk" / "ParticleData_Fluid_11.vtk")
    center = frame.positions.mean(axis=0)
    sections = small_scene((center + np.array([1.2, 1.0, 1.6])).tolist(), 0.025)
    sections["camera"]["target"] = center.tolist()
    stats, _ = render_both(renderer, frame.positions, sections)
    assert stats.particles_splatted < stats.particles_drawn


def test_culling_with_near_plane_radii_and_temperatures(renderer: SurfaceRenderer) -> None:
    """A ball crossing the near plane (spheres reaching the eye plane are always drawn), one
    radius per particle from 0.2 r to 3 r, and temperatures (the front particle's kelvin must
    be the same, so the colour is)."""
    r = 0.01
    positions = jittered_lattice_ball(0.35, r, seed=2)  # 22k particles
    rng = np.random.default_rng(4)
    radii = r * rng.uniform(0.2, 3.0, len(positions))
    temperatures = rng.uniform(300.0, 2500.0, len(positions))
    for eye in ([0.0, 0.0, 0.8], [0.0, 0.05, 0.37]):
        sections = small_scene(eye, r)
        sections["camera"]["near"] = 0.02
        stats, _ = render_both(
            renderer, positions, sections, radii=radii, temperatures=temperatures
        )
        print(eye, stats.particles_splatted, stats.particles_drawn)
        assert stats.particles_splatted < stats.particles_drawn


def test_screen_box_holds_every_covered_pixel(renderer: SurfaceRenderer) -> None:
    """The passes after the splat run only inside `screen_box`: every pixel the GL splat covers,
    with its direct neighbours (the normals read them), must lie inside it. Spheres of very
    different sizes, some cut by the image border."""
    rng = np.random.default_rng(8)
    # The view is +-0.87 wide and +-0.58 high at the origin: spheres reach past the left border
    # only, so the box is cut there and must stay tight on the other three sides.
    positions = rng.uniform([-0.95, -0.25, -0.3], [0.3, 0.25, 0.3], (300, 3))
    radii = rng.uniform(0.005, 0.08, len(positions))
    scene = scene_from_dict(small_scene([0.0, 0.0, 1.6], 0.01))
    frame, _ = renderer.render(make_frame(positions, radii=radii), scene, depth=True)
    assert frame.depth is not None
    camera = Camera.from_config(scene.camera, 240, 160)
    prepared = prepare_particles(make_frame(positions, radii=radii), camera, scene)
    box = screen_box(occlusion.sphere_bounds(prepared.center_radius, camera), camera)
    assert box is not None
    x, y, w, h = box
    rows, columns = np.nonzero(np.isfinite(frame.depth))
    window_y = camera.height - 1 - rows
    assert columns.min() == 0 and x == 0  # some spheres are cut by the left border
    assert np.all((columns - 1 >= x) | (columns == 0))
    assert np.all((columns + 1 < x + w) | (columns == camera.width - 1))
    assert np.all((window_y - 1 >= y) | (window_y == 0))
    assert np.all((window_y + 1 < y + h) | (window_y == camera.height - 1))
    assert w * h < camera.width * camera.height  # and it does skip some background


# -- anti-aliasing coverage of hidden particles ---------------------------------------------------


def sphere_behind_a_screen(camera: Camera) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """A big sphere on the view axis whose silhouette's right end lies 0.05 px left of the
    centre of the pixel just right of the last pixel centre it covers (so it covers ~45 % of that
    pixel, which its bounds rectangle holds as its 1-pixel margin), behind a screen of tiny
    spheres (0.3 px) at eye depth 0.8, one over every pixel centre of that rectangle: the big
    sphere is hidden (every pixel of its rectangle is nearer) but overlaps rim pixels. Plus a
    block of tiny spheres far to the left, so the frame is over the culling's particle
    threshold. Returns positions, radii and the (column, GL row) of that margin pixel."""
    f = camera.pixels_per_unit_at_unit_depth
    half_w, half_h = camera.width / 2.0, camera.height / 2.0
    margin_centre = np.floor(half_w + 9.0) + 0.5  # ~9.5 px projected radius
    rho = (margin_centre - 0.05) - half_w  # projected radius: f R / sqrt(d^2 - R^2) at d = 2
    ratio = rho / f
    big_radius = 2.0 * ratio / np.sqrt(1.0 + ratio * ratio)
    bounds = occlusion.sphere_bounds(np.array([[0.0, 0.0, -2.0, big_radius]], np.float32), camera)
    assert bounds.x1[0] + 0.5 == margin_centre, "the margin pixel is the rectangle's last column"

    def tiny_spheres_at(columns: np.ndarray, rows: np.ndarray) -> np.ndarray:
        # Off the pixel centres by a fraction of a pixel: a sphere centred on a pixel's centre
        # ray leaves its edge direction there to rounding.
        xs, ys = np.meshgrid(columns + 0.6, rows + 0.43)
        depth = 0.8
        view = np.stack(
            [(xs - half_w) / f * depth, (ys - half_h) / f * depth, np.full_like(xs, -depth)],
            axis=-1,
        ).reshape(-1, 3)
        return view + np.array([0.0, 0.0, 2.0])  # world = view + eye (camera at z = 2, -z view)

    screen = tiny_spheres_at(
        np.arange(bounds.x0[0], bounds.x1[0] + 1), np.arange(bounds.y0[0], bounds.y1[0] + 1)
    )
    filler = tiny_spheres_at(np.arange(0, 30), np.arange(0, camera.height))
    tiny = np.concatenate([screen, filler])
    positions = np.concatenate([np.zeros((1, 3)), tiny])
    radii = np.concatenate([[big_radius], np.full(len(tiny), 0.3 * 0.8 / f)]).astype(np.float32)
    return positions, radii, (int(bounds.x1[0]), camera.height // 2)


def test_a_hidden_sphere_adds_no_coverage_the_shade_pass_reads(gl_context: Any) -> None:
    """Culling leaves a hidden particle's coverage out with its depth (passes/splat.py
    COVERAGE_NEED_PX): at a pixel where the shade pass reads coverage, the sphere in front
    covers the pixel centre (coverage >= 1/2) and the hidden one does not (<= 1/2). Here the
    hidden sphere overlaps a rim pixel by ~45 % (seen when it is drawn alone), and the alpha
    with it is the alpha without it, culled or not. The host prepare's culling (exact
    rectangles; the device's tests aligned blocks up to 8 px wider, which see past this screen
    and draw the sphere, so there the case does not arise; the rule is the same)."""
    sections = {
        "image": {"width": 96, "height": 64},
        "camera": {"eye": [0.0, 0.0, 2.0], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        "particles": {"radius": 0.01},
        "quality": {"filter": "none", "exact_droplets": False, "antialias": True},
        "shading": {"background": "transparent"},
    }
    scene = scene_from_dict(sections)
    camera = Camera.from_config(scene.camera, 96, 64)
    positions, radii, (column, gl_row) = sphere_behind_a_screen(camera)
    renderer = SurfaceRenderer(gl_context, prepare="host")
    try:
        culled, _ = render_both(renderer, positions, sections, radii=radii)
        assert culled.particles_splatted == culled.particles_drawn - 1  # the big one, hidden
        images = [
            renderer.render(make_frame(positions[rows], radii=radii[rows]), scene)[0].rgba
            for rows in (slice(None), slice(1, None), slice(0, 1))
        ]
    finally:
        renderer.release()
    with_big, without_big, big_alone = images
    row = camera.height - 1 - gl_row  # top-first
    assert 0.35 < big_alone[row, column, 3] < 0.5
    assert 0.5 <= without_big[row, column, 3] < 1.0  # a rim pixel: its coverage is read
    # Alpha only (the colours see the frame's reference radius, which the big sphere moves),
    # to float32 rounding of the view positions (1e-5; the frame's extent changes it). Were the
    # coverage model to give a pixel whose centre a sphere covers less than 1/2 (say the true
    # area of a sub-pixel sphere), the hidden sphere would show here, and the culling would
    # have to draw hidden particles' coverage again.
    np.testing.assert_allclose(with_big[..., 3], without_big[..., 3], rtol=0, atol=1e-4)
