"""Mitsuba 3 (scalar_rgb) as an independent reference: copper and iron spheres at roughness 0.2
and 0.5 under a uniform and a non-uniform environment; below, dielectric, partly metallic and
metal spheres under the strongly directional workshop preset (diffuse + specular IBL).

Parameter mapping: Mitsuba's `principled` BSDF with metallic = 1 is a GGX metal with Schlick's
Fresnel, F0 = base_color, and alpha = roughness^2, i.e. our model except for the shadowing term:
Mitsuba uses the *separable* Smith G (G1(l) G1(v)), we default to the height-correlated form.
The environment is the overcast preset written to EXR; both renderers use the same
equirectangular convention (checked through Mitsuba's envmap: +x at u = 0.25, +z at u = 0.5,
+y at the top row). Our side shades exact sphere normals (`shade_normal_depth`), so the
comparison is about shading, not the particle surface.

Compared: the mean over the facing region (true n.v >= 0.5, at least 2 px inside the
silhouette) per channel. Tolerance per channel, derived:
* Mitsuba's Monte Carlo noise: 3 x the standard error of the region mean, estimated from the
  spread of four renders with different seeds (METAL_SEEDS);
* the G difference: the ratio of directional albedos (height-correlated / separable) for the
  material's F0, by quadrature, averaged over the region's n.v distribution; this is exact for
  the uniform environment and a good estimate for the smooth overcast sky;
* our method's own error: prefiltered table lookup 0.5% (furnace test budget) under the
  uniform environment; under the sky the split sum adds its error, measured here on llvmpipe
  as at most 0.21% (roughness 0.2) and 0.31% (0.5) over metals and channels: allowance twice
  that, 0.4% and 0.6%, for another driver's mip filtering. (A smooth sky hides lookup-level and
  orientation errors; the workshop section below is the test for those.)
The issue's Done-when asks copper at roughness 0.5 within 6% per channel of principled: checked
separately under the uniform environment.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import NamedTuple

import mitsuba as mi  # the test extra: a missing reference renderer fails, never skips
import numpy as np
import OpenImageIO as oiio
import pytest
import reference_shading as ref
from single_passes import SinglePasses

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.lighting import environment as env
from sphrender.server.engine.lighting.materials import METAL_F0
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

WIDTH = HEIGHT = 40
EYE = (0.0, 0.5, 3.4)
FOV_Y = 40.0
SPP = 96
METAL_SEEDS = (1, 2, 3, 4)
ENVIRONMENTS = ("uniform", "overcast")


def write_preset_exr(name: str, directory: Path) -> Path:
    path = directory / f"{name}.exr"
    pixels = env.preset_image(name).pixels
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, "float")
    out = oiio.ImageOutput.create(str(path))
    assert out is not None and out.open(str(path), spec)
    out.write_image(pixels)
    out.close()
    return path


@pytest.fixture(scope="module")
def overcast_exr(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_preset_exr("overcast", tmp_path_factory.mktemp("mitsuba"))


def mitsuba_sphere(
    bsdf: Mapping[str, object],
    emitter: Mapping[str, object],
    *,
    eye: tuple[float, float, float] = EYE,
    size: int = WIDTH,
    spp: int = SPP,
    seed: int,
) -> np.ndarray:
    """Mitsuba's (size, size, 3) image of the unit sphere at the origin with `bsdf`."""
    mi.set_variant("scalar_rgb")
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
                    origin=list(eye), target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]
                ),
                "film": {
                    "type": "hdrfilm",
                    "width": size,
                    "height": size,
                    "rfilter": {"type": "box"},
                    "pixel_format": "rgb",
                },
                "sampler": {"type": "independent", "sample_count": spp, "seed": seed},
            },
            "sphere": {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 1.0, "bsdf": bsdf},
            "emitter": emitter,
        }
    )
    return np.array(mi.render(scene), dtype=np.float64)[..., :3]


def principled_metal(f0: Sequence[float] | np.ndarray, roughness: float) -> dict[str, object]:
    """GGX + Schlick with F0 = base colour (see the module docstring)."""
    return {
        "type": "principled",
        "base_color": {"type": "rgb", "value": [float(c) for c in f0]},
        "metallic": 1.0,
        "roughness": roughness,
    }


