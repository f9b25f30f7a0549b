"""Hot-metal glow: the blackbody table against validation-data.md, the shader's emission
against (1 - F) B(T), and per-particle temperatures through splat, blur and shade."""

from __future__ import annotations

import numpy as np
import pytest
import reference_shading as ref
from single_passes import SinglePasses

from sphrender.core.frame import make_frame
from sphrender.server.bench.analytic import pixel_rays
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.lighting.blackbody import (
    REC709_LUMINANCE,
    blackbody_rgb,
    blackbody_table,
    to_gamut,
)
from sphrender.server.engine.lighting.materials import METAL_F0
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

#: validation-data.md: kelvin -> (RGB at Y = 1, luminance cd/m^2 at emissivity 1).
TABLE = {
    1000: ((4.60, 0.04, -0.09), 2.7),
    1500: ((3.26, 0.43, -0.06), 7.7e3),
    1800: ((2.77, 0.58, -0.02), 1.2e5),
    2000: ((2.52, 0.65, 0.02), 4.6e5),
    2500: ((2.07, 0.77, 0.14), 5.6e6),
    3000: ((1.77, 0.84, 0.27), 3.0e7),
}


@pytest.mark.parametrize("kelvin", sorted(TABLE))
def test_blackbody_matches_the_validation_table(kelvin: int) -> None:
    """Colours are printed with 2 decimals (rounding <= 0.005) and luminances with 2 significant
    digits (rounding <= half a unit of the second digit); the CIE table is the standard
    observer at 5 nm, so nothing else separates the two."""
    (want_rgb, want_luminance) = TABLE[kelvin]
    rgb, luminance = blackbody_rgb(kelvin)
    assert np.all(np.abs(rgb - np.array(want_rgb)) <= 0.005 + 1e-9)
    digit = 10.0 ** (np.floor(np.log10(want_luminance)) - 1)
    assert abs(luminance - want_luminance) <= 0.5 * digit


def test_gamut_mapping_keeps_luminance_and_moves_little() -> None:
    """Clip-and-rescale keeps Y = 1 exactly: negative channels become 0 and, at 1000-1800 K
    (the dim end of what glows visibly), the others change by less than 1%."""
    for kelvin in (1000, 1200, 1500, 1800):
        rgb, _ = blackbody_rgb(kelvin)
        mapped = to_gamut(rgb)
        assert np.all(mapped >= 0.0)
        assert mapped @ REC709_LUMINANCE == pytest.approx(1.0, abs=1e-12)
        positive = rgb > 0
        assert np.all(mapped[~positive] == 0.0)
        assert np.all(np.abs(mapped[positive] / rgb[positive] - 1.0) <= 0.01)
    rgb, _ = blackbody_rgb(2500)
    assert np.allclose(to_gamut(rgb), rgb)  # in gamut: unchanged
    table = blackbody_table()
    assert np.all(np.isfinite(table)) and np.all(table[:, :3] >= 0.0)


def test_shader_emission_is_one_minus_fresnel_times_planck(renderer: SurfaceRenderer) -> None:
    """Debug view 'emission' on normals with n.v from 0.05 to 1 and 500-3000 K, iron:
    emissivity (1 - F0)(1 - (1 - n.v)^5) times the table's B(T) times emission_scale.
    Tolerance 1e-3 relative: log-luminance is interpolated linearly between entries 2.8 K
    apart, whose curvature (d^2 ln Y / dT^2 ~ 5e-5 K^-2 at 1000 K) bounds the error at ~5e-5;
    fp32 exp2 and the Schlick power add ~1e-6."""
    scene = scene_from_dict(
        {
            "image": {"width": 12, "height": 8},
            "camera": {"eye": [0.0, 0.0, 3.0]},
            "material": {"preset": "iron"},
            "shading": {"debug_view": "emission", "emission_scale": 1e-3, "ibl_mode": "none"},
        }
    )
    camera = Camera.from_config(scene.camera, 12, 8)
    views = ref.view_vectors(camera)
    mu = np.linspace(0.05, 1.0, 12)[None, :].repeat(8, axis=0)
    normals = ref.directions_with_nv(views, mu, np.zeros_like(mu))
    kelvin = np.linspace(500.0, 3000.0, 8, dtype=np.float32)[:, None].repeat(12, axis=1)
    rgba = SinglePasses(renderer).shade_normal_depth(
        ref.normal_depth_image(camera, normals), scene, kelvin
    )
    emissivity = 1.0 - np.array(METAL_F0["iron"])
    want = np.zeros((8, 12, 3))
    for row in range(8):
        rgb, luminance = blackbody_rgb(float(kelvin[row, 0]))
        for column in range(12):
            shape = 1.0 - (1.0 - mu[row, column]) ** 5
            want[row, column] = emissivity * shape * to_gamut(rgb) * luminance * 1e-3
    got = rgba[..., :3].astype(np.float64)
    assert np.allclose(got, want, rtol=1e-3, atol=1e-12)


