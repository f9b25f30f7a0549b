"""The brushed lobe under image-based light, prefiltered mode (the presets' IBL): the split sum
reads the anisotropic lobe's own (A, B) table (lighting/anisotropic_lut.py), so under a uniform
environment the shaded pixel is the lobe's directional albedo for any F0. Checked against the
float64 numpy albedo (reference_anisotropic.py, a hemisphere quadrature that shares nothing with
the table's sampling map) on three lobes, including a rough one seen at grazing along its smooth
axis (the isotropic lookup missed that by 19 %), at n.v from 0.9 down to 0.1, with the brush at
twelve azimuths about the normal (one per pixel).

Tolerance, 2 % (the issue's bound) over the table's own error budget: linear interpolation on
its grid is within 0.9 % for n.v >= 0.05, its quadrature within 0.2 %, RG16F rounding 0.05 %;
the reference quadrature at n = 200 differs from n = 800 by <= 0.11 % on these lobes.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator

import numpy as np
import pytest
import reference_anisotropic as ra
import reference_shading as ref
import test_shading_ibl as ibl
from single_passes import SinglePasses

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.lighting import environment as env
from sphrender.server.engine.lighting.materials import METAL_F0
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

BRUSH = np.array([1.0, 0.0, 0.0])
#: (roughness, anisotropy): the Mitsuba test's lobe (alpha 0.1 / 0.4), a rough one (alpha_t 0.16,
#: alpha_b clamped to 1) and one brushed across (negative anisotropy: alpha_t 0.2, alpha_b 0.05).
LOBES = [(0.5, 0.6), (0.9, 0.8), (0.35, -0.6)]
MUS = (0.9, 0.5, 0.2, 0.1)
F0S = {"white": (1.0, 1.0, 1.0), "copper": METAL_F0["copper"]}
QUADRATURE_N = 200


def brushed_scene(
    lobe: tuple[float, float], f0: tuple[float, float, float], **shading: object
) -> Scene:
    roughness, anisotropy = lobe
    return scene_from_dict(
        {
            "image": {"width": 4, "height": 3},
            "camera": {"eye": [0.0, 0.0, 3.0], "fov_y": 30.0},
            "material": {"f0": list(f0), "metallic": 1.0, "roughness": roughness},
            "finish": {"anisotropy": anisotropy, "brush_direction": BRUSH.tolist()},
            "environment": {"uniform": [1.0, 1.0, 1.0]},
            "shading": shading,
        }
    )


def pixel_normals(camera: Camera, mu: float) -> tuple[np.ndarray, np.ndarray]:
    """Normals with n.v = mu turning about v across the image (fp32-rounded) and the views."""
    view = ref.view_vectors(camera)
    azimuth = np.linspace(0.3, 0.3 + 2 * np.pi, view[..., 0].size, endpoint=False)
    normals = ref.directions_with_nv(view, np.full(view.shape[:2], mu), azimuth.reshape(3, 4))
    return normals.astype(np.float32).astype(np.float64), view


def shade(renderer: SurfaceRenderer, scene: Scene, mu: float) -> np.ndarray:
    camera = Camera.from_config(scene.camera, 4, 3)
    normals, _ = pixel_normals(camera, mu)
    rgba = SinglePasses(renderer).shade_normal_depth(ref.normal_depth_image(camera, normals), scene)
    assert np.all(np.isfinite(rgba))
    return rgba[..., :3].astype(np.float64)


@functools.cache
def reference_albedos(lobe: tuple[float, float], mu: float) -> np.ndarray:
    """(3, 4, 6): numpy albedo per pixel, white F0 in channels 0-2 and copper's in 3-5."""
    roughness, anisotropy = lobe
    camera = Camera.from_config(brushed_scene(lobe, F0S["white"]).camera, 4, 3)
    normals, view = pixel_normals(camera, mu)
    t, b, alpha_t, alpha_b = ra.brushed_frame(normals, BRUSH, roughness**2, anisotropy)
    local = ra.to_local(view, t, b, normals)
    f0 = np.concatenate([F0S["white"], F0S["copper"]])
    return np.stack(
        [
            [
                ra.albedo(local[i, j], alpha_t[i, j], alpha_b[i, j], f0, n=QUADRATURE_N)
                for j in range(4)
            ]
            for i in range(3)
        ]
    )


