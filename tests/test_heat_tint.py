"""Heat tint and molten metal: the film table against an independent spectral reference, the
shader's tinted Fresnel against it, the temper colour charts along a rendered peak ramp, and
the liquid blend across the melting range."""

from __future__ import annotations

import colorsys
import itertools

import numpy as np
import pytest
import reference_shading as ref
from single_passes import SinglePasses

from sphrender.core.frame import make_frame
from sphrender.server.bench.analytic import pixel_rays
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.lighting.blackbody import XYZ_TO_REC709
from sphrender.server.engine.lighting.cie_cmf import CIE_1931_2DEG_5NM
from sphrender.server.engine.lighting.materials import (
    LIQUID_F0,
    LIQUID_ROUGHNESS,
    METAL_F0,
    resolve_material,
)
from sphrender.server.engine.lighting.thin_film import (
    COS_SAMPLES,
    FILM_MAX_NM,
    FILM_SAMPLES,
    THICKNESS_SPREAD,
    film_spec,
    film_table,
    oxide_thickness_nm,
    substrate_index,
)
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict


def airy_series_reflectance(
    d_nm: np.ndarray, cos0: float, wavelengths: np.ndarray, film: complex, metal: np.ndarray
) -> np.ndarray:
    """R(lambda) of air / film / metal by summing the bounces one by one (the Airy series
    r01 + t01 t10 r12 e^{2i delta} sum_m (r10 r12 e^{2i delta})^m), s and p averaged; written
    apart from the module's closed form on purpose."""
    sin2 = 1.0 - cos0 * cos0
    cos1 = np.sqrt(1.0 - sin2 / film**2 + 0j)
    cos2 = np.sqrt(1.0 - sin2 / metal**2 + 0j)
    phase = np.exp(4j * np.pi * film * d_nm * cos1 / wavelengths)
    total = np.zeros(phase.shape)
    for s_pol in (True, False):
        if s_pol:
            r01 = (cos0 - film * cos1) / (cos0 + film * cos1)
            r12 = (film * cos1 - metal * cos2) / (film * cos1 + metal * cos2)
        else:
            r01 = (film * cos0 - cos1) / (film * cos0 + cos1)
            r12 = (metal * cos1 - film * cos2) / (metal * cos1 + film * cos2)
        r10 = -r01
        t01_t10 = 1.0 - r01 * r01  # Stokes: t t' = 1 - r^2
        amplitude = r01 + 0j
        bounce = t01_t10 * r12 * phase
        for _ in range(400):  # |r10 r12 e^{2i delta}| < 0.99 at these films: < 1e-6 left
            amplitude = amplitude + bounce
            bounce = bounce * r10 * r12 * phase
            if np.abs(bounce).max() < 1e-9:
                break
        total += 0.5 * np.abs(amplitude) ** 2
    return total


def spread_samples(d_nm: float, spread: float) -> tuple[np.ndarray, np.ndarray]:
    """Thicknesses and weights of the lognormal spread about median d_nm (thin_film.py): a
    dense uniform grid in d itself (not in ln d, as the module steps), 240 points over
    +-5 sigma, each weighted by the lognormal density; steps <= 3.5 nm against an ~75 nm
    fringe period on an integrand that vanishes at both ends (the trapezoid's error there is
    spectrally small)."""
    if d_nm == 0.0 or spread == 0.0:
        return np.array([d_nm]), np.array([1.0])
    d = np.linspace(d_nm * np.exp(-5 * spread), d_nm * np.exp(5 * spread), 240)
    density = np.exp(-0.5 * (np.log(d / d_nm) / spread) ** 2) / d
    return d, density / density.sum()


def reference_rgb(
    d_nm: float, cos0: float, preset: str, spread: float = THICKNESS_SPREAD
) -> np.ndarray:
    """The film's reflectance averaged over its thickness spread, CIE 1931 (equal-energy light,
    380-780 nm) -> linear Rec.709, a perfect reflector = 1."""
    table = np.asarray(CIE_1931_2DEG_5NM, dtype=np.float64)
    table = table[(table[:, 0] >= 380) & (table[:, 0] <= 780)]
    wavelengths, cmf = table[:, 0], table[:, 1:]
    spec = film_spec(preset, METAL_F0[preset])
    metal = substrate_index(spec.f0, wavelengths)
    d, weights = spread_samples(d_nm, spread)
    spectra = airy_series_reflectance(d[:, None], cos0, wavelengths, spec.film_index, metal)
    rgb = XYZ_TO_REC709 @ ((weights @ spectra) @ cmf)
    white = XYZ_TO_REC709 @ cmf.sum(axis=0)
    return np.asarray(rgb / white)