def test_particle_temperatures_glow_where_the_hot_particles_are(
    renderer: SurfaceRenderer,
) -> None:
    """A ball whose +x half is at 2500 K and -x half at room temperature, with some particles
    culled (behind the camera): the right half of the image glows, the left does not, so the
    temperatures stay attached to their particles through culling, splat and blur."""
    positions = jittered_lattice_ball(0.3, 0.02, seed=2)
    behind = np.array([[0.0, 0.0, 5.0], [0.1, 0.0, 6.0]])  # the eye is at z = 2
    positions = np.concatenate([behind, positions])
    temperatures = np.where(positions[:, 0] > 0.0, 2500.0, 300.0)
    temperatures[:2] = 1e4  # culled particles must not leak their temperature
    scene = scene_from_dict(
        {
            "image": {"width": 64, "height": 48},
            "camera": {"eye": [0.0, 0.0, 2.0], "fov_y": 30.0},
            "particles": {"radius": 0.02},
            "shading": {"debug_view": "emission", "ibl_mode": "none"},
        }
    )
    frame, _ = renderer.render(make_frame(positions, temperatures=temperatures), scene)
    glow = frame.rgba[..., 0]
    covered = frame.rgba[..., 3] > 0
    left = glow[:, :28][covered[:, :28]]
    right = glow[:, 36:][covered[:, 36:]]
    assert left.size > 50 and right.size > 50
    assert np.median(right) > 100.0  # 2500 K iron-free default steel: ~1e3 scene units
    assert np.median(left) < 1e-6  # 300 K emits nothing visible
    assert glow[covered].max() < 1e4  # no 1e4 K particle leaked in (that would be ~1e5)


def test_temperatures_in_celsius_render_as_sent_with_a_note(renderer: SurfaceRenderer) -> None:
    """A weld bead in degrees Celsius (20 at the cold end, 1500 at the hot): the frame renders
    exactly as sent (the glow reads kelvin), and its stats carry one note on `temperatures`
    saying what to add; the same frame in kelvin (+ 273.15) has none. The note's "~12x" is the
    Planck ratio at 600 nm, checked here."""
    positions = jittered_lattice_ball(0.2, 0.02, seed=3)
    celsius = np.linspace(20.0, 1500.0, len(positions))
    scene = scene_from_dict(
        {"image": {"width": 48, "height": 32}, "camera": {"eye": [0.0, 0.0, 1.5]},
         "particles": {"radius": 0.02}}
    )  # fmt: skip
    sent, stats = renderer.render(make_frame(positions, temperatures=celsius), scene)
    as_kelvin, plain = renderer.render(make_frame(positions, temperatures=celsius + 273.15), scene)
    assert [n.field for n in stats.notes] == ["temperatures"]
    assert "from 20 K to 1500 K" in stats.notes[0].message
    assert "add 273.15" in stats.notes[0].message
    assert plain.notes == []
    assert not np.array_equal(sent.rgba, as_kelvin.rgba)  # rendered as sent: not converted
    c2 = 0.014388 / 600e-9  # hc / (lambda k), K
    assert np.expm1(c2 / 1500.0) / np.expm1(c2 / 1773.15) == pytest.approx(11.7, abs=0.1)