@pytest.mark.parametrize("lobe", LOBES)
def test_prefiltered_uniform_environment_is_the_anisotropic_albedo(
    renderer: SurfaceRenderer, lobe: tuple[float, float]
) -> None:
    worst = 0.0
    for f0_name, channels in (("white", slice(0, 3)), ("copper", slice(3, 6))):
        scene = brushed_scene(lobe, F0S[f0_name], ibl_mode="prefiltered")
        for mu in MUS:
            got = shade(renderer, scene, mu)
            want = reference_albedos(lobe, mu)[..., channels]
            worst = max(worst, float(np.max(np.abs(got - want) / want)))
    print(f"prefiltered, lobe {lobe}: worst relative error {worst:.4f}")
    assert worst < 0.02


def test_multiple_scattering_compensation_uses_the_lobes_albedo(renderer: SurfaceRenderer) -> None:
    """White furnace with the energy compensation on, sampled mode: the sampled single-scatter
    albedo (4096 samples, its own 2 % budget in test_shading_anisotropic.py) times 1 / E from
    the table is 1 where the table is the lobe's albedo; the isotropic table's E at one roughness
    leaves up to 19 % on the rough lobe. The direct light's compensation is the same factor."""
    worst = 0.0
    for lobe in LOBES[:2]:
        scene = brushed_scene(
            lobe, F0S["white"], ibl_mode="sampled", ibl_samples=4096, multiple_scattering=True
        )
        for mu in (0.9, 0.2, 0.1):
            worst = max(worst, float(np.max(np.abs(shade(renderer, scene, mu) - 1.0))))
    print(f"furnace with compensation: worst |1 - result| {worst:.4f}")
    assert worst < 0.02


@pytest.fixture(scope="module")
def smooth_renderer(
    gl_context: GLContext, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[SurfaceRenderer]:
    """A renderer whose environment directory holds test_shading_ibl's smooth environment."""
    directory = tmp_path_factory.mktemp("environments")
    ibl.write_exr(directory / "smooth.exr", ibl.smooth_test_environment().pixels)
    renderer = SurfaceRenderer(gl_context, environment_dirs=[directory])
    yield renderer
    renderer.release()


def brute_force_brushed(
    normals: np.ndarray, views: np.ndarray, lobe: tuple[float, float], n: int = 160
) -> np.ndarray:
    """int f_spec L (n.l) dl per pixel by the midpoint rule over the hemisphere of l (copper F0),
    with bilinear lookups of the smooth environment: no sampling map, no split."""
    pixels = ibl.smooth_test_environment().pixels
    roughness, anisotropy = lobe
    t, b, at, ab = ra.brushed_frame(normals, BRUSH, roughness**2, anisotropy)
    theta = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    phi = (np.arange(4 * n) + 0.5) * (2 * np.pi / (4 * n))
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    local = np.stack(
        np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.broadcast_to(ct, (n, 4 * n))),
        axis=-1,
    )
    cell = (ct * st)[..., None] * (0.5 * np.pi / n) * (2 * np.pi / (4 * n))
    out = np.zeros((len(normals), 3))
    for i in range(len(normals)):
        v = ra.to_local(views[i], t[i], b[i], normals[i])
        f = ra.brdf_specular(
            np.broadcast_to(v, local.shape), local, at[i], ab[i], ibl.COPPER, separable=False
        )
        world = local @ np.stack([t[i], b[i], normals[i]])
        out[i] = (f * cell * env.sample_bilinear(pixels, world)).sum(axis=(0, 1))
    return out


