"""Mitsuba 3 (scalar_rgb) as an independent reference: copper and iron spheres at roughness 0.2
and 0.5 under a uniform and a non-uniform environment.

Parameter mapping: Mitsuba's `principled` BSDF with metallic = 1 is a GGX metal with Schlick's
Fresnel, F0 = base_color, and alpha = roughness^2, i.e. our model except for the shadowing term:
Mitsuba uses the *separable* Smith G (G1(l) G1(v)), we default to the height-correlated form.
The environment is the overcast preset written to EXR; both renderers use the same
equirectangular convention (checked through Mitsuba's envmap: +x at u = 0.25, +z at u = 0.5,
+y at the top row). Our side shades exact sphere normals (`shade_normal_depth`), so the
comparison is about shading, not the particle surface.

Compared: the mean over the facing region (true n.v >= 0.5, at least 2 px inside the
silhouette) per channel. Tolerance per channel, derived:
* Mitsuba's Monte Carlo noise: 3 x the standard error of the region mean, estimated from two
  renders with different seeds;
* the G difference: the ratio of directional albedos (height-correlated / separable) for the
  material's F0, by quadrature, averaged over the region's n.v distribution; this is exact for
  the uniform environment and a good estimate for the smooth overcast sky;
* our method's own error: prefiltered table lookup 0.5% (furnace test budget) under the
  uniform environment; under the sky the split sum adds its error, measured on a much harsher
  environment in test_shading_ibl.py (mean 0.8% at roughness 0.2, 7.6% at 0.5), of which a
  smooth sky keeps a fraction: allowance 2% (0.2) and 4% (0.5).
The issue's Done-when asks copper at roughness 0.5 within 6% per channel of principled: checked
separately under the uniform environment.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
import reference_shading as ref

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.lighting import environment as env
from sphrender.server.engine.lighting.materials import METAL_F0
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

mi = pytest.importorskip("mitsuba", reason="mitsuba (PyPI, test extra) is not installed")

WIDTH = HEIGHT = 40
EYE = (0.0, 0.5, 3.4)
FOV_Y = 40.0
SPP = 96
ENVIRONMENTS = ("uniform", "overcast")


@pytest.fixture(scope="module")
def overcast_exr(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mitsuba") / "overcast.exr"
    pixels = env.preset_image("overcast").pixels
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, "float")
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), spec)
    out.write_image(pixels)
    out.close()
    return path


def mitsuba_render(
    f0: tuple[float, float, float], roughness: float, environment: str, exr: Path, seed: int
) -> np.ndarray:
    mi.set_variant("scalar_rgb")
    emitter = (
        {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
        if environment == "uniform"
        else {"type": "envmap", "filename": str(exr)}
    )
    scene = mi.load_dict(
        {
            "type": "scene",
            # Camera -> sphere -> environment: a convex sphere has no interreflection, so
            # direct lighting (max_depth 2) is the whole answer.
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": {
                "type": "perspective",
                "fov": FOV_Y,
                "fov_axis": "y",
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=list(EYE), target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]
                ),
                "film": {
                    "type": "hdrfilm",
                    "width": WIDTH,
                    "height": HEIGHT,
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "independent", "sample_count": SPP, "seed": seed},
            },
            "sphere": {
                "type": "sphere",
                "center": [0.0, 0.0, 0.0],
                "radius": 1.0,
                "bsdf": {
                    "type": "principled",
                    "base_color": {"type": "rgb", "value": list(f0)},
                    "metallic": 1.0,
                    "roughness": roughness,
                },
            },
            "emitter": emitter,
        }
    )
    return np.array(mi.render(scene), dtype=np.float64)[..., :3]


def our_render(
    renderer: SurfaceRenderer, metal: str, roughness: float, environment: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Our shading of the exact sphere: (H, W, 3) colour, facing region mask, true n.v."""
    config: dict[str, object] = (
        {"uniform": [1.0, 1.0, 1.0]} if environment == "uniform" else {"preset": "overcast"}
    )
    scene = scene_from_dict(
        {
            "image": {"width": WIDTH, "height": HEIGHT},
            "camera": {"eye": list(EYE), "fov_y": FOV_Y},
            "material": {"preset": metal, "roughness": roughness},
            "environment": config,
        }
    )
    camera = Camera.from_config(scene.camera, WIDTH, HEIGHT)
    normal_depth, hit = ref.sphere_normal_depth(camera, np.zeros(3), 1.0)
    rgba = renderer.shade_normal_depth(normal_depth, scene)
    facing = np.einsum("hwk,hwk->hw", normal_depth[..., :3], ref.view_vectors(camera))
    inside = hit.copy()
    for axis in (0, 1):
        for shift in (-2, -1, 1, 2):
            inside &= np.roll(hit, shift, axis=axis)
    region = inside & (facing >= 0.5)
    return rgba[..., :3].astype(np.float64), region, facing


@functools.lru_cache(maxsize=8)
def g_ratio(metal: str, roughness: float) -> tuple[np.ndarray, np.ndarray]:
    """n.v grid and albedo(height-correlated) / albedo(separable) on it, (6,) and (6, 3)."""
    mus = np.linspace(0.5, 1.0, 6)
    alpha = roughness**2
    ratios = [
        [
            ref.albedo_quadrature("smith_height_correlated", mu, alpha, f0=f0, n=160)
            / ref.albedo_quadrature("separable", mu, alpha, f0=f0, n=160)
            for f0 in METAL_F0[metal]
        ]
        for mu in mus
    ]
    return mus, np.array(ratios)


@pytest.mark.parametrize("environment", ENVIRONMENTS)
@pytest.mark.parametrize("roughness", [0.2, 0.5])
@pytest.mark.parametrize("metal", ["copper", "iron"])
def test_sphere_matches_mitsuba_principled(
    renderer: SurfaceRenderer, overcast_exr: Path, metal: str, roughness: float, environment: str
) -> None:
    f0 = METAL_F0[metal]
    first = mitsuba_render(f0, roughness, environment, overcast_exr, seed=1)
    second = mitsuba_render(f0, roughness, environment, overcast_exr, seed=2)
    ours, region, facing = our_render(renderer, metal, roughness, environment)
    mitsuba_mean = 0.5 * (first[region].mean(axis=0) + second[region].mean(axis=0))
    noise = np.abs(first[region].mean(axis=0) - second[region].mean(axis=0)) / 2.0
    mus, ratios = g_ratio(metal, roughness)
    per_pixel = np.stack([np.interp(facing[region], mus, ratios[:, c]) for c in range(3)], -1)
    expected_g = per_pixel.mean(axis=0) - 1.0
    ours_mean = ours[region].mean(axis=0)
    relative = ours_mean / mitsuba_mean - 1.0
    method = 0.005 if environment == "uniform" else {0.2: 0.02, 0.5: 0.04}[roughness]
    tolerance = 3.0 * noise / mitsuba_mean + np.abs(expected_g) + method
    print(
        f"{metal} r={roughness} {environment}: ours {ours_mean.round(4)} mitsuba "
        f"{mitsuba_mean.round(4)} rel {relative.round(4)} (G model {expected_g.round(4)}, "
        f"tolerance {tolerance.round(4)})"
    )
    assert np.all(np.abs(relative) <= tolerance)
    if metal == "copper" and roughness == 0.5 and environment == "uniform":
        assert np.all(np.abs(relative) <= 0.06)  # the Done-when