def mitsuba_render(
    f0: tuple[float, float, float], roughness: float, environment: str, exr: Path, seed: int
) -> np.ndarray:
    emitter = (
        {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
        if environment == "uniform"
        else {"type": "envmap", "filename": str(exr)}
    )
    return mitsuba_sphere(principled_metal(f0, roughness), emitter, seed=seed)


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
    rgba = SinglePasses(renderer).shade_normal_depth(normal_depth, scene)
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
    ours, region, facing = our_render(renderer, metal, roughness, environment)
    f0 = METAL_F0[metal]
    region_means = np.array(
        [
            mitsuba_render(f0, roughness, environment, overcast_exr, seed=seed)[region].mean(0)
            for seed in METAL_SEEDS
        ]
    )
    mitsuba_mean = region_means.mean(axis=0)
    noise = region_means.std(axis=0, ddof=1) / np.sqrt(len(METAL_SEEDS))
    mus, ratios = g_ratio(metal, roughness)
    per_pixel = np.stack([np.interp(facing[region], mus, ratios[:, c]) for c in range(3)], -1)
    expected_g = per_pixel.mean(axis=0) - 1.0
    ours_mean = ours[region].mean(axis=0)
    relative = ours_mean / mitsuba_mean - 1.0
    method = 0.005 if environment == "uniform" else {0.2: 0.004, 0.5: 0.006}[roughness]
    tolerance = 3.0 * noise / mitsuba_mean + np.abs(expected_g) + method
    print(
        f"{metal} r={roughness} {environment}: ours {ours_mean.round(4)} mitsuba "
        f"{mitsuba_mean.round(4)} rel {relative.round(4)} (G model {expected_g.round(4)}, "
        f"tolerance {tolerance.round(4)})"
    )
    assert np.all(np.abs(relative) <= tolerance)
    if metal == "copper" and roughness == 0.5 and environment == "uniform":
        assert np.all(np.abs(relative) <= 0.06)  # the Done-when


# -- Dielectric and partly metallic spheres under the workshop: diffuse + specular IBL -------
#
# The metal cases above cannot see the diffuse term (metallic = 1 has none), and a uniform or
# smooth overcast sky looks the same at every prefilter level and orientation. Here the
# environment is the workshop preset, whose light comes from one bright window (-z wall) and
# rows of ceiling tubes, and the camera looks at the sphere from the window's side, so the
# facing normals see the window directly (diffuse) and reflect it (specular).
#
# Reference: Mitsuba renders two independent parts, which our model combines per pixel:
#   diffuse  a white Lambertian sphere (`diffuse`, reflectance 1) gives E(n) / pi exactly;
#            scaled by our model's weight (1 - (F0 A + B)(n.v)) c_diff, where F0 A + B is the
#            directional albedo of the specular lobe by quadrature (reference_shading.py);
#   specular `principled` with metallic = 1 and base colour = the effective F0 (GGX + Schlick),
#            times the albedo ratio height-correlated / separable G (as above).
# Compared per block of 2 x 2 pixels: mean over blocks of |ours / reference - 1|, the statistic
# that sees a sharper or blurrier reflection (a region mean does not: the prefiltered levels
# all hold the same energy). Mitsuba's noise is measured, not assumed: WORKSHOP_SEEDS renders
# with different seeds give each block's standard error.
#
# Tolerance per case and IBL mode: 1.25 x the error measured on llvmpipe against a 16-seed x
# 256 spp reference (4096 samples per pixel, so that figure is the method's own error, not
# noise; values in WORKSHOP_CASES) for another driver's texture filtering and rounding, plus
# 3 x the mean relative standard error of the test's own reference blocks (with 6 seeds at
# 64 spp a block mean has an error of ~1.5-3 %, which adds at most that much to the statistic).
# Regions: `sampled` (256 GGX samples per pixel, no split sum) over the whole facing region,
# n.v >= 0.3; `prefiltered` (the default, split sum) only where n.v >= 0.9: the split sum
# assumes n = v = r, which holds at the centre of the sphere; towards grazing angles its error
# under a small bright source grows to 28 % of a block (measured, n.v 0.3-0.6, roughness 0.5),
# which is the method, not a bug. What these bounds exclude, measured (mean |block error|): the
# diffuse term without its 1 / pi, 1.99 / 1.92 on the dielectric (sampled / prefiltered) and
# 1.20 / 0.81 half metallic; the prefiltered level looked up at roughness^2 instead of
# roughness, 0.11 / 0.43 / 0.46 (dielectric / half metallic / metal) instead of 0.05 / 0.07 /
# 0.05, against tolerances of 0.08 / 0.12 / 0.13.

WORKSHOP_SIZE = 64
WORKSHOP_EYE = (0.0, 0.5, -3.4)
WORKSHOP_SPP = 64
WORKSHOP_SEEDS = 6
BLOCK = 2
IBL_REGIONS = {"sampled": 0.3, "prefiltered": 0.9}  # smallest true n.v compared


class WorkshopCase(NamedTuple):
    base_color: tuple[float, float, float]
    metallic: float
    roughness: float
    #: mean |block error| per IBL mode on llvmpipe against the 4096-spp reference
    measured: dict[str, float]


WORKSHOP_CASES = {
    # a red-brown paint: the diffuse term carries the image
    "dielectric": WorkshopCase(
        (0.8, 0.35, 0.15), 0.0, 0.5, {"sampled": 0.018, "prefiltered": 0.031}
    ),
    # copper half way through the metallic workflow: F0 = 0.49 .. 0.33, c_diff = 0.47 .. 0.26
    "half_metallic": WorkshopCase(
        METAL_F0["copper"], 0.5, 0.5, {"sampled": 0.029, "prefiltered": 0.061}
    ),
    # copper at roughness 0.2: the window's reflection is sharp, its blur decides every block
    "metal": WorkshopCase(METAL_F0["copper"], 1.0, 0.2, {"sampled": 0.037, "prefiltered": 0.031}),
}


@pytest.fixture(scope="module")
def workshop_exr(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_preset_exr("workshop", tmp_path_factory.mktemp("mitsuba-workshop"))


def workshop_mitsuba(
    bsdf: Mapping[str, object], exr: Path, *, spp: int = WORKSHOP_SPP, seeds: int = WORKSHOP_SEEDS
) -> np.ndarray:
    """(seeds, H, W, 3): one Mitsuba image per seed."""
    emitter = {"type": "envmap", "filename": str(exr)}
    return np.stack(
        [
            mitsuba_sphere(
                bsdf, emitter, eye=WORKSHOP_EYE, size=WORKSHOP_SIZE, spp=spp, seed=100 + seed
            )
            for seed in range(seeds)
        ]
    )


def effective_f0(case: WorkshopCase) -> np.ndarray:
    """The metallic workflow (materials.py): F0 = mix(0.04, base colour, metallic)."""
    return 0.04 * (1.0 - case.metallic) + np.asarray(case.base_color) * case.metallic


@functools.lru_cache(maxsize=8)
def specular_albedo(f0: tuple[float, ...], roughness: float, g_term: str) -> np.ndarray:
    """F0 A + B per channel on ALBEDO_MUS (directional albedo of the specular lobe)."""
    return np.array(
        [
            [ref.albedo_quadrature(g_term, mu, roughness**2, f0=f, n=160) for f in f0]
            for mu in ALBEDO_MUS
        ]
    )


ALBEDO_MUS = np.linspace(0.25, 1.0, 10)


def per_pixel(values: np.ndarray, facing: np.ndarray) -> np.ndarray:
    """(len(ALBEDO_MUS), 3) values interpolated at every pixel's n.v -> (H, W, 3)."""
    mu = np.clip(facing, ALBEDO_MUS[0], 1.0)
    return np.stack([np.interp(mu, ALBEDO_MUS, values[:, c]) for c in range(3)], axis=-1)


def workshop_reference(
    case: WorkshopCase, lambert: np.ndarray, specular: np.ndarray, facing: np.ndarray
) -> np.ndarray:
    """Per seed (seeds, H, W, 3): (1 - E_spec(n.v)) c_diff E / pi + specular x G ratio."""
    f0 = tuple(float(c) for c in effective_f0(case))
    hc = specular_albedo(f0, case.roughness, "smith_height_correlated")
    separable = specular_albedo(f0, case.roughness, "separable")
    diffuse_albedo = np.asarray(case.base_color) * (1.0 - case.metallic)
    weight = (1.0 - per_pixel(hc, facing)) * diffuse_albedo
    result: np.ndarray = weight * lambert + specular * per_pixel(hc / separable, facing)
    return result


def block_errors(
    ours: np.ndarray, references: np.ndarray, region: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per BLOCK x BLOCK block fully inside `region`: |ours / reference - 1| (against the mean
    over seeds) and the reference's relative standard error, both (blocks, 3)."""
    h, w = region.shape
    full = region.reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).all(axis=(1, 3))

    def blocks(image: np.ndarray) -> np.ndarray:
        shaped = image.reshape(*image.shape[:-3], h // BLOCK, BLOCK, w // BLOCK, BLOCK, 3)
        means: np.ndarray = shaped.mean(axis=(-4, -2))[..., full, :]
        return means

    ref_blocks = blocks(references)  # (seeds, blocks, 3)
    mean = ref_blocks.mean(axis=0)
    standard_error = ref_blocks.std(axis=0, ddof=1) / np.sqrt(ref_blocks.shape[0])
    return np.abs(blocks(ours) / mean - 1.0), standard_error / mean


@functools.lru_cache(maxsize=1)
def workshop_lambert(exr: str) -> np.ndarray:
    return workshop_mitsuba(
        {"type": "diffuse", "reflectance": {"type": "rgb", "value": [1.0] * 3}}, Path(exr)
    )


@functools.lru_cache(maxsize=4)
def workshop_specular(name: str, exr: str) -> np.ndarray:
    case = WORKSHOP_CASES[name]
    return workshop_mitsuba(principled_metal(effective_f0(case), case.roughness), Path(exr))


def our_workshop_render(
    renderer: SurfaceRenderer, case: WorkshopCase, ibl_mode: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Our shading of the exact sphere: (H, W, 3) colour, true n.v, pixels 2 px inside."""
    size = WORKSHOP_SIZE
    shading: dict[str, object] = {"ibl_mode": ibl_mode}
    if ibl_mode == "sampled":
        shading["ibl_samples"] = 256
    scene = scene_from_dict(
        {
            "image": {"width": size, "height": size},
            "camera": {"eye": list(WORKSHOP_EYE), "fov_y": FOV_Y},
            "material": {
                "f0": list(case.base_color),
                "metallic": case.metallic,
                "roughness": case.roughness,
            },
            "environment": {"preset": "workshop"},
            "shading": shading,
        }
    )
    camera = Camera.from_config(scene.camera, size, size)
    normal_depth, hit = ref.sphere_normal_depth(camera, np.zeros(3), 1.0)
    rgba = SinglePasses(renderer).shade_normal_depth(normal_depth, scene)
    facing = np.einsum("hwk,hwk->hw", normal_depth[..., :3], ref.view_vectors(camera))
    inside = hit.copy()
    for axis in (0, 1):
        for shift in (-2, -1, 1, 2):
            inside &= np.roll(hit, shift, axis=axis)
    return rgba[..., :3].astype(np.float64), facing, inside


@pytest.mark.parametrize("ibl_mode", list(IBL_REGIONS))
@pytest.mark.parametrize("name", list(WORKSHOP_CASES))
def test_dielectric_and_partly_metallic_spheres_under_the_workshop_match_mitsuba(
    renderer: SurfaceRenderer, workshop_exr: Path, name: str, ibl_mode: str
) -> None:
    """Guards the diffuse IBL term (its 1 / pi, the metallic workflow's c_diff, the SH9
    orientation) and the specular lookup (prefiltered level per roughness, sampled lobes)
    against Mitsuba under a strongly directional environment; see the section comment."""
    case = WORKSHOP_CASES[name]
    ours, facing, inside = our_workshop_render(renderer, case, ibl_mode)
    references = workshop_reference(
        case,
        workshop_lambert(str(workshop_exr)),
        workshop_specular(name, str(workshop_exr)),
        facing,
    )
    region = inside & (facing >= IBL_REGIONS[ibl_mode])
    errors, noise = block_errors(ours, references, region)
    error, mean_noise = float(errors.mean()), float(noise.mean())
    tolerance = 1.25 * case.measured[ibl_mode] + 3.0 * mean_noise
    print(
        f"{name} {ibl_mode}: mean |block error| {error:.4f} over {errors.shape[0]} blocks "
        f"(max {errors.max():.3f}); reference noise {mean_noise:.4f}; tolerance {tolerance:.4f}"
    )
    assert errors.shape[0] >= 40
    assert mean_noise <= 0.04  # the reference is good enough to judge by
    assert error <= tolerance