def test_direct_lights_and_weighted_combination(renderer: SurfaceRenderer) -> None:
    """A directional and a point light on a flat patch facing +z, against the numpy BRDF times
    irradiance (E cos for the sun, I cos / d^2 for the point light, positions relative to an
    eye at 1e5: the float64 subtraction keeps them exact). Then weighted (eq 55) at 0.3 must give
    0.3 direct + 0.7 indirect, and 'add' their sum. fp32: 1e-4 relative."""
    eye = np.array([1e5, 0.0, 3.0])
    light_position = np.array([1e5 + 0.5, 0.4, 1.0])
    sections = {
        "image": {"width": 6, "height": 4},
        "camera": {"eye": list(eye), "target": [1e5, 0.0, 0.0], "fov_y": 20.0},
        "material": {"preset": "copper", "roughness": 0.4, "metallic": 0.7},
        "lights": [
            {"direction": [0.3, -0.2, -1.0], "intensity": 2.0, "color": [1.0, 0.9, 0.8]},
            {"type": "point", "position": list(light_position), "intensity": 3.0},
        ],
        "environment": {"preset": "overcast"},
    }
    base = scene_from_dict(sections)
    camera = Camera.from_config(base.camera, 6, 4)
    normals = np.zeros((4, 6, 3))
    normals[..., 2] = 1.0
    image = ref.normal_depth_image(camera, normals, depth=3.0)

    def shade(**shading: object) -> np.ndarray:
        scene = scene_from_dict({**sections, "shading": shading})
        return SinglePasses(renderer).shade_normal_depth(image, scene)[..., :3].astype(np.float64)

    direct = shade(debug_view="direct")
    from sphrender.server.bench.analytic import pixel_rays
    from sphrender.server.engine.lighting.materials import resolve_material

    material = resolve_material(base.material)
    rays = pixel_rays(camera)
    points = rays.origin + rays.directions * (3.0 / rays.view_z)[..., None]
    v = -rays.directions
    n = np.array([0.0, 0.0, 1.0])
    alpha = float(ref.alpha_of(material.roughness))
    f0 = np.array(material.specular_f0)
    albedo = np.array(material.diffuse_albedo)

    def brdf(light: np.ndarray) -> np.ndarray:
        h = (v + light) / np.linalg.norm(v + light, axis=-1, keepdims=True)
        nl, nv, nh = light @ n, v @ n, h @ n
        vh = np.einsum("...k,...k->...", v, h)
        f = ref.schlick(f0, vh[..., None])
        spec = ref.d_ggx(nh, alpha) * ref.visibility(
            "smith_height_correlated", nl, nv, nh, vh, alpha
        )
        return (1 - f) * albedo / np.pi + spec[..., None] * f

    sun = -np.array([0.3, -0.2, -1.0]) / np.linalg.norm([0.3, -0.2, -1.0])
    sun_l = np.broadcast_to(sun, points.shape)
    want = brdf(sun_l) * (2.0 * np.array([1.0, 0.9, 0.8])) * (sun_l @ n)[..., None]
    to_light = light_position - points
    d2 = np.einsum("...k,...k->...", to_light, to_light)
    point_l = to_light / np.sqrt(d2)[..., None]
    want += brdf(point_l) * (3.0 / d2 * (point_l @ n))[..., None]
    assert np.allclose(direct, want, rtol=1e-4)

    indirect = shade(debug_view="diffuse_ibl") + shade(debug_view="specular_ibl")
    assert np.allclose(shade(), direct + indirect, rtol=1e-5)
    assert np.allclose(
        shade(combine="weighted", direct_weight=0.3), 0.3 * direct + 0.7 * indirect, rtol=1e-5
    )


