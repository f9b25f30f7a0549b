"""Solid workpieces against analytic truth (real EGL): flat faces, sharp edges, a root gap.

The scenes are `server/bench/solid_scenes.py`'s at small sizes; the truth is the analytic solid
grown by r, ray cast per pixel. Tolerances are the issue's targets for 960x540 where a small
image can meet them, and derived per test otherwise (see each assert's comment).
"""

from __future__ import annotations

import numpy as np
import pytest

from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.server.bench.metrics import solid_metrics, surface_metrics
from sphrender.server.bench.scenes import BenchScene
from sphrender.server.bench.solid_scenes import (
    JointShape,
    bevel_joint_scene,
    plate_scene,
    wall_scene,
)
from sphrender.server.bench.sweep import bench_scene_dict, preset_setting, scene_for
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

W, H = 256, 144


def _scene(bench: BenchScene, **sections: object) -> Scene:
    base = bench_scene_dict(bench, W, H)
    base.update(sections)  # type: ignore[arg-type]
    return scene_for(preset_setting("balanced"), base)


def _render(renderer: SurfaceRenderer, bench: BenchScene, positions=None, solid=True, **kw):
    positions = bench.positions if positions is None else positions
    flags = np.ones(len(positions), np.bool_) if solid else None
    frame = make_frame(positions, solid=flags)
    return renderer.render(frame, _scene(bench, **kw), depth=True, normals=True)


def _metrics(renderer: SurfaceRenderer, bench: BenchScene, **kw):
    rendered, _ = _render(renderer, bench, **kw)
    camera = Camera.from_config(bench.camera_config(), W, H)
    return rendered, solid_metrics(rendered, camera, bench.truth(camera), bench.radius)


SMALL_PLATE = plate_scene(counts=(30, 3, 30))


def test_plate_faces_flat_and_edges_sharp(renderer: SurfaceRenderer) -> None:
    """Targets of the issue (faces <= 1.5 / 4 deg, edge band <= 8 / 30 deg): a disc's normal is
    its face's plane fitted over hundreds of particles, so the faces are exact to the jitter's
    leftover (0.1 r over a face of 30 spacings: < 0.1 deg) and the band errs only at pixels
    whose centre ray lands across the crease from where the truth's does."""
    rendered, metrics = _metrics(renderer, SMALL_PLATE)
    assert metrics.face_mean_deg <= 1.5 and metrics.face_p95_deg <= 4.0, metrics
    assert metrics.edge_mean_deg <= 8.0 and metrics.edge_p95_deg <= 30.0, metrics
    assert np.isfinite(rendered.rgba).all()


def test_regular_lattice_plate(renderer: SurfaceRenderer) -> None:
    """A perfectly regular lattice (no jitter: ties everywhere in the extremal tests, moiré
    bait): the same targets."""
    _, metrics = _metrics(renderer, plate_scene(counts=(30, 3, 30), jitter=0.0))
    assert metrics.face_mean_deg <= 1.5 and metrics.face_p95_deg <= 4.0, metrics
    assert metrics.edge_mean_deg <= 8.0 and metrics.edge_p95_deg <= 30.0, metrics


def test_todays_path_rounds_the_same_plate(renderer: SurfaceRenderer) -> None:
    """The check above can fail: the fluid path on the same particles misses the edge target."""
    rendered, _ = _render(renderer, SMALL_PLATE, solid=False)
    camera = Camera.from_config(SMALL_PLATE.camera_config(), W, H)
    metrics = solid_metrics(rendered, camera, SMALL_PLATE.truth(camera), SMALL_PLATE.radius)
    assert metrics.edge_mean_deg > 8.0, metrics


def test_bevel_joint_planes_and_open_root_gap(renderer: SurfaceRenderer) -> None:
    """Bevels are planes meeting the root faces and tops at creases; the gap of 4 r (3 px wide
    at this size) is seen through where the truth is: IoU >= 0.9 as the issue asks at 960x540,
    which at 256x144 leaves ~1 px of slack per gap side."""
    joint = bevel_joint_scene(shape=JointShape(width=28, layers=6, length=40))
    _, metrics = _metrics(renderer, joint)
    assert metrics.face_mean_deg <= 1.5 and metrics.face_p95_deg <= 4.0, metrics
    assert metrics.edge_mean_deg <= 8.0 and metrics.edge_p95_deg <= 30.0, metrics
    assert metrics.gap_iou >= 0.9, metrics


