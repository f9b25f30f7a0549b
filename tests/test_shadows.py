"""Shadows and sphere lights against ray-traced truth (real EGL): a jittered particle ball over
a particle plate (server/bench/shadow_scene.py), lit by point, sphere and directional lights.

Truth (server/bench/shadow_truth.py): a plate pixel's world point (from the Z AOV) is in shadow
when the segment to the light meets a ball particle's sphere; a sphere light's visible fraction is
a 256-point quadrature over its disc; its penumbra's full width comes from similar triangles.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.server.bench.shadow_scene import (
    BALL_RADIUS,
    BallOverPlate,
    iou,
    penumbra,
    render_both,
    shadow_iou,
)
from sphrender.server.bench.shadow_truth import occluded
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict
from sphrender.server.scene.layering import merge_scene_dicts

R = 0.05  # particle radius
SETUP = BallOverPlate(radius=R)
POINT = {"type": "point", "position": [-0.5, 3.0, -0.7], "intensity": 8.0}


def test_point_light_shadow_matches_ray_traced_truth(renderer: SurfaceRenderer) -> None:
    result = render_both(renderer, POINT, SETUP)
    score, shadowed = shadow_iou(result, np.array(POINT["position"]), R)
    print(f"point light: IoU {score:.4f} over {shadowed} shadowed of {result.plate.sum()} pixels")
    assert shadowed > 500
    assert score >= 0.95


def test_point_light_lit_faces_have_no_acne(renderer: SurfaceRenderer) -> None:
    """Lit in truth (plate pixels no ball sphere hides, ball pixels facing the light): the
    shadowed render keeps >= 98 % of the unshadowed one on average."""
    result = render_both(renderer, POINT, SETUP)
    light, world, plate = np.array(POINT["position"]), result.world, result.plate
    surface = np.isfinite(world[..., 1]) & np.isfinite(result.ratio)
    to_light = np.nan_to_num(light - world)
    to_light /= np.maximum(np.linalg.norm(to_light, axis=2, keepdims=True), 1e-30)
    facing = np.einsum("ijk,ijk->ij", np.nan_to_num(result.normals), to_light) > 0.3
    ball_faces = surface & ~plate & (world[..., 1] > 0.4) & facing
    plate_lit = plate.copy()
    plate_lit[plate] = ~occluded(world[plate], light, result.ball, R)
    for name, mask in (("plate", plate_lit), ("ball", ball_faces)):
        values = result.ratio[mask]
        print(f"{name}: {mask.sum()} lit pixels, mean ratio {values.mean():.4f}")
        assert mask.sum() > 300
        assert values.mean() >= 0.98


def test_sphere_light_penumbra_width_follows_similar_triangles(renderer: SurfaceRenderer) -> None:
    """The rendered 10-90 % width, scaled to a full width by the exact profile's shape, within
    20 % of the similar-triangles width."""
    setup = BallOverPlate(radius=R, ball_y=1.2)
    light = {"type": "sphere", "position": [0.0, 3.0, 0.0], "radius": 0.35, "intensity": 8.0}
    found = penumbra(render_both(renderer, light, setup), 3.0, 0.35, 1.2, R)
    print(f"penumbra: {found}, rendered full width {found.rendered_full:.4f}")
    assert abs(found.error) <= 0.2


def test_directional_shadow_matches_ray_traced_truth(renderer: SurfaceRenderer) -> None:
    travel = np.array([0.4, -1.0, 0.5])
    light = {"type": "directional", "direction": list(travel), "intensity": 3.0}
    result = render_both(renderer, light, SETUP)
    far = result.world - 10.0 * travel / np.linalg.norm(travel)
    score, shadowed = shadow_iou(result, far, R)
    print(f"directional: IoU {score:.4f} over {shadowed} shadowed pixels")
    assert shadowed > 500
    assert score >= 0.95


def test_directional_penumbra_follows_the_angular_radius(renderer: SurfaceRenderer) -> None:
    """A sun of angular radius 8 degrees straight above: the same similar triangles as a sphere
    light of radius H tan(8 deg) at a great height H."""
    setup = BallOverPlate(radius=R, ball_y=1.2, turned=True)  # no lattice holes along y
    light = {"type": "directional", "direction": [0, -1, 0], "angular_radius_deg": 8.0}
    height = 1e3
    disc = height * np.tan(np.radians(8.0))
    found = penumbra(render_both(renderer, dict(light, intensity=3.0), setup), height, disc, 1.2, R)
    print(f"directional penumbra: {found}, rendered full width {found.rendered_full:.4f}")
    assert abs(found.error) <= 0.2


def _colour(renderer: SurfaceRenderer, light: dict[str, Any]) -> np.ndarray:
    frame, _ = renderer.render(ParticleFrame(SETUP.positions()), SETUP.scene([light]))
    return frame.rgba


def test_radius_zero_sphere_light_is_the_point_light(renderer: SurfaceRenderer) -> None:
    """A sphere light of radius 0 is drawn as a point light: byte-identical images, shadowed
    or not."""
    for shadows in (False, True):
        point = _colour(renderer, dict(POINT, shadows=shadows))
        sphere = _colour(renderer, dict(POINT, type="sphere", radius=0.0, shadows=shadows))
        assert np.array_equal(sphere, point)


def test_small_sphere_light_shades_like_the_point_light(renderer: SurfaceRenderer) -> None:
    """Radius 1e-4 (of a light 3 units away): the representative point and the form factor
    tend to the point light's direction and irradiance, so the images agree to fp32 rounding
    of the extra arithmetic (relative 1e-3 of the brightest pixel)."""
    point = _colour(renderer, POINT)
    tiny = _colour(renderer, dict(POINT, type="sphere", radius=1e-4))
    assert np.abs(tiny - point).max() <= 1e-3 * point[..., :3].max()


def test_shadows_off_runs_no_shadow_stage(renderer: SurfaceRenderer) -> None:
    frame = ParticleFrame(SETUP.positions())
    _, stats = renderer.render(frame, SETUP.scene([POINT]))
    assert "shadow" not in stats.stage_ms
    _, stats = renderer.render(frame, SETUP.scene([dict(POINT, shadows=True)]))
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
    """Every pixel finite (render_both checks), a shadow only takes light away, and where the
    light is small the shadow still matches the truth (IoU >= 0.9: these masks are small)."""
    result = render_both(renderer, dict(light, intensity=5.0), SETUP)
    values = result.ratio[result.plate]
    assert np.isfinite(values).all()
    assert (values <= 1.0 + 1e-4).all()
    if light.get("radius", 0.0) < 1.0:
        score, shadowed = shadow_iou(result, np.array(light["position"]), R)
        print(f"{light}: IoU {score:.4f}, {shadowed} shadowed")
        assert shadowed == 0 or score >= 0.9


def test_shadows_at_1e5_match_the_origin(renderer: SurfaceRenderer) -> None:
    """The same scene moved by 1e5 on every axis: light-space maths is relative to the particles'
    centre in float64, so the shadow masks agree."""
    near = render_both(renderer, POINT, SETUP)
    far_light = dict(POINT, position=list(np.array(POINT["position"]) + 1e5))
    far = render_both(renderer, far_light, BallOverPlate(radius=R, offset=1e5))
    both = near.plate & far.plate
    score = iou(near.ratio[both] < 0.5, far.ratio[both] < 0.5)
    print(f"1e5: IoU {score:.4f} against the origin's mask")
    assert score >= 0.97


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
            {"type": "point", "position": [0, 1, 0], "angular_radius_deg": 1},
            "lights[0].angular_radius_deg",
            "only directional",
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
    moves, and its shadow with it (still the truth's)."""
    arc = dict(POINT, type="sphere", radius=0.02)
    moved = merge_scene_dicts({"lights": [arc]}, {"lights": [dict(arc, position=[0.6, 3.0, 0.7])]})
    light = scene_from_dict(moved).lights[0]
    assert light.position == (0.6, 3.0, 0.7) and light.radius == 0.02
    result = render_both(renderer, dict(arc, position=list(light.position)), SETUP)
    score, shadowed = shadow_iou(result, np.array(light.position), R)
    assert shadowed > 300 and score >= 0.95


