"""Heat tint against Blender Cycles' thin film (Principled and Metallic BSDF): ΔE2000 per thickness.

Not a test; a bench extra run by hand. Needs a second environment with Blender as a module
(bpy >= 4.2 for the thin film; its wheels are CPython 3.11 only and pin numpy < 2, so it is no
extra of this package):
    python3.11 -m venv .venv-bpy && .venv-bpy/bin/pip install 'bpy>=4.2'
Run:  .venv/bin/python benchmarks/bench_cycles_thin_film.py [--bpy-python .venv-bpy/bin/python]

The case, the same in both: a flat mirror plate (roughness 0) of the preset's metal F0 under a
uniform white environment of radiance 1, seen head-on and at 60 degrees from the normal, a
thin film of the preset's film n on it. Cycles renders a 16x16 orthographic view of the plate
(GGX, roughness 0, Thin Film Thickness / IOR; Standard view transform, linear Rec.709 scene
space) and the bench takes the mean pixel.

Cycles' base metals. The Metallic BSDF's physical conductor ("conductor") is given
thin_film.py's own substrate n + ik at 650, 550 and 450 nm: the same metal. The Principled BSDF
(metallic 1) takes a base colour F0 and a Specular Tint t, an F82-tint metal (Kutz et al.):
F(cos) = Schlick(cos) - b cos (1 - cos)^6 with b set so that F(1/7) = Schlick(1/7) t. With a
film (kernel/closure/bsdf_microfacet.h, microfacet_fresnel, the F82_TINT branch; bsdf_util.h,
fresnel_iridescence and fresnel_conductor_polarized; bpy 5.0.1's copy under
cycles/source/kernel, other versions may differ) it turns that metal into a conductor by
Gulbrandsen's inversion with r = min(F0, 0.999) and edge tint g = F(1/7), the model's own
reflectance at 82 degrees; the film/metal interface then takes its phase from that n + ik and
its reflectance from the F82 model again (F0 of n + ik relative to the film index, F82 = g), one
value for s and p. thin_film.py inverts with g = F0 and uses the exact s and p terms. So the
Principled's film sits on our n + ik exactly when F(1/7) = F0, i.e. t = F0 / Schlick(1/7)
("principled g=F0"); t white ("principled") gives g = Schlick(1/7) > F0, a smaller n and another
phase; t = our metal's true 82-degree reflectance over Schlick's ("principled F82") matches our
bare metal's angular curve but not its film substrate.

sphrender's side is thin_film.py's functions: `film_rgb` with the film's k set to 0 (Cycles
takes a real IOR only: the like-for-like case); thin_film.py's optics on the substrate Cycles'
model implies ("implied": the film apart from the metal model); the bench's numpy Airy sum with
the Principled's F82 interface ("iface"), and with all of Cycles' rule ("rule": also Belcour &
Barla's series cut after m = 3 and n + ik constant within each RGB channel, each channel
integrated on its own, bsdf_util.h iridescence_airy_summation); `film_rgb` with the real k; and
the product's table value (`spread_rgb`: real k plus the lognormal thickness spread). Both RGBs
go to CIELAB (D65, white = RGB 1) and the bench prints ΔE2000 per thickness. This process
imports bpy only in `--cycles-worker` mode, which the main mode runs under --bpy-python.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

THICKNESSES_NM = (0.0, 20.0, 40.0, 60.0, 80.0, 100.0, 150.0)
COS_THETAS = (1.0, 0.5)
PRESETS = ("iron", "stainless_steel")
MODELS = ("principled", "principled g=F0", "principled F82", "conductor")
HEADER = """Cycles: principled = Principled BSDF (metallic 1, base colour F0, Specular Tint white);
  principled g=F0 = the same, Specular Tint F0 / Schlick(82 deg): its film substrate is ours;
  principled F82 = Specular Tint = our metal's reflectance at 82 deg / Schlick's: our bare metal;
  conductor = Metallic BSDF, physical conductor, n + ik = thin_film.py's substrate, 650/550/450 nm.