def test_root_gap_closes_where_the_plates_touch(renderer: SurfaceRenderer) -> None:
    """Plates 2 r apart at the particle centres touch: no pixel of the window sees through."""
    joint = bevel_joint_scene(shape=JointShape(width=28, layers=6, length=40, gap_radii=0.0))
    rendered, _ = _render(renderer, joint)
    camera = Camera.from_config(joint.camera_config(), W, H)
    truth = joint.truth(camera)
    assert truth.gap_window is not None
    see_through = truth.gap_window & ~np.isfinite(rendered.depth)
    assert not (truth.gap_window & ~truth.hit).any()
    assert see_through.sum() == 0


def test_fluid_against_a_wall_matches_its_truth(renderer: SurfaceRenderer) -> None:
    """The sweep's fluid block flush against a solid wall, with the bench's per-particle flags
    (the wall only): the render covers the truth's union of the two boxes (IoU >= 0.95: the
    boxes' outline is ~700 px long at 256x144 and the grown spheres' silhouette departs from
    the box's by under a pixel), and the normals err as the fluid path's do (mean under 10
    deg; 5.1 at 1280x720), which a truth off by a face or flags on the wrong part would not."""
    wall = wall_scene()
    flags = wall.solid_flags()
    assert flags is not None and 0 < int(flags.sum()) < len(flags)
    frame = make_frame(wall.positions, solid=flags)
    rendered, _ = renderer.render(frame, _scene(wall), depth=True, normals=True)
    camera = Camera.from_config(wall.camera_config(), W, H)
    metrics = surface_metrics(rendered, camera, wall.truth(camera), wall.radius)
    assert metrics.silhouette_iou >= 0.95, metrics
    assert metrics.normal_mean_deg < 10.0, metrics
    assert np.isfinite(rendered.rgba).all()


def test_sheet_one_particle_thick(renderer: SurfaceRenderer) -> None:
    """A sheet one particle thick: both sides are faces (the rims stay round, so only faces)."""
    sheet = plate_scene(counts=(30, 1, 30))
    _, metrics = _metrics(renderer, sheet)
    assert metrics.face_mean_deg <= 1.5 and metrics.face_p95_deg <= 4.0, metrics


def test_far_from_the_origin_renders_alike(renderer: SurfaceRenderer) -> None:
    """Coordinates of 1e5 (float64 to the eye subtraction): the same normals as at the origin,
    to float32's rounding of the view-space planes (1e-5 relative of a 2 r disc: far below a
    degree)."""
    near, _ = _render(renderer, SMALL_PLATE)
    shift = np.array([1e5, -2e5, 1e5])
    moved = SMALL_PLATE.camera | {
        "eye": (np.asarray(SMALL_PLATE.camera["eye"]) + shift).tolist(),
        "target": (np.asarray(SMALL_PLATE.camera["target"]) + shift).tolist(),
    }
    far_bench = BenchScene(
        "far", "", SMALL_PLATE.positions + shift, SMALL_PLATE.radius, moved, SMALL_PLATE.truth
    )
    far, _ = _render(renderer, far_bench)
    both = np.isfinite(near.depth) & np.isfinite(far.depth)
    assert both.sum() > 0.95 * np.isfinite(near.depth).sum()
    dots = np.einsum("ij,ij->i", near.normals[both], far.normals[both])
    assert np.degrees(np.arccos(np.clip(dots, -1, 1))).mean() < 0.5


def test_static_solid_is_built_once(renderer: SurfaceRenderer) -> None:
    """A session's static solid: surfels built on the first frame only, whatever the camera;
    moving the solid builds them again."""
    cache = renderer._solids.cache  # the renderer's own pass: its builds are what is counted
    _render(renderer, SMALL_PLATE)
    first = cache.builds
    _render(renderer, SMALL_PLATE, camera={"eye": [0.2, 0.9, 0.6], "target": [0.0, 0.0, 0.0]})
    _render(renderer, SMALL_PLATE)
    assert cache.builds == first
    _render(renderer, SMALL_PLATE, positions=SMALL_PLATE.positions + 0.001)
    assert cache.builds == first + 1


def test_no_solid_particle_changes_nothing(renderer: SurfaceRenderer) -> None:
    """A frame whose flags are all false, or a scene with source none, renders today's bytes."""
    ball = np.random.default_rng(2).normal(0.0, 0.05, (400, 3))
    scene = _scene(SMALL_PLATE)
    plain, _ = renderer.render(make_frame(ball), scene)
    unflagged, _ = renderer.render(make_frame(ball, solid=np.zeros(400, np.uint8)), scene)
    off = _scene(SMALL_PLATE, solids={"source": "none"})
    flagged_off, _ = renderer.render(make_frame(ball, solid=np.ones(400, np.bool_)), off)
    plain_off, _ = renderer.render(make_frame(ball), off)
    assert np.array_equal(plain.rgba, unflagged.rgba)
    assert np.array_equal(plain_off.rgba, flagged_off.rgba)


