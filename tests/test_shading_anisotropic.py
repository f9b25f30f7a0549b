"""The brushed finish: the shader's anisotropic GGX against a float64 numpy reference
(reference_anisotropic.py) and Mitsuba 3's rough conductor, and the world-space surface
detail staying put when the camera moves.

Cases: roughness 0.5 (alpha 0.25) with anisotropy 0.6, i.e. alpha 0.1 along the brush and 0.4
across; a white F0 (the furnace) and copper's; n.v = 0.9, 0.5, 0.2 with the brush at every
azimuth about the normal (each pixel of a 4 x 3 image a different one).

Tolerances:
* directional light: the shader evaluates the same formulas in fp32 from fp32 normals; the
  normals' rounding moves h by ~1e-7 rad, which the lobe (0.1 rad wide) turns into ~1e-5
  relative: 1e-4 leaves room for driver transcendental error.
* uniform environment, sampled mode, 4096 Hammersley samples: the estimate of a smooth
  integrand converges like ~log(N)^2 / N (512 samples leave 2 % at n.v = 0.2, and a numpy
  Hammersley estimate of the same pdf leaves the same: the estimate's own error, not a bias);
  the issue's bound, 2 %, is what is asserted.
* uniform environment, prefiltered mode: test_shading_anisotropic_ibl.py.
* Mitsuba: pointwise, its float32 evaluation (1e-4 relative); its directional albedo from
  4096 stratified BSDF samples has a spread of ~0.3 %, and the G-form difference (Mitsuba's G
  is separable) is divided out exactly with the numpy ratio, leaving the 2 % of the issue.
"""

from __future__ import annotations

import functools
import math

import mitsuba as mi  # the test extra: a missing reference renderer fails, never skips
import numpy as np
import pytest
import reference_anisotropic as ra
import reference_shading as ref
from single_passes import SinglePasses
from world_fixed import two_view_angles

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.lighting.materials import METAL_F0
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

ROUGHNESS = 0.5
ANISOTROPY = 0.6
ALPHA_T = ROUGHNESS**2 * (1 - ANISOTROPY)
ALPHA_B = ROUGHNESS**2 * (1 + ANISOTROPY)
BRUSH = np.array([1.0, 0.0, 0.0])
MUS = (0.9, 0.5, 0.2)
F0S = {"white": (1.0, 1.0, 1.0), "copper": METAL_F0["copper"]}
ONE = np.ones(3)


def brushed_scene(f0: tuple[float, float, float], **shading: object) -> Scene:
    extra = shading.pop("lights", None)
    data: dict[str, object] = {
        "image": {"width": 4, "height": 3},
        "camera": {"eye": [0.0, 0.0, 3.0], "fov_y": 30.0},
        "material": {"f0": list(f0), "metallic": 1.0, "roughness": ROUGHNESS},
        "finish": {"anisotropy": ANISOTROPY, "brush_direction": BRUSH.tolist()},
        "shading": shading,
    }
    if extra is not None:
        data["lights"] = extra
    else:
        data["environment"] = {"uniform": [1.0, 1.0, 1.0]}
    return scene_from_dict(data)


def shade(renderer: SurfaceRenderer, scene: Scene, mu: float) -> tuple[np.ndarray, np.ndarray]:
    """Shade normals with n.v = mu whose azimuth about v turns across the image; returns the
    RGB image and the local view vectors (t, b, n frame) per pixel."""
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    view = ref.view_vectors(camera)
    azimuth = np.linspace(0.3, 0.3 + 2 * np.pi, view[..., 0].size, endpoint=False)
    normals = ref.directions_with_nv(
        view, np.full(view.shape[:2], mu), azimuth.reshape(view.shape[:2])
    )
    normals32 = normals.astype(np.float32).astype(np.float64)
    rgba = SinglePasses(renderer).shade_normal_depth(ref.normal_depth_image(camera, normals), scene)
    assert np.all(np.isfinite(rgba))
    t, b, at, ab = ra.brushed_frame(normals32, BRUSH, ROUGHNESS**2, ANISOTROPY)
    assert np.allclose(at, ALPHA_T) and np.allclose(ab, ALPHA_B)  # no pixel near the fade
    return rgba[..., :3].astype(np.float64), ra.to_local(view, t, b, normals32)