def front_particles(
    camera: Camera, centers: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """Numpy ray cast (float64) of every pixel centre against every sphere: the index of the
    nearest sphere hit (-1 = none) and the eye-depth gap to the second nearest (inf if none),
    both (H, W), rows top first."""
    rays = pixel_rays(camera)
    directions = rays.directions.reshape(-1, 3)
    oc = centers - rays.origin
    nearest = np.full(directions.shape[0], -1)
    gap = np.full(directions.shape[0], np.inf)
    for start in range(0, directions.shape[0], 512):
        d = directions[start : start + 512]
        b = d @ oc.T  # (P, N)
        disc = radius**2 - (np.einsum("nk,nk->n", oc, oc)[None, :] - b * b)
        t = np.where((disc >= 0) & (b > 0), b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
        order = np.argsort(t, axis=1)[:, :2]
        first = np.take_along_axis(t, order, axis=1)
        hit = np.isfinite(first[:, 0])
        nearest[start : start + 512] = np.where(hit, order[:, 0], -1)
        with np.errstate(invalid="ignore"):  # inf - inf where nothing is hit
            gap[start : start + 512] = first[:, 1] - first[:, 0]
    view_z = rays.view_z.reshape(-1)
    shape = (camera.height, camera.width)
    return nearest.reshape(shape), (gap * view_z).reshape(shape)


def splatted_temperature(renderer: SurfaceRenderer, size: tuple[int, int]) -> np.ndarray:
    """The kelvin target of the last render as splatted (front particle per pixel, before the
    blur), rows top first. Read from the renderer's own target: no public AOV carries it, and
    the blurred field mixes neighbours, so only this image can show which particle's value
    landed on a pixel."""
    width, height = size
    targets = renderer.splat_pass.targets(size)
    assert targets.temperature is not None
    kelvin = np.frombuffer(targets.temperature.read(), dtype=np.float32).reshape(height, width)
    return np.ascontiguousarray(kelvin[::-1])


@pytest.mark.parametrize(
    "sections",
    [{}, {"sph": {"surface_only": True}}],
    ids=["culling+occlusion", "surface_only"],
)
def test_each_pixel_shows_the_temperature_of_its_front_particle(
    renderer: SurfaceRenderer, sections: dict[str, dict[str, object]]
) -> None:
    """Every particle gets its own temperature (a shuffled ramp, 0.5 K apart) and ~13% of the
    particles, spread through the array, lie outside the view (behind the eye or beside the
    image), so culling keeps a subset in scattered order. The splatted temperature must equal,
    pixel for pixel, the temperature of the particle a numpy ray cast finds in front; every
    path that subsets the particles (view culling, occlusion culling of the ~3000-particle
    ball, surface-only splatting) must carry the temperatures along with the positions: a
    shift or permutation of the temperatures shows on most pixels. Pixels where the two
    nearest spheres are within 1e-3 r in depth are ties that float32 may break either way;
    they are left out (and counted)."""
    r = 0.015
    eye = np.array([1.2, 0.9, 1.3])  # oblique: along a lattice axis rays slip between columns
    rng = np.random.default_rng(5)
    ball = jittered_lattice_ball(0.3, r, seed=4)
    outside = np.concatenate(
        [
            rng.uniform(-0.5, 0.5, (300, 3)) + 1.8 * eye,  # behind the eye
            rng.uniform(-0.2, 0.2, (300, 3)) + np.array([0.0, 3.0, 0.0]),  # beside the image
        ]
    )
    positions = np.concatenate([ball, outside])[rng.permutation(len(ball) + len(outside))]
    temperatures = 1200.0 + 0.5 * rng.permutation(len(positions)).astype(np.float64)
    scene = scene_from_dict(
        {
            "image": {"width": 128, "height": 96},
            "camera": {"eye": list(eye), "fov_y": 30.0},
            "particles": {"radius": r},
            "shading": {"debug_view": "emission", "ibl_mode": "none"},
            # The splat's own kelvin: the gap pass fills closed gaps in it (interpolated).
            "quality": {"close_gaps": 0.0},
            **sections,
        }
    )
    frame = make_frame(positions, temperatures=temperatures)
    _, stats = renderer.render(frame, scene)
    camera = Camera.from_config(scene.camera, 128, 96)
    assert stats.particles_drawn < len(positions)  # culling removed some
    if "sph" in sections:
        assert stats.particles_drawn < len(ball)  # hidden interior not drawn
    else:
        assert stats.particles_splatted < stats.particles_drawn  # occlusion culling ran
    got = splatted_temperature(renderer, (128, 96))
    front, gap = front_particles(camera, positions, r)
    hit = front >= 0
    assert np.array_equal(got > 0, hit)  # coverage is the union of the spheres
    want = np.where(hit, temperatures.astype(np.float32)[front], 0.0)
    decided = hit & (gap > 1e-3 * r)
    assert decided.sum() > 0.97 * hit.sum() > 2000
    wrong = decided & (got != want)
    print(f"{sections}: {hit.sum()} px, {hit.sum() - decided.sum()} ties, {wrong.sum()} wrong")
    assert not wrong.any()