#: Mean / max relative error of prefiltered mode against the brute force on 64 pixels (n.v in
#: [0.3, 1]), measured on llvmpipe: lobe (0.5, 0.6) 0.048 / 0.30, (0.8, 0.8) 0.062 / 0.27 (one
#: isotropic lookup at the RMS roughness: 0.134 / 0.45 and 0.205 / 0.62; sampled mode with 1024
#: samples 0.005 / 0.027, which checks the brute force). Bounds = measured x 1.4 as in
#: test_shading_ibl.py, whose isotropic split sum errs by 7.6 % / 28 % at roughness 0.5 here.
SMOOTH_BOUNDS = {(0.5, 0.6): (0.068, 0.42), (0.8, 0.8): (0.087, 0.38)}


@pytest.mark.parametrize("lobe", list(SMOOTH_BOUNDS))
def test_prefiltered_smooth_environment_against_brute_force(
    smooth_renderer: SurfaceRenderer, lobe: tuple[float, float]
) -> None:
    roughness, anisotropy = lobe
    scene = ibl.grid_scene(
        material={"f0": ibl.COPPER.tolist(), "metallic": 1.0, "roughness": roughness},
        finish={"anisotropy": anisotropy, "brush_direction": BRUSH.tolist()},
        environment={"file": "smooth.exr"},
        shading={"ibl_mode": "prefiltered", "debug_view": "specular_ibl"},
    )
    camera = Camera.from_config(scene.camera, 8, 8)
    views = ref.view_vectors(camera).reshape(-1, 3)
    rng = np.random.default_rng(7)
    mu = rng.uniform(0.3, 1.0, len(views))
    normals = ref.directions_with_nv(views, mu, rng.uniform(0, 2 * np.pi, len(views)))
    normals = normals.astype(np.float32).astype(np.float64)
    got = ibl.shade_normals(smooth_renderer, scene, normals)
    want = brute_force_brushed(normals, views, lobe)
    relative = np.abs(got - want) / want
    print(
        f"brushed {lobe}, smooth environment: mean {relative.mean():.4f} max {relative.max():.4f}"
    )
    bound_mean, bound_max = SMOOTH_BOUNDS[lobe]
    assert relative.mean() <= bound_mean and relative.max() <= bound_max


@pytest.mark.parametrize("brush", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0)])
def test_view_along_either_brush_axis(renderer: SurfaceRenderer, brush: tuple[float, ...]) -> None:
    """The table's azimuth ends: one pixel at the image centre (its view is exactly +z) with
    the normal tilted in x-z, so the view's tangent part lies exactly along the brush (x) or
    across it (y), at n.v 0.5 and 0.1; rough lobe, copper. Same 2 % as above."""
    lobe = (0.9, 0.8)
    for mu in (0.5, 0.1):
        normal = np.array([np.sqrt(1.0 - mu * mu), 0.0, mu])
        scene = scene_from_dict(
            {
                "image": {"width": 1, "height": 1},
                "camera": {"eye": [0.0, 0.0, 3.0], "fov_y": 30.0},
                "material": {"f0": list(F0S["copper"]), "metallic": 1.0, "roughness": lobe[0]},
                "finish": {"anisotropy": lobe[1], "brush_direction": list(brush)},
                "environment": {"uniform": [1.0, 1.0, 1.0]},
                "shading": {"ibl_mode": "prefiltered"},
            }
        )
        camera = Camera.from_config(scene.camera, 1, 1)
        view = ref.view_vectors(camera)[0, 0]
        assert np.allclose(view, [0.0, 0.0, 1.0])
        image = ref.normal_depth_image(camera, normal.reshape(1, 1, 3))
        got = SinglePasses(renderer).shade_normal_depth(image, scene)[0, 0, :3].astype(np.float64)
        t, b, alpha_t, alpha_b = ra.brushed_frame(normal, np.asarray(brush), lobe[0] ** 2, lobe[1])
        local = ra.to_local(view, t, b, normal)
        want = ra.albedo(local, float(alpha_t), float(alpha_b), np.asarray(F0S["copper"]))
        assert np.all(np.isfinite(got))
        assert np.max(np.abs(got - want) / want) < 0.02, (brush, mu, got, want)