def bilinear(table: np.ndarray, d_nm: float, cos0: float) -> np.ndarray:
    """The read a GL LINEAR sampler does at the shader's coordinates (thin_film.glsl)."""
    x = np.clip(d_nm / FILM_MAX_NM, 0, 1) * (FILM_SAMPLES - 1)
    y = np.clip(cos0, 0, 1) * (COS_SAMPLES - 1)
    x0, y0 = min(int(x), FILM_SAMPLES - 2), min(int(y), COS_SAMPLES - 2)
    fx, fy = x - x0, y - y0
    t = table[..., :3].astype(np.float64)
    top = t[y0, x0] * (1 - fx) + t[y0, x0 + 1] * fx
    bottom = t[y0 + 1, x0] * (1 - fx) + t[y0 + 1, x0 + 1] * fx
    return np.asarray(top * (1 - fy) + bottom * fy)


@pytest.mark.parametrize("preset", ["iron", "stainless_steel"])
def test_film_table_matches_the_spectral_airy_sum(preset: str) -> None:
    """Off the table's nodes (thicknesses and angles between samples, where interpolation errs
    most) the bilinear read is within 1e-3 of the bounce-by-bounce spectral reference averaged
    over the thickness spread by dense sampling in d:
    0.59 nm steps against a ~80 nm interference period bound the interpolation at
    (pi * 0.59 / 80)^2 / 2 * amplitude ~ 3e-4; fp32 storage adds ~1e-7."""
    table = film_table(film_spec(preset, METAL_F0[preset]))
    for d_nm in (0.0, 13.3, 27.7, 38.1, 51.9, 73.4, 140.2, 299.0):
        for cos0 in (1.0, 0.93, 0.71, 0.42, 0.15):
            got = bilinear(table, d_nm, cos0)
            want = reference_rgb(d_nm, cos0, preset)
            assert np.abs(got - want).max() < 1e-3, (d_nm, cos0, got, want)


def test_bare_metal_row_is_close_to_the_presets_f0() -> None:
    """Zero film at normal incidence is the substrate alone; its n, k come from the preset's F0
    (Gulbrandsen), so its colour returns F0 up to the spectral spread between the three
    channel wavelengths (~1e-2)."""
    for preset in ("iron", "stainless_steel"):
        table = film_table(film_spec(preset, METAL_F0[preset]))
        assert np.abs(table[-1, 0, :3] - np.array(METAL_F0[preset])).max() < 0.02