def test_temperature_source_and_molten_pool_on_the_plate(renderer: SurfaceRenderer) -> None:
    """Solid by temperature (below iron's solidus) with a hot pool on the plate: the plate's
    faces stay flat around the pool, the pool covers its part of the top (no crack: every pixel
    of the plate's silhouette is covered) and nothing is NaN."""
    plate = SMALL_PLATE.positions
    top = plate[:, 1].max()
    axis = (np.arange(10) - 4.5) * 0.02
    pool = np.stack(np.meshgrid(axis, [0.0, 0.02], axis, indexing="ij"), -1).reshape(-1, 3)
    pool += np.random.default_rng(4).uniform(-0.002, 0.002, pool.shape)
    pool[:, 1] += top + 0.015  # resting on the top layer, sunk a quarter radius into it
    positions = np.concatenate([plate, pool])
    kelvin = np.concatenate([np.full(len(plate), 600.0), np.full(len(pool), 2100.0)])
    scene = _scene(SMALL_PLATE, solids={"source": "temperature"})
    frame = make_frame(positions, temperatures=kelvin)
    rendered, _ = renderer.render(frame, scene, depth=True, normals=True)
    camera = Camera.from_config(SMALL_PLATE.camera_config(), W, H)
    truth = SMALL_PLATE.truth(camera)
    assert rendered.depth is not None
    covered = np.isfinite(rendered.depth)
    inner = truth.hit.copy()  # the silhouette's pixels less one: a centre ray there may miss
    for axis_ in (0, 1):
        for step in (-1, 1):
            inner &= np.roll(truth.hit, step, axis=axis_)
    assert covered[inner].all()
    assert np.isfinite(rendered.rgba).all()
    metrics = solid_metrics(rendered, camera, truth, SMALL_PLATE.radius)
    assert metrics.edge_mean_deg <= 8.0, metrics  # the plate's edges, away from the pool


def test_edge_on_and_near_plane_crossing(renderer: SurfaceRenderer) -> None:
    """A plate seen edge-on, and a camera whose near plane cuts the plate: finite pixels, a
    covered line for the edge-on plate, no error."""
    edge_on = _scene(SMALL_PLATE, camera={"eye": [0.0, 0.0, 1.0], "target": [0.0, 0.0, 0.0]})
    flags = np.ones(len(SMALL_PLATE.positions), np.bool_)
    rendered, _ = renderer.render(make_frame(SMALL_PLATE.positions, solid=flags), edge_on)
    assert np.isfinite(rendered.rgba).all() and (rendered.rgba[:, :, 3] > 0).any()
    inside = _scene(SMALL_PLATE, camera={"eye": [0.0, 0.03, 0.25], "target": [0.0, 0.0, -1.0]})
    rendered, _ = renderer.render(make_frame(SMALL_PLATE.positions, solid=flags), inside)
    assert np.isfinite(rendered.rgba).all() and (rendered.rgba[:, :, 3] > 0).any()


@pytest.mark.parametrize(
    ("flags", "field", "words"),
    [
        (np.array([0, 2, 1]), "solid[1]", "must be 0 or 1"),
        (np.array([0.0, 1.0, 1.0]), "solid", "bool or integer"),
        (np.array([1, 0]), "solid", "has 2 entries"),
        (np.ones((3, 1), np.uint8), "solid", "shape (N,)"),
    ],
)
def test_bad_solid_flags_are_named(flags: np.ndarray, field: str, words: str) -> None:
    with pytest.raises(InputError) as raised:
        make_frame(np.zeros((3, 3)), solid=flags)
    assert raised.value.field == field and words in str(raised.value)


def test_solids_source_is_validated() -> None:
    with pytest.raises(InputError) as raised:
        scene_from_dict({"solids": {"source": "melted"}})
    assert "solids.source" in str(raised.value)


