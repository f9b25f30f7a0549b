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
space) and the bench takes the mean pixel, with two base-metal models: the Principled BSDF
(metallic 1, base colour = F0, its F82-tint conductor) and the Metallic BSDF's physical
conductor given thin_film.py's own substrate n + ik at 650, 550 and 450 nm (the same metal).
sphrender's side is thin_film.py's functions: `film_rgb` with the film's k set to 0 (Cycles
takes a real IOR only: the like-for-like case), `film_rgb` with the real k, and the product's
table value (`spread_rgb`: real k plus the lognormal thickness spread). Both RGBs go to
CIELAB (D65, white = RGB 1) and the bench prints ΔE2000 per thickness. This process imports bpy
only in `--cycles-worker` mode, which the main mode runs under --bpy-python.
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
MODELS = ("principled", "conductor")
HEADER = """Cycles: principled = Principled BSDF (metallic 1, base colour F0, F82 tint white);
  conductor = Metallic BSDF, physical conductor, n + ik = thin_film.py's substrate, 650/550/450 nm.
dE2000 (CIELAB D65, white = RGB 1) of Cycles against thin_film.py with the film's k = 0 and no
  spread (like for like), with its k, and the table (k + lognormal spread: the product's);
  noise = the largest per-pixel standard deviation in the Cycles image."""
SIZE = 16
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
        if case["model"] == "principled":
            bsdf = principled
            bsdf.inputs["Base Color"].default_value = (*case["f0"], 1.0)
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


def sphrender_rgbs(preset: str, thickness: float, cos_theta: float) -> dict[str, np.ndarray]:
    """thin_film.py's reflectance: k = 0 uniform, real k uniform, real k with the spread."""
    from sphrender.server.engine.lighting.materials import METAL_F0
    from sphrender.server.engine.lighting.thin_film import (
        FilmSpec,
        film_rgb,
        film_spec,
        spread_rgb,
    )

    spec = film_spec(preset, METAL_F0[preset])
    lossless = FilmSpec(spec.f0, complex(spec.film_index.real, 0.0))
    d, c = np.array([thickness]), np.array([cos_theta])
    return {
        "k0": film_rgb(lossless, d, c)[0],
        "k": film_rgb(spec, d, c)[0],
        "table": spread_rgb(spec, d, c)[0, 0],
    }


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
    from sphrender.server.engine.lighting.materials import METAL_F0
    from sphrender.server.engine.lighting.thin_film import (
        FILM_INDEX,
        substrate_index,
    )

    cases = []
    for preset in PRESETS:
        substrate = substrate_index(METAL_F0[preset], np.array([650.0, 550.0, 450.0]))
        common = {
            "preset": preset,
            "f0": list(METAL_F0[preset]),
            "substrate_n": substrate.real.tolist(),
            "substrate_k": substrate.imag.tolist(),
            "film_n": FILM_INDEX[preset].real,
        }
        for model in MODELS:
            for c in COS_THETAS:
                for d in THICKNESSES_NM:
                    cases.append({**common, "model": model, "thickness_nm": d, "cos_theta": c})
    with tempfile.TemporaryDirectory() as tmp:
        request, out = Path(tmp) / "request.json", Path(tmp) / "out.json"
        request.write_text(json.dumps(cases))
        subprocess.run(
            [args.bpy_python, __file__, "--cycles-worker", str(request), str(out)],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        rendered = json.loads(out.read_text())
    print(HEADER)
    print(
        f"{'preset':16s} {'model':10s} cos  d nm  {'Cycles RGB':24s} {'ours k=0 RGB':24s} "
        "dE k=0  dE k  dE table  noise"
    )
    for row in rendered:
        ours = sphrender_rgbs(row["preset"], row["thickness_nm"], row["cos_theta"])
        theirs = cielab(np.array(row["rgb"]))
        de = {key: float(ciede2000(cielab(value), theirs)) for key, value in ours.items()}
        print(
            f"{row['preset']:16s} {row['model']:10s} "
            f"{row['cos_theta']:.1f} {row['thickness_nm']:5.0f}  "
            f"{np.array2string(np.array(row['rgb']), precision=3):24s} "
            f"{np.array2string(ours['k0'], precision=3):24s} "
            f"{de['k0']:6.2f} {de['k']:5.2f} {de['table']:8.2f}  {max(row['std']):.1e}"
        )
    sys.stdout.flush()


if __name__ == "__main__":
    main()
