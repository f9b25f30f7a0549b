"""Shadows and sphere lights against ray-traced truth (real EGL): a jittered particle ball over
a particle plate (server/content/lattice.py), lit by point, sphere and directional lights.

Truth (tests/shadow_reference.py): each plate pixel's world point (from the Z AOV) is in shadow
when the segment to the light meets a ball particle's sphere; a sphere light's visible fraction is
a 256-point quadrature over its disc. A pixel counts as shadowed in the render when its colour is
under half the colour of the same render without shadows (the scenes have direct light only).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.server.bench.analytic import reconstruct_world_positions
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict
from sphrender.server.scene.layering import merge_scene_dicts
from tests.shadow_reference import occluded, penumbra_edges, visible_fraction

R = 0.05  # particle radius
SIZE = 160
BALL_RADIUS = 0.5


def _particles(
    ball_y: float, offset: float = 0.0
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    ball = jittered_lattice_ball(BALL_RADIUS, R, center=(0.0, ball_y, 0.0), seed=3)
    plate = lattice_slab(3.2, 3.2, 2, R, top_y=0.0)
    return ball + offset, np.concatenate([ball, plate]) + offset


def _scene(lights: list[dict[str, Any]], offset: float = 0.0, **camera: Any) -> Scene:
    eye = np.array(camera.pop("eye", (0.0, 4.0, 3.6))) + offset
    return scene_from_dict(
        {
            "image": {"width": SIZE, "height": SIZE},
            "camera": {"eye": list(eye), "target": [offset] * 3, "fov_y": 50.0, **camera},
            "particles": {"radius": R},
            "shading": {"ibl_mode": "none"},
            "material": {"preset": "iron", "roughness": 0.6},
            "lights": lights,
        }
    )


def _render(
    renderer: SurfaceRenderer, positions: npt.NDArray[np.float64], scene: Scene
) -> RenderedFrame:
    frame, _ = renderer.render(ParticleFrame(positions), scene, depth=True, normals=True)
    assert np.isfinite(frame.rgba).all()
    return frame


def _shadow_setup(
    renderer: SurfaceRenderer, light: dict[str, Any], ball_y: float = 1.0, offset: float = 0.0
):
    """(ratio shadowed / unshadowed, world points, normals, mask of interior plate pixels)."""
    ball, positions = _particles(ball_y, offset)
    lit = _render(renderer, positions, _scene([dict(light, shadows=False)], offset))
    shadowed = _render(renderer, positions, _scene([dict(light, shadows=True)], offset))
    camera = Camera.from_config(_scene([], offset).camera, SIZE, SIZE)
    world = reconstruct_world_positions(lit, camera)
    luminance_lit = lit.rgba[..., :3].sum(axis=2)
    ratio = shadowed.rgba[..., :3].sum(axis=2) / np.maximum(luminance_lit, 1e-30)
    plate = np.isfinite(world[..., 1]) & (world[..., 1] < offset + 0.2) & (lit.rgba[..., 3] >= 1.0)
    plate &= luminance_lit > 0.0
    return ratio, world, lit.normals, plate, ball


def _iou(a: npt.NDArray[np.bool_], b: npt.NDArray[np.bool_]) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


POINT = {"type": "point", "position": [-0.5, 3.0, -0.7], "intensity": 8.0}


def test_point_light_shadow_matches_ray_traced_truth(renderer: SurfaceRenderer) -> None:
    ratio, world, _, plate, ball = _shadow_setup(renderer, POINT)
    truth = occluded(world[plate], np.array(POINT["position"]), ball, R)
    ours = ratio[plate] < 0.5
    iou = _iou(ours, truth)
    print(f"point light: IoU {iou:.4f} over {truth.sum()} shadowed of {plate.sum()} plate pixels")
    assert truth.sum() > 500
    assert iou >= 0.95


def test_point_light_lit_faces_have_no_acne(renderer: SurfaceRenderer) -> None:
    ratio, world, normals, plate, ball = _shadow_setup(renderer, POINT)
    light = np.array(POINT["position"])
    # Lit in truth: plate pixels no ball sphere hides, and ball pixels facing the light.
    surface = np.isfinite(world[..., 1]) & np.isfinite(ratio)
    to_light = light - world
    to_light /= np.linalg.norm(to_light, axis=2, keepdims=True)
    facing = np.einsum("ijk,ijk->ij", np.nan_to_num(normals), np.nan_to_num(to_light)) > 0.3
    ball_faces = surface & ~plate & (world[..., 1] > 0.4) & facing
    plate_lit = plate.copy()
    plate_lit[plate] = ~occluded(world[plate], light, ball, R)
    for name, mask in (("plate", plate_lit), ("ball", ball_faces)):
        values = ratio[mask]
        print(
            f"{name}: {mask.sum()} lit pixels, mean ratio {values.mean():.4f}, "
            f"1st percentile {np.percentile(values, 1):.4f}"
        )
        assert mask.sum() > 300
        assert values.mean() >= 0.98


def _penumbra_width(
    rho: npt.NDArray[np.float64], value: npt.NDArray[np.float64], least: int = 5
) -> float:
    """Distance between the radii where the radial profile (median per bin) crosses 0.1 and
    0.9, the profile made monotone by a running maximum from the centre outwards."""
    bins = np.arange(0.0, rho.max(), 0.02)
    index = np.digitize(rho, bins)
    centres, medians = [], []
    for k in range(1, len(bins)):
        chosen = value[index == k]
        if chosen.size >= least:
            centres.append(0.5 * (bins[k - 1] + bins[k]))
            medians.append(float(np.median(chosen)))
    profile = np.maximum.accumulate(np.clip(medians, 0.0, 1.0))
    x = np.asarray(centres)
    return float(np.interp(0.9, profile, x) - np.interp(0.1, profile, x))


def test_sphere_light_penumbra_width_follows_similar_triangles(renderer: SurfaceRenderer) -> None:
    light_y, light_radius, ball_y = 3.0, 0.35, 1.2
    light = {
        "type": "sphere",
        "position": [0.0, light_y, 0.0],
        "radius": light_radius,
        "intensity": 8.0,
    }
    ratio, world, _, plate, ball = _shadow_setup(renderer, light, ball_y=ball_y)
    points = world[plate]
    rho = np.hypot(points[:, 0], points[:, 2])
    plane = float(np.median(points[:, 1]))
    silhouette = float(np.max(np.hypot(ball[:, 0], ball[:, 2]))) + R
    inner, outer = penumbra_edges(light_y, light_radius, ball_y, silhouette, plane)
    # The exact profile of a sphere light past a sphere (quadrature over the light's disc along
    # one radius): how its 10-90 % width relates to the full width.
    radii = np.linspace(0.0, outer * 1.3, 80)
    line = np.stack([radii, np.full_like(radii, plane), np.zeros_like(radii)], axis=1)
    exact = visible_fraction(line, np.array([0.0, light_y, 0.0]), light_radius, ball, R)
    exact_width = _penumbra_width(radii, exact, least=1)
    rendered_width = _penumbra_width(rho, ratio[plate])
    shape = exact_width / (outer - inner)
    print(
        f"penumbra: analytic {outer - inner:.4f} (umbra {inner:.3f}, outer {outer:.3f}); "
        f"10-90 %: exact {exact_width:.4f}, rendered {rendered_width:.4f}; "
        f"rendered full width {rendered_width / shape:.4f}"
    )
    assert abs(rendered_width / shape - (outer - inner)) <= 0.2 * (outer - inner)


def test_directional_shadow_matches_ray_traced_truth(renderer: SurfaceRenderer) -> None:
    travel = np.array([0.4, -1.0, 0.5])
    light = {"type": "directional", "direction": list(travel), "intensity": 3.0}
    ratio, world, _, plate, ball = _shadow_setup(renderer, light)
    towards = -travel / np.linalg.norm(travel)
    truth = occluded(world[plate], world[plate] + 10.0 * towards, ball, R)
    iou = _iou(ratio[plate] < 0.5, truth)
    print(f"directional: IoU {iou:.4f} over {truth.sum()} shadowed pixels")
    assert truth.sum() > 500
    assert iou >= 0.95


def test_radius_zero_sphere_light_is_the_point_light(renderer: SurfaceRenderer) -> None:
    """A sphere light of radius 0 is drawn as a point light: byte-identical images, shadowed
    or not."""
    _, positions = _particles(1.0)
    for shadows in (False, True):
        point = _render(renderer, positions, _scene([dict(POINT, shadows=shadows)]))
        sphere = dict(POINT, type="sphere", radius=0.0, shadows=shadows)
        assert np.array_equal(_render(renderer, positions, _scene([sphere])).rgba, point.rgba)


def test_small_sphere_light_shades_like_the_point_light(renderer: SurfaceRenderer) -> None:
    """Radius 1e-4 (of a light 3 units away): the representative point and the form factor
    tend to the point light's direction and irradiance, so the images agree to fp32 rounding
    of the extra arithmetic (relative 1e-3 of the brightest pixel)."""
    _, positions = _particles(1.0)
    point = _render(renderer, positions, _scene([POINT])).rgba
    tiny = _render(renderer, positions, _scene([dict(POINT, type="sphere", radius=1e-4)])).rgba
    assert np.abs(tiny - point).max() <= 1e-3 * point[..., :3].max()


def test_shadows_off_runs_no_shadow_stage(renderer: SurfaceRenderer) -> None:
    _, positions = _particles(1.0)
    _, stats = renderer.render(ParticleFrame(positions), _scene([POINT]))
    assert "shadow" not in stats.stage_ms
    _, stats = renderer.render(ParticleFrame(positions), _scene([dict(POINT, shadows=True)]))
    assert "shadow" in stats.stage_ms


@pytest.mark.parametrize(
    "light",
    [
        # inside the cloud: at the ball's centre, inside its particles
        {"type": "sphere", "position": [0.0, 1.0, 0.0], "radius": 0.05},
        # touching the ball's top surface
        {"type": "point", "position": [0.0, 1.0 + BALL_RADIUS + R, 0.0]},
        # behind the camera
        {"type": "sphere", "position": [2.5, 5.0, 6.0], "radius": 0.2},
        # huge: the whole scene inside the light
        {"type": "sphere", "position": [0.0, 2.0, 0.0], "radius": 50.0},
    ],
    ids=["inside-cloud", "touching", "behind-camera", "huge"],
)
def test_hard_lights_render_finite_and_sane(
    renderer: SurfaceRenderer, light: dict[str, Any]
) -> None:
    ratio, world, _, plate, ball = _shadow_setup(renderer, dict(light, intensity=5.0))
    values = ratio[plate]
    assert np.isfinite(values).all()
    assert (values <= 1.0 + 1e-4).all()  # a shadow only ever takes light away
    position = np.array(light["position"])
    if light.get("radius", 0.0) < 1.0:
        truth = occluded(world[plate], position, ball, R)
        iou = _iou(values < 0.5, truth)
        print(f"{light}: IoU {iou:.4f}, {truth.sum()} shadowed")
        assert truth.sum() == 0 or iou >= 0.9


def test_shadows_at_1e5_match_the_origin(renderer: SurfaceRenderer) -> None:
    """The same scene moved by 1e5 on every axis: light-space maths is relative to the particles'
    centre in float64, so the shadow masks agree."""
    near, _, _, plate, _ = _shadow_setup(renderer, POINT)
    far_light = dict(POINT, position=list(np.array(POINT["position"]) + 1e5))
    far, _, _, far_plate, _ = _shadow_setup(renderer, far_light, offset=1e5)
    both = plate & far_plate
    iou = _iou(near[both] < 0.5, far[both] < 0.5)
    print(f"1e5: IoU {iou:.4f} against the origin's mask")
    assert iou >= 0.97


@pytest.mark.parametrize(
    ("light", "field", "words"),
    [
        ({"type": "sphere", "radius": 0.1}, "lights[0].position", "sphere light needs a position"),
        (
            {"type": "point", "position": [0, 1, 0], "radius": 0.1},
            "lights[0].radius",
            "only sphere",
        ),
        (
            {"type": "sphere", "position": [0, 1, 0], "radius": -1},
            "lights[0].radius",
            "[0, 1000000]",
        ),
        (
            {"type": "point", "position": [0, 1, 0], "shadow_map_size": 8},
            "lights[0].shadow_map_size",
            "16",
        ),
        (
            {"type": "point", "position": [0, 1, 0], "temperature_k": 50},
            "lights[0].temperature_k",
            "1000",
        ),
    ],
)
def test_bad_light_fields_name_the_field(light: dict[str, Any], field: str, words: str) -> None:
    with pytest.raises(InputError) as caught:
        scene_from_dict({"lights": [light]})
    assert caught.value.field == field
    assert words in str(caught.value)


def test_a_frame_may_move_the_arc(renderer: SurfaceRenderer) -> None:
    """A frame's scene override replaces the lights array (as it replaces the camera): the arc
    moves, and its shadow with it."""
    base = {"lights": [dict(POINT, type="sphere", radius=0.1, shadows=True)]}
    moved = merge_scene_dicts(base, {"lights": [dict(base["lights"][0], position=[0.6, 3.0, 0.7])]})
    scene = scene_from_dict(moved)
    assert scene.lights[0].position == (0.6, 3.0, 0.7)
    assert scene.lights[0].shadows and scene.lights[0].radius == 0.1


def test_temperature_tints_the_light(renderer: SurfaceRenderer) -> None:
    """temperature_k multiplies the colour by the blackbody's at luminance 1: 2000 K is
    red-orange and keeps the light's luminance."""
    from sphrender.server.engine.lighting.blackbody import REC709_LUMINANCE
    from sphrender.server.engine.lighting.lights import light_radiance

    warm = light_radiance(
        scene_from_dict({"lights": [dict(POINT, temperature_k=2000.0)]}).lights[0]
    )
    assert warm[0] > warm[1] > warm[2]
    luminance = warm @ REC709_LUMINANCE
    assert luminance == pytest.approx(POINT["intensity"], rel=1e-6)