def test_the_fluid_part_keeps_every_array_of_the_frame(renderer: SurfaceRenderer) -> None:
    """Splitting off the solid keeps the fluid's rows of every per-particle array (peaks,
    velocities, ids included), so a frame with solids and every other feature on renders."""
    from dataclasses import fields

    from sphrender.server.content.lattice import lattice_slab
    from sphrender.server.engine.passes.solid_surface import split_solid

    plate = lattice_slab(0.6, 0.6, layers=3, particle_radius=0.015, top_y=0.0)
    drops = np.array([[0.0, 0.05, 0.0], [0.03, 0.05, 0.0], [-0.03, 0.06, 0.01]])
    positions = np.concatenate([plate, drops])
    n = len(positions)
    flags = np.r_[np.ones(len(plate), bool), np.zeros(len(drops), bool)]
    frame = make_frame(
        positions,
        temperatures=np.full(n, 400.0),
        peak_temperatures=np.where(positions[:, 0] > 0.0, 600.0, 400.0),
        velocities=np.tile([1.0, 0.0, 0.0], (n, 1)),
        ids=np.arange(n),
        solid=flags,
    )
    scene = scene_from_dict(
        {
            "image": {"width": 64, "height": 48},
            "camera": {"eye": [0.0, 1.0, 1.0], "shutter": 0.01},
            "particles": {"radius": 0.015},
            "material": {"preset": "iron", "heat_tint": True, "molten": True},
            "lights": [
                {"type": "sphere", "position": [0, 0.3, 0], "radius": 0.02, "shadows": True}
            ],
            "glare": {"enabled": True},
        }
    )
    fluid, solid = split_solid(frame, scene)
    assert solid is not None and len(solid.positions) == len(plate)
    for f in fields(fluid):
        value = getattr(fluid, f.name)
        assert value is None or len(value) == len(drops), f.name
    rendered, stats = renderer.render(frame, scene)
    assert np.isfinite(rendered.rgba).all() and "solids" in stats.stage_ms


def test_the_finish_detail_reaches_the_solid_surface(renderer: SurfaceRenderer) -> None:
    """The world-fixed detail tilts the solid's normals as it does the fluid's (it runs after the
    solid is composed): the N AOV over a flagged plate changes when the detail is on."""
    from sphrender.server.content.lattice import lattice_slab

    plate = lattice_slab(0.6, 0.6, layers=3, particle_radius=0.015, top_y=0.0)
    frame = make_frame(plate, solid=np.ones(len(plate), bool))
    sections = {
        "image": {"width": 64, "height": 48},
        "camera": {"eye": [0.0, 0.8, 0.6]},
        "particles": {"radius": 0.015},
    }
    plain, _ = renderer.render(frame, scene_from_dict(sections), normals=True)
    brushed = {**sections, "finish": {"detail": "brushed", "detail_scale": 0.02}}
    detailed, _ = renderer.render(frame, scene_from_dict(brushed), normals=True)
    assert plain.normals is not None and detailed.normals is not None
    surface = np.linalg.norm(plain.normals, axis=-1) > 0.5
    tilt = np.degrees(
        np.arccos(np.clip(np.sum(plain.normals * detailed.normals, axis=-1), -1.0, 1.0))
    )
    assert surface.sum() > 500 and np.median(tilt[surface]) > 0.2


def test_the_heat_tint_reads_the_solid_particles_peaks(renderer: SurfaceRenderer) -> None:
    """A solid plate at room temperature whose right half peaked at 300 C (carbon steel: blue):
    the solid path carries the peaks beside the kelvin, so that half turns blue and the other
    half renders as without peaks."""
    from sphrender.server.content.lattice import lattice_slab

    plate = lattice_slab(0.6, 0.3, layers=2, particle_radius=0.015, top_y=0.0)
    n = len(plate)
    current = np.full(n, 293.15)
    peaks = np.where(plate[:, 0] > 0.0, 573.15, 293.15)
    scene = scene_from_dict(
        {
            "image": {"width": 96, "height": 48},
            "camera": {"eye": [0.0, 1.2, 0.4], "fov_y": 35.0},
            "particles": {"radius": 0.015},
            "material": {"preset": "iron", "roughness": 0.5, "heat_tint": True},
            "lights": [{"direction": [0.0, -1.0, -0.3], "intensity": 3.0}],
            "shading": {"ibl_mode": "none"},
        }
    )
    flags = np.ones(n, bool)
    tinted, _ = renderer.render(
        make_frame(plate, temperatures=current, peak_temperatures=peaks, solid=flags), scene
    )
    cold, _ = renderer.render(make_frame(plate, temperatures=current, solid=flags), scene)
    covered = (tinted.rgba[..., 3] > 0.99) & (cold.rgba[..., 3] > 0.99)
    left, right = covered.copy(), covered.copy()
    left[:, 40:] = False  # a margin each side of the middle, where the blur mixes the halves
    right[:, :56] = False
    assert left.sum() > 200 and right.sum() > 200
    blue = tinted.rgba[right][:, :3].mean(axis=0)
    assert blue[2] > blue[0] * 1.5, blue  # blue where the peak was 300 C
    assert np.allclose(tinted.rgba[left], cold.rgba[left], atol=1e-4)