@pytest.mark.parametrize("mu", MUS)
@pytest.mark.parametrize("f0_name", list(F0S))
def test_directional_light_matches_numpy(
    renderer: SurfaceRenderer, mu: float, f0_name: str
) -> None:
    travel = np.array([0.3, -0.4, -1.0])
    light = [{"type": "directional", "direction": travel.tolist(), "intensity": 2.0}]
    scene = brushed_scene(F0S[f0_name], ibl_mode="none", lights=light)
    got, view_local = shade(renderer, scene, mu)
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    normals = (
        ref.directions_with_nv(
            ref.view_vectors(camera),
            np.full((3, 4), mu),
            np.linspace(0.3, 0.3 + 2 * np.pi, 12, endpoint=False).reshape(3, 4),
        )
        .astype(np.float32)
        .astype(np.float64)
    )
    t, b, _, _ = ra.brushed_frame(normals, BRUSH, ROUGHNESS**2, ANISOTROPY)
    l_local = ra.to_local(
        np.broadcast_to(-travel / np.linalg.norm(travel), normals.shape), t, b, normals
    )
    f = ra.brdf_specular(
        view_local, l_local, ALPHA_T, ALPHA_B, np.asarray(F0S[f0_name]), separable=False
    )
    want = f * 2.0 * np.maximum(l_local[..., 2], 0.0)[..., None]
    lit = want > 1e-3 * want.max()
    assert lit.sum() >= 12  # most pixels see the light
    assert np.max(np.abs(got - want)[lit] / want[lit]) < 1e-4
    assert np.all(got[~lit] < 2e-3 * want.max())


#: The quadrature's cells: n = 150 differs from n = 800 by < 1e-4 relative on this lobe.
QUADRATURE_N = 150


@functools.cache
def reference_albedos(mu: float) -> np.ndarray:
    """(3, 4, 6): numpy albedo per pixel of `shade`'s image at n.v = mu, white F0 in the first
    three channels and copper's in the last three."""
    scene = brushed_scene(F0S["white"], ibl_mode="none")
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    view = ref.view_vectors(camera)
    azimuth = np.linspace(0.3, 0.3 + 2 * np.pi, view[..., 0].size, endpoint=False)
    normals = ref.directions_with_nv(view, np.full(view.shape[:2], mu), azimuth.reshape(3, 4))
    normals = normals.astype(np.float32).astype(np.float64)
    t, b, _, _ = ra.brushed_frame(normals, BRUSH, ROUGHNESS**2, ANISOTROPY)
    local = ra.to_local(view, t, b, normals)
    f0 = np.concatenate([F0S["white"], F0S["copper"]])
    return np.stack(
        [
            [ra.albedo(local[i, j], ALPHA_T, ALPHA_B, f0, n=QUADRATURE_N) for j in range(4)]
            for i in range(3)
        ]
    )


@pytest.mark.parametrize("f0_name", list(F0S))
def test_uniform_environment_sampled_matches_numpy_albedo(
    renderer: SurfaceRenderer, f0_name: str
) -> None:
    channels = slice(0, 3) if f0_name == "white" else slice(3, 6)
    worst = 0.0
    for mu in MUS:
        scene = brushed_scene(F0S[f0_name], ibl_mode="sampled", ibl_samples=4096)
        got, _ = shade(renderer, scene, mu)
        want = reference_albedos(mu)[..., channels]
        worst = max(worst, float(np.max(np.abs(got - want) / want)))
    print(f"sampled {f0_name}: worst relative error {worst:.4f}")
    assert worst < 0.02


def mitsuba_albedo(view: np.ndarray, count: int = 4096) -> float:
    """Mitsuba's directional albedo of a rough conductor (F = 1, alpha_u along x = the brush),
    from `count` stratified BSDF samples."""
    mi.set_variant("scalar_rgb")
    bsdf = mi.load_dict(
        {
            "type": "roughconductor",
            "distribution": "ggx",
            "alpha_u": ALPHA_T,
            "alpha_v": ALPHA_B,
            "material": "none",
        }
    )
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    si.wi = mi.Vector3f(*view)
    side = int(math.sqrt(count))
    total = 0.0
    for i in range(side):
        for j in range(side):
            sample = mi.Point2f((i + 0.5) / side, (j + 0.5) / side)
            _, weight = bsdf.sample(mi.BSDFContext(), si, 0.5, sample)
            total += float(weight[0])
    return total / side**2