dE2000 (CIELAB D65, white = RGB 1) of Cycles against thin_film.py with the film's k = 0 and no
  spread (like for like); the same on the substrate Cycles' model implies (implied), then with
  the Principled's film/metal interface (iface: F82 |r|^2, one for s and p), then with all of
  Cycles' rule (rule: also Airy's series cut at m = 3, n + ik constant per RGB channel, each
  channel integrated on its own); with the film's k; the table (k + lognormal spread: the
  product's);
  noise = the largest per-pixel standard deviation in the Cycles image."""
SIZE = 16
CHANNEL_NM = np.array([650.0, 550.0, 450.0])  # thin_film.py's R, G, B wavelengths
SAMPLES = 64

SRGB_TO_XYZ = np.array(
    [[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]
)


def cycles_worker(request_path: str, out_path: str) -> None:
    """Render every (preset, thickness, angle) in Cycles; write mean linear RGB as JSON."""
    import bpy

    request = json.loads(Path(request_path).read_text())
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = SAMPLES
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    world = bpy.data.worlds.new("white")
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    background.inputs["Strength"].default_value = 1.0
    scene.world = world
    bpy.ops.mesh.primitive_plane_add(size=1000.0)
    plate = bpy.context.active_object
    material = bpy.data.materials.new("plate")
    material.use_nodes = True
    tree = material.node_tree
    principled = tree.nodes["Principled BSDF"]
    principled.distribution = "GGX"
    principled.inputs["Metallic"].default_value = 1.0
    principled.inputs["Roughness"].default_value = 0.0
    conductor = tree.nodes.new("ShaderNodeBsdfMetallic")
    conductor.fresnel_type = "PHYSICAL_CONDUCTOR"
    conductor.distribution = "GGX"
    conductor.inputs["Roughness"].default_value = 0.0
    output = tree.nodes["Material Output"]
    plate.data.materials.append(material)
    camera_data = bpy.data.cameras.new("camera")
    camera_data.type = "ORTHO"
    camera_data.ortho_scale = 1.0
    camera = bpy.data.objects.new("camera", camera_data)
    scene.collection.objects.link(camera)
    scene.camera = camera
    results = []
    out_dir = Path(tempfile.mkdtemp())
    for case in request:
        if case["model"].startswith("principled"):
            bsdf = principled
            bsdf.inputs["Base Color"].default_value = (*case["f0"], 1.0)
            bsdf.inputs["Specular Tint"].default_value = (*case["tint"], 1.0)
        else:
            bsdf = conductor
            bsdf.inputs["IOR"].default_value = case["substrate_n"]
            bsdf.inputs["Extinction"].default_value = case["substrate_k"]
        tree.links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
        bsdf.inputs["Thin Film Thickness"].default_value = case["thickness_nm"]
        bsdf.inputs["Thin Film IOR"].default_value = case["film_n"]
        theta = float(np.arccos(case["cos_theta"]))
        camera.location = (0.0, -10.0 * np.sin(theta), 10.0 * np.cos(theta))
        camera.rotation_euler = (theta, 0.0, 0.0)
        scene.render.filepath = str(out_dir / "frame.exr")
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(str(out_dir / "frame.exr"))
        pixels = np.array(image.pixels[:], dtype=np.float64).reshape(-1, 4)[:, :3]
        bpy.data.images.remove(image)
        results.append({**case, "rgb": pixels.mean(axis=0).tolist(), "std": pixels.std(0).tolist()})
    Path(out_path).write_text(json.dumps(results))


def cielab(rgb: np.ndarray) -> np.ndarray:
    """CIELAB (D65) of linear Rec.709 reflectances, white = RGB (1, 1, 1)."""
    white = SRGB_TO_XYZ @ np.ones(3)
    xyz = (np.asarray(rgb) @ SRGB_TO_XYZ.T) / white
    f = np.where(
        xyz > (6 / 29) ** 3, np.cbrt(np.maximum(xyz, 0.0)), xyz / (3 * (6 / 29) ** 2) + 4 / 29
    )
    return np.stack(
        [116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1
    )


def ciede2000(lab1: np.ndarray, lab2: np.ndarray) -> np.ndarray:
    """CIE ΔE2000 (Sharma, Wu & Dalal 2005), kL = kC = kH = 1."""
    l1, a1, b1 = np.moveaxis(lab1, -1, 0)
    l2, a2, b2 = np.moveaxis(lab2, -1, 0)
    c_mean = (np.hypot(a1, b1) + np.hypot(a2, b2)) / 2
    g = 0.5 * (1 - np.sqrt(c_mean**7 / (c_mean**7 + 25.0**7)))
    a1p, a2p = (1 + g) * a1, (1 + g) * a2
    c1p, c2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.degrees(np.arctan2(b1, a1p)) % 360
    h2p = np.degrees(np.arctan2(b2, a2p)) % 360
    dlp, dcp = l2 - l1, c2p - c1p
    dh = h2p - h1p
    dh = np.where(dh > 180, dh - 360, np.where(dh < -180, dh + 360, dh))
    dh = np.where(c1p * c2p == 0, 0.0, dh)
    dhp = 2 * np.sqrt(c1p * c2p) * np.sin(np.radians(dh / 2))
    lp, cp = (l1 + l2) / 2, (c1p + c2p) / 2
    hsum = h1p + h2p
    hp = np.where(
        c1p * c2p == 0,
        hsum,
        np.where(
            np.abs(h1p - h2p) <= 180, hsum / 2, np.where(hsum < 360, hsum / 2 + 180, hsum / 2 - 180)
        ),
    )
    t = (
        1
        - 0.17 * np.cos(np.radians(hp - 30))
        + 0.24 * np.cos(np.radians(2 * hp))
        + 0.32 * np.cos(np.radians(3 * hp + 6))
        - 0.20 * np.cos(np.radians(4 * hp - 63))
    )
    sl = 1 + 0.015 * (lp - 50) ** 2 / np.sqrt(20 + (lp - 50) ** 2)
    sc, sh = 1 + 0.045 * cp, 1 + 0.015 * cp * t
    rt = (
        -2
        * np.sqrt(cp**7 / (cp**7 + 25.0**7))
        * np.sin(np.radians(60 * np.exp(-(((hp - 275) / 25) ** 2))))
    )
    result: np.ndarray = np.sqrt(
        (dlp / sl) ** 2 + (dcp / sc) ** 2 + (dhp / sh) ** 2 + rt * (dcp / sc) * (dhp / sh)
    )
    return result


def schlick_82(f0: np.ndarray) -> np.ndarray:
    """Schlick's Fresnel at cos theta = 1/7 (~82 degrees), where F82-tint pins its tint."""
    result: np.ndarray = f0 + (1.0 - f0) * (6.0 / 7.0) ** 5
    return result