def test_temperature_tints_the_light() -> None:
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


def test_shadow_maps_beyond_the_gpu_are_a_clear_error(renderer: SurfaceRenderer) -> None:
    """Eight 2048 cube maps need a 6144 x 32768 atlas: more than a GL texture may be here
    (llvmpipe and most GPUs: 16384), answered as bad input naming the lights."""
    light = dict(POINT, shadows=True, shadow_map_size=2048)
    limit = renderer.gl.limits.max_texture_size
    if limit >= 8 * 2 * 2048:
        pytest.skip(f"this GL takes {limit}-texel textures")
    with pytest.raises(InputError) as caught:
        renderer.render(ParticleFrame(SETUP.positions()), SETUP.scene([light] * 8))
    assert caught.value.field == "lights"
    assert "shadow_map_size" in str(caught.value)


def test_sphere_light_diffuse_is_the_point_lights_above_the_horizon(
    renderer: SurfaceRenderer,
) -> None:
    """A rough dielectric plate (diffuse, F0 0.04) under a sphere light of radius 0.5 whose
    whole disc is above every pixel's horizon: the form factor is cos(theta) I / d^2, the point
    light's, so the image's total agrees within 2 % (what differs is the 4 % specular lobe,
    widened by the representative point)."""
    plate = lattice_slab(6.0, 6.0, 2, 0.03, top_y=0.0)
    point = {"type": "point", "position": [0.0, 1.5, -1.0], "intensity": 5.0}

    def total(light: dict[str, Any]) -> float:
        scene = scene_from_dict(
            {
                "image": {"width": 96, "height": 96},
                "camera": {"eye": [0.0, 4.0, 2.0], "target": [0, 0, 0], "fov_y": 60},
                "particles": {"radius": 0.03},
                "shading": {"ibl_mode": "none"},
                "material": {"preset": "iron", "roughness": 0.9, "metallic": 0.0},
                "lights": [light],
            }
        )
        frame, _ = renderer.render(ParticleFrame(plate), scene)
        return float(frame.rgba[..., :3].sum())

    ratio = total(dict(point, type="sphere", radius=0.5)) / total(point)
    print(f"sphere / point light, diffuse plate: {ratio:.4f}")
    assert abs(ratio - 1.0) <= 0.02