def test_mitsuba_rough_conductor_agrees_pointwise_and_in_the_furnace(
    renderer: SurfaceRenderer,
) -> None:
    mi.set_variant("scalar_rgb")
    bsdf = mi.load_dict(
        {
            "type": "roughconductor",
            "distribution": "ggx",
            "alpha_u": ALPHA_T,
            "alpha_v": ALPHA_B,
            "material": "none",
        }
    )
    rng = np.random.default_rng(7)
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    for _ in range(32):
        v, light = (
            w / np.linalg.norm(w) for w in np.abs(rng.normal(size=(2, 3))) * [[1, 1, 1], [-1, 1, 1]]
        )
        si.wi = mi.Vector3f(*v)
        theirs = float(np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*light)))[0])
        ours = (
            ra.brdf_specular(v, light, ALPHA_T, ALPHA_B, np.ones(3), separable=True)[0] * light[2]
        )
        assert abs(theirs - ours) <= 1e-4 * ours + 1e-7
    # The shader's furnace (height-correlated G), with the G form divided out, against Mitsuba's:
    # sampled and prefiltered (the anisotropic split-sum table) IBL.
    sampled = brushed_scene(F0S["white"], ibl_mode="sampled", ibl_samples=4096)
    prefiltered = brushed_scene(F0S["white"], ibl_mode="prefiltered")
    worst = {"sampled": 0.0, "prefiltered": 0.0}
    for mu in MUS:
        got, view_local = shade(renderer, sampled, mu)
        got_prefiltered, _ = shade(renderer, prefiltered, mu)
        for pixel in [(0, 0), (1, 2), (2, 1)]:
            v = view_local[pixel]
            ratio = (
                ra.albedo(v, ALPHA_T, ALPHA_B, ONE, separable=True, n=QUADRATURE_N)[0]
                / ra.albedo(v, ALPHA_T, ALPHA_B, ONE, n=QUADRATURE_N)[0]
            )
            theirs = mitsuba_albedo(v)
            for mode, image in (("sampled", got), ("prefiltered", got_prefiltered)):
                error = abs(image[pixel][0] * ratio - theirs) / theirs
                worst[mode] = max(worst[mode], error)
    print(f"Mitsuba furnace: worst relative difference {worst}")
    assert max(worst.values()) < 0.02


def test_brush_along_the_normal_falls_back_to_isotropic(renderer: SurfaceRenderer) -> None:
    """Normals within the fade (and exactly along the brush) shade finite, and exactly along it
    as the isotropic lobe does: the same arithmetic up to fp32 rounding, but the IBL's (A, B)
    from the anisotropic table at alpha_t = alpha_b, which differs from the isotropic table by
    their interpolation errors (measured 4e-4 here; each within 1 % of its integral)."""
    light = [{"type": "directional", "direction": [0.2, -0.3, -1.0], "intensity": 1.0}]
    data = {
        "image": {"width": 4, "height": 3},
        "camera": {"eye": [0.0, 0.0, 3.0], "fov_y": 30.0},
        "material": {"preset": "copper", "roughness": ROUGHNESS},
        "lights": light,
        "environment": {"preset": "workshop"},
    }
    camera = Camera.from_config(scene_from_dict(data).camera, 4, 3)
    normals = np.zeros((3, 4, 3))
    normals[..., 2] = 1.0
    brushed = scene_from_dict({**data, "finish": {"anisotropy": 1.0, "brush_direction": [0, 0, 1]}})
    plain = scene_from_dict(data)
    passes = SinglePasses(renderer)
    got = passes.shade_normal_depth(ref.normal_depth_image(camera, normals), brushed)
    want = passes.shade_normal_depth(ref.normal_depth_image(camera, normals), plain)
    assert np.all(np.isfinite(got))
    assert np.allclose(got, want, rtol=2e-3, atol=1e-6)


def plate_scene(eye: list[float], detail: str = "brushed") -> Scene:
    return scene_from_dict(
        {
            "image": {"width": 128, "height": 96},
            "camera": {"eye": eye, "target": [0.0, 0.0, 0.0], "fov_y": 35.0},
            "particles": {"radius": 0.02},
            "finish": {
                "detail": detail,
                "brush_direction": [1.0, 0.0, 0.4],
                "detail_scale": 0.2,
                "detail_normal_strength": 0.3,
            },
        }
    )