def gulbrandsen(r: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Gulbrandsen's (2014) n + ik from reflectivity r and edge tint g, as Cycles' Principled
    evaluates it (r clamped to 0.999; thin_film.gulbrandsen_index is the case g = r)."""
    r = np.minimum(r, 0.999)
    sr = np.sqrt(r)
    n = (1.0 + sr) / (1.0 - sr) * (1.0 - g) + (1.0 - r) / (1.0 + r) * g
    k2 = (r * (n + 1.0) ** 2 - (n - 1.0) ** 2) / (1.0 - r)
    result: np.ndarray = n + 1j * np.sqrt(np.maximum(k2, 0.0))
    return result


def principled_inputs(model: str, f0: np.ndarray, substrate: np.ndarray) -> dict[str, list]:
    """Specular Tint for a Principled model, and the edge tint g and n + ik per RGB channel
    its film sees."""
    from sphrender.server.engine.lighting.thin_film import film_reflectance_spectrum

    if model == "principled":
        tint = np.ones(3)
    elif model == "principled g=F0":
        tint = f0 / schlick_82(f0)
    else:
        ours_82 = film_reflectance_spectrum(
            np.zeros(3), np.full(3, 1.0 / 7.0), CHANNEL_NM, 1.0 + 0j, substrate
        )
        tint = ours_82 / schlick_82(f0)
    edge = schlick_82(f0) * np.minimum(tint, 1.0)  # the model's reflectance at cos 1/7
    implied = gulbrandsen(f0, edge)
    return {
        "tint": tint.tolist(),
        "implied_g": edge.tolist(),
        "implied_n": implied.real.tolist(),
        "implied_k": implied.imag.tolist(),
    }


def per_wavelength(channels: np.ndarray, wavelengths: np.ndarray) -> np.ndarray:
    """Values at the R, G, B wavelengths, linear in between and constant outside, as
    thin_film.substrate_index spreads the substrate's n + ik."""
    order = np.argsort(CHANNEL_NM)
    real = np.interp(wavelengths, CHANNEL_NM[order], np.real(channels)[order])
    imag = np.interp(wavelengths, CHANNEL_NM[order], np.imag(channels)[order])
    result: np.ndarray = real + 1j * imag if np.iscomplexobj(channels) else real
    return result


def f82_tint_reflectance(cos: np.ndarray, f0: np.ndarray, f82: np.ndarray) -> np.ndarray:
    """The F82 metal model (Kutz et al.) through F0 at normal incidence and f82 at cos = 1/7."""
    b = 7.0 / (6.0 / 7.0) ** 6 * (schlick_82(f0) - f82)
    s = 1.0 - cos
    result: np.ndarray = np.clip(f0 + (1.0 - f0) * s**5 - b * cos * s**6, 0.0, 1.0)
    return result


def airy_spectrum(
    row: dict, n2: np.ndarray, edge: np.ndarray, wavelengths: np.ndarray, cycles: set[str]
) -> np.ndarray:
    """Film (k = 0) on a substrate n2 with edge tint `edge` (per wavelength or constant), the
    reflectance spectrum averaged over s and p. `cycles` picks Cycles' approximations:
    "interface" = the film/metal interface keeps the phase of n2 but reflects the F82 model's
    |r|^2 (F0 of n2 relative to the film, F82 = the edge tint), one value for s and p;
    "orders" = Airy's series in Belcour & Barla's Fourier form cut after the third order."""
    n1, c0, d = row["film_n"], row["cos_theta"], row["thickness_nm"]
    sin2 = 1.0 - c0**2
    c1, c2 = np.sqrt(1.0 - sin2 / n1**2), np.sqrt(1.0 - sin2 / n2**2 + 0j)
    f0_inside = np.abs((n2 / n1 - 1.0) / (n2 / n1 + 1.0)) ** 2
    amplitude = np.sqrt(f82_tint_reflectance(c1, f0_inside, edge))
    delta = 4.0 * np.pi * n1 * d * c1 / wavelengths
    spectrum = np.zeros_like(wavelengths)
    for r01, r12 in (
        ((c0 - n1 * c1) / (c0 + n1 * c1), (n1 * c1 - n2 * c2) / (n1 * c1 + n2 * c2)),
        ((n1 * c0 - c1) / (n1 * c0 + c1), (n2 * c1 - n1 * c2) / (n2 * c1 + n1 * c2)),
    ):
        if "interface" in cycles:
            r12 = amplitude * r12 / np.abs(r12)
        if "orders" not in cycles:
            phase = np.exp(1j * delta)
            spectrum += 0.5 * np.abs((r01 + r12 * phase) / (1.0 + r01 * r12 * phase)) ** 2
            continue
        r_top, r_bottom = r01**2, np.abs(r12) ** 2
        t_top, r_both = 1.0 - r_top, np.sqrt(r_top * r_bottom)
        r_sum = t_top**2 * r_bottom / (1.0 - r_top * r_bottom)
        shift = np.angle(r12) + np.angle(-r01)
        total = r_top + r_sum
        for m in range(1, 4):
            total = total + 2.0 * (r_sum - t_top) * r_both**m * np.cos(m * (delta + shift))
        spectrum += 0.5 * total
    return spectrum


def film_rgb_on(row: dict, cycles: set[str]) -> np.ndarray:
    """RGB of airy_spectrum on the substrate Cycles' model implies. With "channels" in `cycles`
    as Cycles does: n + ik constant within each RGB channel, each channel integrated on its own
    and clamped to 0..1; else n + ik interpolated over wavelength as thin_film.py does."""
    from sphrender.server.engine.lighting.thin_film import (
        film_reflectance_spectrum,
        spectrum_to_rgb,
    )

    wavelengths = np.arange(380.0, 781.0, 5.0)
    n_k = np.array(row["implied_n"]) + 1j * np.array(row["implied_k"])
    edge = np.array(row.get("implied_g", [-1.0] * 3))
    if not cycles:  # thin_film.py's own optics on Cycles' metal
        spectrum = film_reflectance_spectrum(
            np.array(row["thickness_nm"]),
            np.array(row["cos_theta"]),
            wavelengths,
            complex(row["film_n"]),
            per_wavelength(n_k, wavelengths),
        )
        return np.asarray(spectrum_to_rgb(spectrum))
    if "channels" not in cycles:
        n2, g = per_wavelength(n_k, wavelengths), per_wavelength(edge, wavelengths)
        return np.asarray(spectrum_to_rgb(airy_spectrum(row, n2, g, wavelengths, cycles)))
    rgb = np.empty(3)
    for channel in range(3):
        spectrum = airy_spectrum(row, n_k[channel], edge[channel], wavelengths, cycles)
        rgb[channel] = spectrum_to_rgb(spectrum)[channel]
    return np.clip(rgb, 0.0, 1.0)


def sphrender_rgbs(row: dict) -> dict[str, np.ndarray]:
    """thin_film.py's reflectance: k = 0 uniform; k = 0 on the substrate Cycles implies, then
    with Cycles' interface, then with all of Cycles' rule; real k uniform; real k with the
    spread."""
    from sphrender.server.engine.lighting.materials import METAL_F0
    from sphrender.server.engine.lighting.thin_film import (
        FilmSpec,
        film_rgb,
        film_spec,
        spread_rgb,
    )

    spec = film_spec(row["preset"], METAL_F0[row["preset"]])
    interface = set() if row["model"] == "conductor" else {"interface"}
    lossless = FilmSpec(spec.f0, complex(spec.film_index.real, 0.0))
    d, c = np.array([row["thickness_nm"]]), np.array([row["cos_theta"]])
    return {
        "k0": film_rgb(lossless, d, c)[0],
        "implied": film_rgb_on(row, set()),
        "interface": film_rgb_on(row, interface),
        "rule": film_rgb_on(row, interface | {"orders", "channels"}),
        "k": film_rgb(spec, d, c)[0],
        "table": spread_rgb(spec, d, c)[0, 0],
    }


def build_cases() -> list[dict]:
    """Every (preset, Cycles model, angle, thickness) with the inputs both sides need."""
    from sphrender.server.engine.lighting.materials import METAL_F0
    from sphrender.server.engine.lighting.thin_film import (
        FILM_INDEX,
        gulbrandsen_index,
        substrate_index,
    )

    cases = []
    for preset in PRESETS:
        f0 = np.asarray(METAL_F0[preset], dtype=np.float64)
        substrate = substrate_index(METAL_F0[preset], CHANNEL_NM)
        # The bench's Gulbrandsen must be thin_film.py's where the edge tint is F0.
        assert np.allclose(gulbrandsen(f0, f0), gulbrandsen_index(f0), rtol=1e-12)
        common = {
            "preset": preset,
            "f0": f0.tolist(),
            "substrate_n": substrate.real.tolist(),
            "substrate_k": substrate.imag.tolist(),
            "film_n": FILM_INDEX[preset].real,
        }
        for model in MODELS:
            if model == "conductor":
                extra = {"implied_n": common["substrate_n"], "implied_k": common["substrate_k"]}
            else:
                extra = principled_inputs(model, f0, substrate)
            for c in COS_THETAS:
                for d in THICKNESSES_NM:
                    cases.append(
                        {**common, **extra, "model": model, "thickness_nm": d, "cos_theta": c}
                    )
    return cases


def render_in_cycles(bpy_python: str, cases: list[dict]) -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        request, out = Path(tmp) / "request.json", Path(tmp) / "out.json"
        request.write_text(json.dumps(cases))
        subprocess.run(
            [bpy_python, __file__, "--cycles-worker", str(request), str(out)],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        rendered: list[dict] = json.loads(out.read_text())
    return rendered


def print_inputs(cases: list[dict]) -> None:
    """The Principled inputs and the n + ik they imply, per preset and model."""
    seen = set()
    print("inputs (R, G, B at 650/550/450 nm):")
    for case in cases:
        key = (case["preset"], case["model"])
        if key in seen:
            continue
        seen.add(key)
        tint = np.array(case.get("tint", [np.nan] * 3))
        n_k = np.array(case["implied_n"]) + 1j * np.array(case["implied_k"])
        print(
            f"  {case['preset']:16s} {case['model']:16s} tint {np.array2string(tint, precision=3)}"
            f"  n+ik {np.array2string(n_k, precision=3)}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bpy-python", default=".venv-bpy/bin/python")
    parser.add_argument(
        "--cycles-worker", nargs=2, metavar=("REQUEST", "OUT"), help=argparse.SUPPRESS
    )
    args = parser.parse_args()
    if args.cycles_worker:
        cycles_worker(*args.cycles_worker)
        return
    cases = build_cases()
    rendered = render_in_cycles(args.bpy_python, cases)
    print(HEADER)
    print_inputs(cases)
    print(
        f"{'preset':16s} {'model':16s} cos  d nm  {'Cycles RGB':24s} {'ours k=0 RGB':24s} "
        "dE k=0  implied  iface  rule  dE k  dE table  noise"
    )
    worst: dict[tuple[str, float], list[tuple[float, float, float]]] = {}
    for row in rendered:
        ours = sphrender_rgbs(row)
        theirs = cielab(np.array(row["rgb"]))
        de = {key: float(ciede2000(cielab(value), theirs)) for key, value in ours.items()}
        worst.setdefault((row["model"], row["cos_theta"]), []).append(
            (row["thickness_nm"], de["k0"], de["rule"])
        )
        print(
            f"{row['preset']:16s} {row['model']:16s} "
            f"{row['cos_theta']:.1f} {row['thickness_nm']:5.0f}  "
            f"{np.array2string(np.array(row['rgb']), precision=3):24s} "
            f"{np.array2string(ours['k0'], precision=3):24s} "
            f"{de['k0']:6.2f} {de['implied']:8.2f} {de['interface']:6.2f} {de['rule']:5.2f} "
            f"{de['k']:5.2f} "
            f"{de['table']:8.2f}  "
            f"{max(row['std']):.1e}"
        )
    print("against thin_film.py with k = 0 and no spread, both presets, every thickness:")
    for (model, cos), pairs in worst.items():
        thickness, values, rule = np.array(pairs).T
        print(
            f"  {model:16s} cos {cos:.1f}: max dE {values.max():5.2f}, "
            f"median {np.median(values):4.2f}, {(values <= 3.0).sum()} of {len(values)} <= 3; "
            f"Cycles' rule in numpy with a film: max dE {rule[thickness > 0].max():4.2f}"
        )
    sys.stdout.flush()


if __name__ == "__main__":
    main()