def test_frames_after_a_shadowed_frame_render_as_before(renderer: SurfaceRenderer) -> None:
    """The shadow pass binds its spheres to a storage-buffer binding point the splat's peak
    temperatures also use: a frame drawn after a shadowed one is byte-identical to the same frame
    drawn before it (binding points are shared context state, claimed by whoever binds)."""
    positions = lattice_slab(0.6, 0.6, layers=2, particle_radius=0.015, top_y=0.0)
    peaks = np.where(positions[:, 0] > 0.0, 573.15, 293.15)
    frame = ParticleFrame(
        positions=positions,
        temperatures=np.full(len(positions), 293.15, np.float32),
        peak_temperatures=peaks.astype(np.float32),
    )
    scene = scene_from_dict(
        {
            "image": {"width": 64, "height": 32},
            "camera": {"eye": [0.0, 1.0, 0.8], "target": [0.0, 0.0, 0.0]},
            "particles": {"radius": 0.015},
            "material": {"preset": "iron", "heat_tint": True},
            "lights": [{"direction": [0.0, -1.0, -0.3], "intensity": 3.0}],
            "shading": {"ibl_mode": "none"},
        }
    )
    before, _ = renderer.render(frame, scene)
    render_both(renderer, dict(POINT), SETUP)
    after, _ = renderer.render(frame, scene)
    assert np.array_equal(before.rgba, after.rgba)