def top_face_slopes(
    renderer: SurfaceRenderer, frame: ParticleFrame, eye: list[float]
) -> tuple[np.ndarray, np.ndarray]:
    """World (x, z) of the plate's top-face pixels seen from `eye` (positions from Z) and the
    detail's slope there: s = n - n_d / (n . n_d) from the normal without (n) and with (n_d) the
    detail, which inverts n_d ~ n - s (detail_normal); its x and z components."""
    scene = plate_scene(eye)
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    out, _ = renderer.render(frame, scene, depth=True, normals=True)
    plain, _ = renderer.render(frame, plate_scene(eye, "none"), depth=True, normals=True)
    assert out.depth is not None and out.normals is not None
    assert plain.depth is not None and plain.normals is not None
    assert np.all(np.isfinite(out.rgba)) and np.array_equal(out.depth, plain.depth)
    rays = ref.pixel_rays(camera)
    world = camera.eye + rays.directions * (out.depth.astype(np.float64) / rays.view_z)[..., None]
    n, n_d = plain.normals.astype(np.float64), out.normals.astype(np.float64)
    top = np.isfinite(world[..., 1]) & (world[..., 1] > 0.0) & (n[..., 1] > 0.99)
    n, n_d = n[top], n_d[top]
    slope = n - n_d / np.sum(n * n_d, axis=-1, keepdims=True)
    return world[top][:, [0, 2]], slope[:, [0, 2]]


def test_detail_normals_stay_put_when_the_camera_moves(renderer: SurfaceRenderer) -> None:
    """The plate's top face from two cameras: view B's detail slopes interpolated (linear, over
    its pixels' world x, z from Z) at view A's points; the normals a flat face gets from them,
    (-s_x, 1, -s_z), agree within 1 degree. The interpolation's own error: the grooves are
    s = 0.2 wide, B's pixels ~0.01 apart; at s = 0.15 it measured 0.35 deg at most for a camera
    moved by 0.02, 0.84 for this half turn, 3.6 at s = 0.05 (it grows as (h / s)^2).
    The base normals differ between the views by a few degrees (the screen-space surface); the
    slope's x, z components do not see that at first order, the full normals would."""
    frame = make_frame(lattice_slab(1.2, 1.2, 2, 0.02))
    points_a, slopes_a = top_face_slopes(renderer, frame, [0.0, 1.3, 1.0])
    points_b, slopes_b = top_face_slopes(renderer, frame, [0.7, 1.1, -0.9])
    angle, tilt = two_view_angles(points_a, slopes_a, points_b, slopes_b)
    assert tilt.mean() > 3.0  # the detail is there, and a screen-fixed one would differ this much
    assert angle.max() < 1.0


def test_brushed_plate_example_is_a_valid_scene() -> None:
    from pathlib import Path

    from sphrender.server.scene import read_scene_toml

    path = Path(__file__).resolve().parents[1] / "examples" / "brushed_plate.toml"
    scene = scene_from_dict(read_scene_toml(path))
    assert scene.finish.anisotropy > 0 and scene.finish.detail == "brushed"


def test_zero_brush_direction_is_refused_naming_the_field() -> None:
    with pytest.raises(InputError) as caught:
        scene_from_dict({"finish": {"anisotropy": 0.5, "brush_direction": [0.0, 0.0, 0.0]}})
    assert str(caught.value) == "finish.brush_direction: must not be the zero vector"


@pytest.mark.parametrize("mode", ["prefiltered", "sampled"])
def test_extreme_lobes_stay_finite(renderer: SurfaceRenderer, mode: str) -> None:
    """Roughness 0 with anisotropy +-1 (alpha clamped to 0.002 on one axis) under a light on
    the mirror direction and a bright environment: every pixel finite."""
    normals = np.zeros((3, 4, 3))
    normals[..., 2] = 1.0
    for anisotropy in (-1.0, 1.0):
        scene = scene_from_dict(
            {
                "image": {"width": 4, "height": 3},
                "camera": {"eye": [0.0, 0.0, 3.0], "fov_y": 30.0},
                "material": {"preset": "silver", "roughness": 0.0},
                "finish": {"anisotropy": anisotropy, "brush_direction": [0.3, 1.0, 0.0]},
                "lights": [{"type": "directional", "direction": [0, 0, -1], "intensity": 1e5}],
                "environment": {"preset": "workshop", "intensity": 1e3},
                "shading": {"ibl_mode": mode, "ibl_samples": 64},
            }
        )
        camera = Camera.from_config(scene.camera, 4, 3)
        rgba = SinglePasses(renderer).shade_normal_depth(
            ref.normal_depth_image(camera, normals), scene
        )
        assert np.all(np.isfinite(rgba)) and rgba[..., :3].max() > 0