def cielab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB of linear Rec.709 reflectances (a perfect reflector = 1), white = the perfect
    reflector under the equal-energy light the table assumes: a flat spectrum has C* = 0."""
    table = np.asarray(CIE_1931_2DEG_5NM, dtype=np.float64)
    white_xyz = table[(table[:, 0] >= 380) & (table[:, 0] <= 780), 1:].sum(axis=0)
    xyz = (rgb * (XYZ_TO_REC709 @ white_xyz)) @ np.linalg.inv(XYZ_TO_REC709).T / white_xyz
    f = np.where(
        xyz > (6 / 29) ** 3, np.cbrt(np.maximum(xyz, 0.0)), xyz / (3 * (6 / 29) ** 2) + 4 / 29
    )
    return np.stack(
        [116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1
    )


#: Scale thickness (nm): ~3x the charts' thickest colour (carbon steel's light blue, 72 nm).
THICK_NM = 200.0


@pytest.mark.parametrize("preset", ["iron", "stainless_steel"])
def test_thick_scale_is_a_dark_low_chroma_grey(preset: str) -> None:
    """Past THICK_NM the table's normal-incidence colour has CIELAB chroma below D * C_uniform:
    the spread multiplies the interference term by its characteristic function
    D = exp(-(4 pi n sigma_d / lambda)^2 / 2) (sigma_d = spread * d, the small-spread form of
    the lognormal), weakest at d = THICK_NM and lambda = 650 nm (the red end of the CMFs), and
    chroma grows about linearly with the fringe amplitude; C_uniform is the most chroma uniform
    films reach over the same thicknesses (the spectral reference), which is above the bound, so
    the check tells them apart. The film absorbs (k > 0): the scale is darker than bare metal."""
    spec = film_spec(preset, METAL_F0[preset])
    table = film_table(spec)[-1, :, :3].astype(np.float64)
    thickness = np.linspace(0.0, FILM_MAX_NM, FILM_SAMPLES)
    lab = cielab(table)
    chroma = np.hypot(lab[thickness >= THICK_NM, 1], lab[thickness >= THICK_NM, 2])
    uniform = cielab(
        np.array([reference_rgb(d, 1.0, preset, 0.0) for d in np.arange(THICK_NM, 301.0, 5.0)])
    )
    uniform_chroma = float(np.hypot(uniform[:, 1], uniform[:, 2]).max())
    sigma = THICKNESS_SPREAD * THICK_NM
    damping = np.exp(-0.5 * (4 * np.pi * spec.film_index.real * sigma / 650.0) ** 2)
    assert chroma.max() < damping * uniform_chroma < uniform_chroma, (chroma.max(), damping)
    assert lab[-1, 0] < lab[0, 0] - 20.0, (lab[-1, 0], lab[0, 0])


def _flat_patch(width: int, height: int, preset: str, **material: object) -> dict[str, object]:
    return {
        "image": {"width": width, "height": height},
        "camera": {"eye": [0.0, 0.0, 3.0], "fov_y": 20.0},
        "material": {"preset": preset, "roughness": 0.3, **material},
        "lights": [{"direction": [0.0, 0.0, -1.0], "intensity": 2.0}],
        "shading": {"ibl_mode": "none", "debug_view": "direct"},
    }


@pytest.mark.parametrize("preset", ["iron", "stainless_steel"])
def test_shader_tint_is_the_film_over_bare_metal_ratio(
    renderer: SurfaceRenderer, preset: str
) -> None:
    """A flat patch facing the camera under a light from behind it, one peak temperature per
    row: the tinted image over the untinted one is R_film(d, v.h) / R_film(0, v.h) per channel,
    d from the calibration (the spectral reference above, at each pixel's v.h). Tolerance 2e-3:
    both reflectances within 1e-3 of the truth, divided by R_bare >= 0.45."""
    width, height = 10, 6
    sections = _flat_patch(width, height, preset)
    plain_scene = scene_from_dict(sections)
    tinted_scene = scene_from_dict(_flat_patch(width, height, preset, heat_tint=True))
    camera = Camera.from_config(plain_scene.camera, width, height)
    normals = np.zeros((height, width, 3))
    normals[..., 2] = 1.0
    image = ref.normal_depth_image(camera, normals, depth=3.0)
    kelvin = np.linspace(480.0, 620.0, height, dtype=np.float32)[:, None].repeat(width, axis=1)
    passes = SinglePasses(renderer)
    plain = passes.shade_normal_depth(image, plain_scene, kelvin)[..., :3].astype(np.float64)
    tinted = passes.shade_normal_depth(image, tinted_scene, kelvin)[..., :3].astype(np.float64)
    calibration = resolve_material(tinted_scene.material).oxide_calibration
    rays = pixel_rays(camera)
    light = np.array([0.0, 0.0, 1.0])
    for row in range(height):
        d_nm = float(oxide_thickness_nm(float(kelvin[row, 0]), *calibration))
        for column in range(0, width, 3):
            v = -rays.directions[row, column]
            h = (v + light) / np.linalg.norm(v + light)
            vh = float(v @ h)
            want = reference_rgb(d_nm, vh, preset) / reference_rgb(0.0, vh, preset)
            got = tinted[row, column] / plain[row, column]
            assert np.abs(got - want).max() < 2e-3, (row, column, d_nm, got, want)


def _plate(preset: str, peak_c: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """A one-layer particle plate in the x-y plane, peak temperature rising along x."""
    xs = np.arange(-1.0, 1.0001, 0.02)
    ys = np.arange(-0.12, 0.12001, 0.02)
    grid = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    positions = np.column_stack([grid, np.zeros(len(grid))])
    kelvin = np.interp(positions[:, 0], [-1.0, 1.0], peak_c) + 273.15
    return positions, kelvin


#: The temper colour charts (module docstring of lighting/thin_film.py), degrees Celsius, with
#: each colour's hue family on the HSV circle (degrees): straw/yellow 25-65, brown 10-45 and
#: darker than straw, purple/magenta 250-350, blue 195-245.
CHARTS = {
    "iron": [(205, "straw"), (230, "straw"), (260, "brown"), (280, "purple"), (300, "blue"),
             (340, "blue")],
    "stainless_steel": [(290, "straw"), (390, "brown"), (450, "purple"), (540, "blue"),
                        (600, "blue")],
}  # fmt: skip
FAMILIES = {"straw": (25, 65), "brown": (10, 45), "purple": (250, 350), "blue": (195, 245)}


@pytest.mark.parametrize("preset", ["iron", "stainless_steel"])
def test_rendered_peak_ramp_shows_the_temper_chart_in_order(
    renderer: SurfaceRenderer, preset: str
) -> None:
    """A particle plate under a white light along the view, its temperature (= its peak here)
    ramping along x: at each chart temperature the pixel's hue lies in the chart colour's family,
    the unwrapped hue falls monotonically along the chart (straw -> brown -> purple -> blue is the
    first interference order), and brown is darker than straw."""
    charts = CHARTS[preset]
    span = (charts[0][0] - 30.0, charts[-1][0] + 30.0)
    positions, kelvin = _plate(preset, span)
    width, height = 200, 24
    scene = scene_from_dict(
        {
            "image": {"width": width, "height": height},
            "camera": {"eye": [0.0, 0.0, 6.0], "fov_y": 2.4},  # the plate fills the width
            "particles": {"radius": 0.015},
            "material": {"preset": preset, "roughness": 0.5, "heat_tint": True},
            "lights": [{"direction": [0.0, 0.0, -1.0], "intensity": 3.0}],
            "shading": {"ibl_mode": "none"},
        }
    )
    frame, _ = renderer.render(make_frame(positions, temperatures=kelvin), scene)
    rgb = frame.rgba[height // 2 - 2 : height // 2 + 2, :, :3].astype(np.float64).mean(axis=0)
    camera = Camera.from_config(scene.camera, width, height)
    hues: list[float] = []
    lightness: dict[str, float] = {}
    for celsius, colour in charts:
        x_world = np.interp(celsius, span, [-1.0, 1.0])
        view = camera.to_view(np.array([[x_world, 0.0, 0.0]]))[0]
        ndc_x = view[0] / (-view[2] * camera.tan_half_fov_y * camera.aspect)
        column = int((ndc_x + 1.0) * 0.5 * width)
        pixel = rgb[column]
        hue = colorsys.rgb_to_hsv(*(np.maximum(pixel, 0) / pixel.max()))[0] * 360.0
        low, high = FAMILIES[colour]
        assert low <= hue <= high, (celsius, colour, hue, pixel)
        hues.append(hue if colour in ("straw", "brown") else hue - 360.0)
        lightness[colour] = min(lightness.get(colour, np.inf), float(pixel.sum()))
    assert all(b <= a + 1.0 for a, b in itertools.pairwise(hues)), hues
    assert lightness["brown"] < lightness["straw"]


def test_molten_blend_follows_the_melting_range(renderer: SurfaceRenderer) -> None:
    """Flat patch, rows at 1500 K (solid), the middle of 304's mushy range and 2000 K
    (liquid), a light straight along -z: direct light is D V F E (n.l = 1, metal: no diffuse)
    with the solid's F0 and roughness, their average, and the liquid's LIQUID_F0 and
    LIQUID_ROUGHNESS, each pixel at its own v. fp32: 1e-4 relative (D peaks at 3e3 for the
    liquid's alpha = 0.01)."""
    width, height = 4, 3
    sections = _flat_patch(width, height, "stainless_steel", molten=True)
    scene = scene_from_dict(sections)
    camera = Camera.from_config(scene.camera, width, height)
    normals = np.zeros((height, width, 3))
    normals[..., 2] = 1.0
    image = ref.normal_depth_image(camera, normals, depth=3.0)
    material = resolve_material(scene.material)
    mid = 0.5 * (material.solidus_k + material.liquidus_k)
    kelvin = np.array([1500.0, mid, 2000.0], np.float32)[:, None].repeat(width, axis=1)
    got = SinglePasses(renderer).shade_normal_depth(image, scene, kelvin)[..., :3]
    f0 = np.array(material.specular_f0)
    liquid_f0 = np.array(LIQUID_F0)
    looks = [
        (f0, material.roughness),
        (0.5 * (f0 + liquid_f0), 0.5 * (material.roughness + LIQUID_ROUGHNESS)),
        (liquid_f0, LIQUID_ROUGHNESS),
    ]
    v_all = -pixel_rays(camera).directions
    n = np.array([0.0, 0.0, 1.0])
    for row, (f, roughness) in enumerate(looks):
        for column in range(width):
            v = v_all[row, column]
            h = (v + n) / np.linalg.norm(v + n)
            nv, nh, vh = float(v @ n), float(h @ n), float(v @ h)
            alpha = float(ref.alpha_of(roughness))
            lobe = ref.d_ggx(nh, alpha) * ref.visibility(
                "smith_height_correlated", 1.0, nv, nh, vh, alpha
            )
            want = lobe * ref.schlick(f, vh) * 2.0
            assert np.allclose(got[row, column], want, rtol=1e-4), (row, column)


def test_peak_temperatures_tint_what_has_cooled(
    renderer: SurfaceRenderer, gl_context: GLContext
) -> None:
    """A plate at room temperature whose right half peaked at 300 C (carbon steel: blue) and
    whose left half never warmed: with the frame's peaks the right half turns blue and the left
    stays as without any tint, bit for bit where the blur reaches no peak; peaks below the
    current temperature count as the current one; a scene without heat_tint renders the frame
    exactly as if it carried no peaks. Host and device prepare agree."""
    positions, _ = _plate("iron", (20.0, 20.0))
    current = np.full(len(positions), 293.15)
    peak = np.where(positions[:, 0] > 0.0, 573.15, 0.0)
    width, height = 96, 16
    sections: dict[str, object] = {
        "image": {"width": width, "height": height},
        "camera": {"eye": [0.0, 0.0, 6.0], "fov_y": 3.4},  # the plate fills the width
        "particles": {"radius": 0.015},
        "material": {"preset": "iron", "roughness": 0.5, "heat_tint": True},
        "lights": [{"direction": [0.0, 0.0, -1.0], "intensity": 3.0}],
        "shading": {"ibl_mode": "none"},
    }
    scene = scene_from_dict(sections)
    with_peak = make_frame(positions, temperatures=current, peak_temperatures=peak)
    tinted, _ = renderer.render(with_peak, scene)
    cold, _ = renderer.render(make_frame(positions, temperatures=current), scene)
    rgb = tinted.rgba[height // 2, :, :3].astype(np.float64)
    left, right = rgb[width // 8], rgb[7 * width // 8]
    assert right[2] > right[0] * 1.5  # blue
    assert np.array_equal(tinted.rgba[:, : width // 4], cold.rgba[:, : width // 4])
    assert not np.allclose(left, right, rtol=0.1)
    plain_sections = {**sections, "material": {"preset": "iron", "roughness": 0.5}}
    plain = scene_from_dict(plain_sections)
    untinted_peak, _ = renderer.render(with_peak, plain)
    untinted, _ = renderer.render(make_frame(positions, temperatures=current), plain)
    assert np.array_equal(untinted_peak.rgba, untinted.rgba)
    device = SurfaceRenderer(gl_context, prepare="device")
    try:
        on_device, _ = device.render(with_peak, scene)
    finally:
        device.release()
    assert np.abs(on_device.rgba - tinted.rgba).max() < 1e-3
