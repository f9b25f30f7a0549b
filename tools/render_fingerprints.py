"""Byte fingerprints of reference renders, to show that a change did not move a single byte.

Drives only the public CLI (`sphrender demo`, `sphrender render`, `sphrender sph`), so it does
not depend on the internal module layout: run it before a refactor with `--write FILE`, after it
with `--check FILE`.

    .venv/bin/python tools/render_fingerprints.py --write /tmp/before.json
    ... refactor ...
    .venv/bin/python tools/render_fingerprints.py --check /tmp/before.json

The cases cover every pass and option family the engine has: the demo (temperatures, occlusion
culling, workshop IBL, environment background), a jittered ball as float EXR with Z and N,
sampled IBL with lights, the 2-D bilateral filter, gaussian with the depth-falloff kernel and
16-bit PNG, adaptive radii with surface-only splatting (SPH on OpenCL), and the SPH quantities file.
Every case renders under each quality preset (`--quality fast|balanced|best`) as well as on the
scene's own settings. With `../shared/data` beside the checkout, a dam-break frame (SPlisHSPlasH
VTK) joins the cases; a spatter frame (a pool with scattered droplets, densities and temperatures)
is generated here.
The SPH pass may differ between runs in the last float32 bit (atomic arrival order, see
ARCHITECTURE.md), so the SPH cases are rendered twice and reported as "nondeterministic" instead
of "changed" when the two runs already disagree.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SPHRENDER = [str(Path(sys.executable).parent / "sphrender")]


def _ball(count: int, seed: int) -> np.ndarray:
    """A jittered lattice ball of radius ~1 centred at the origin (spacing 2 r, r = 0.05)."""
    rng = np.random.default_rng(seed)
    r = 0.05
    axis = np.arange(-1.0, 1.0 + 1e-9, 2 * r)
    grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    grid = grid[np.linalg.norm(grid, axis=1) <= 1.0]
    grid = grid + rng.normal(0.0, 0.1 * r, grid.shape)
    return grid[:count]


def _scene(**sections: Any) -> dict[str, Any]:
    base: dict[str, Any] = {
        "image": {"width": 320, "height": 180},
        "camera": {"eye": [0.3, 0.8, 3.2], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        "particles": {"radius": 0.05},
    }
    for key, value in sections.items():
        base[key] = value if isinstance(value, list) else {**base.get(key, {}), **value}
    return base


def _toml(scene: dict[str, Any]) -> str:
    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines: list[str] = []
    for section, fields in scene.items():
        if section == "lights":
            for light in fields:
                lines.append("[[lights]]")
                lines += [f"{k} = {value(v)}" for k, v in light.items()]
            continue
        lines.append(f"[{section}]")
        lines += [f"{k} = {value(v)}" for k, v in fields.items()]
    return "\n".join(lines) + "\n"


CASES: dict[str, dict[str, Any]] = {
    "ball_exr_aovs": _scene(
        output={"format": "exr", "aovs": ["Z", "N"], "exr_pixel_type": "float"}
    ),
    "ball_sampled_lights": _scene(
        shading={"ibl_mode": "sampled", "ibl_samples": 16},
        lights=[
            {"type": "directional", "direction": [0.3, -1.0, -0.4], "intensity": 2.0},
            {"type": "point", "position": [1.5, 2.0, 1.0], "intensity": 3.0},
        ],
        material={"preset": "copper", "roughness": 0.3},
    ),
    "ball_bilateral_2d_envbg": _scene(
        quality={"filter": "bilateral", "separable": False, "iterations": 2},
        shading={"background": "environment"},
        environment={"preset": "studio"},
    ),
    "ball_gaussian_eq25_png16": _scene(
        quality={"filter": "gaussian", "kernel_size": "depth_falloff"},
        output={"png_bits": 16, "tone_mapper": "clamp"},
        shading={"multiple_scattering": True},
    ),
    "ball_sph_adaptive_surface_only": _scene(
        sph={"adaptive_radius": True, "surface_only": True},
    ),
}
SPH_CASES = {"ball_sph_adaptive_surface_only"}


PRESETS = ("fast", "balanced", "best")
DAMBREAK_VTK = ROOT.parent / "shared" / "data" / "dambreak-splishsplash" / "vtk"


def _spatter(seed: int) -> dict[str, np.ndarray]:
    """A shallow pool of particles with droplets flung above it, with densities and temperatures."""
    rng = np.random.default_rng(seed)
    r = 0.05
    axis = np.arange(-1.0, 1.0 + 1e-9, 2 * r)
    layers = np.arange(0.0, 4 * 2 * r, 2 * r)
    x, y, z = np.meshgrid(axis, layers, axis, indexing="ij")
    pool = np.stack([x, y - 0.5, z], -1).reshape(-1, 3)
    pool = pool + rng.normal(0.0, 0.1 * r, pool.shape)
    drops = rng.uniform([-0.8, -0.1, -0.8], [0.8, 0.9, 0.8], (300, 3))
    positions = np.concatenate([pool, drops])
    densities = np.concatenate(
        [rng.normal(1000.0, 15.0, len(pool)), rng.uniform(100.0, 300.0, len(drops))]
    )
    temperatures = 1500.0 + 1200.0 * (positions[:, 1] + 0.5)
    return {
        "positions": positions,
        "densities": densities.astype(np.float32),
        "temperatures": temperatures.astype(np.float32),
    }


def _frames(work: Path) -> dict[str, Path]:
    """The particle frames the cases render: name -> file."""
    positions = _ball(20_000, seed=3)
    temperatures = (1200.0 + 1500.0 * (positions[:, 1] + 1.0) / 2.0).astype(np.float32)
    frames = {"ball": work / "ball.npz", "plain": work / "plain.npz"}
    np.savez(frames["ball"], positions=positions, temperatures=temperatures)
    np.savez(frames["plain"], positions=positions)
    frames["spatter"] = work / "spatter.npz"
    np.savez(frames["spatter"], **_spatter(seed=5))
    dam = DAMBREAK_VTK / "ParticleData_Fluid_9.vtk"
    if dam.exists():
        frames["dambreak"] = dam
    return frames


#: Extra cases on other frames: name -> (frame name, scene).
FRAME_CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "spatter": (
        "spatter",
        _scene(camera={"eye": [0.2, 1.4, 2.8], "target": [0.0, -0.2, 0.0], "fov_y": 45.0}),
    ),
    "dambreak_frame9": (
        "dambreak",
        _scene(
            camera={"eye": [0.5, 2.5, 4.0], "target": [-0.5, 0.4, 0.0], "fov_y": 40.0},
            particles={"radius": 0.015},
        ),
    ),
}


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _run(args: list[str]) -> None:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "1")}
    subprocess.run([*SPHRENDER, *args], check=True, cwd=ROOT, env=env, capture_output=True)


def fingerprints(work: Path) -> dict[str, list[str]]:
    """Each case's SHA-256 (two for the SPH cases: one per run)."""
    out: dict[str, list[str]] = {}
    demo = work / "demo.png"
    _run(["demo", "-o", str(demo)])
    out["demo_png"] = [_sha(demo)]
    demo_frame = work / "demo.npz"
    code = (
        "import sys, numpy as np; from sphrender.server.content.demo import demo_frame; "
        "f = demo_frame(); np.savez(sys.argv[1], positions=f.positions, "
        "temperatures=f.temperatures)"
    )
    subprocess.run([sys.executable, "-c", code, str(demo_frame)], check=True)
    demo_scene = ROOT / "configs" / "demo.toml"
    for preset in PRESETS:
        image = work / f"demo-{preset}.png"
        _run(
            [
                "render",
                str(demo_frame),
                "--scene",
                str(demo_scene),
                "-o",
                str(image),
                "--quality",
                preset,
            ]
        )
        out[f"demo_png@{preset}"] = [_sha(image)]
    frames = _frames(work)
    cases = {
        name: ("plain" if name in SPH_CASES else "ball", scene) for name, scene in CASES.items()
    }
    cases.update(FRAME_CASES)
    for name, (frame_name, scene) in cases.items():
        if frame_name not in frames:
            continue
        scene_path = work / f"{name}.toml"
        scene_path.write_text(_toml(scene))
        suffix = ".exr" if scene.get("output", {}).get("format") == "exr" else ".png"
        runs = 2 if name in SPH_CASES or frame_name in ("spatter", "dambreak") else 1
        for preset in (None, *PRESETS):
            key = name if preset is None else f"{name}@{preset}"
            quality = [] if preset is None else ["--quality", preset]
            out[key] = []
            for run in range(runs):
                image = work / f"{key}-{run}{suffix}"
                _run(
                    [
                        "render",
                        str(frames[frame_name]),
                        "--scene",
                        str(scene_path),
                        "-o",
                        str(image),
                        *quality,
                    ]
                )
                out[key].append(_sha(image))
    plain = frames["plain"]
    sph_out = work / "sph.npz"
    _run(
        [
            "sph",
            str(plain),
            "--scene",
            str(work / "ball_sph_adaptive_surface_only.toml"),
            "-o",
            str(sph_out),
        ]
    )
    with np.load(sph_out) as data:
        out["sph_quantities_surface"] = [
            hashlib.sha256(np.asarray(data["surface"]).tobytes()).hexdigest()
        ]
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--write", type=Path, help="write the fingerprints to this JSON file")
    group.add_argument("--check", type=Path, help="compare with fingerprints in this JSON file")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        current = fingerprints(Path(tmp))
    if args.write:
        args.write.write_text(json.dumps(current, indent=2) + "\n")
        for name, shas in current.items():
            print(f"{name:34s} {' '.join(s[:16] for s in shas)}")
        return 0
    before = json.loads(args.check.read_text())
    failed = 0
    for name, shas in current.items():
        old = before.get(name)
        if old is None:
            verdict = "new"
        elif shas[0] == old[0]:
            verdict = "identical"
        elif len(set(old)) > 1 or len(set(shas)) > 1:
            verdict = "nondeterministic (runs disagree)"
        else:
            verdict = "CHANGED"
            failed += 1
        print(f"{name:34s} {verdict}")
    print(f"{len(current) - failed} of {len(current)} cases unchanged")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
