"""Shading cost per IBL mode and sample count, against its error versus brute force.

Not run by CI. Prints, on this machine's GL driver:
* one-time costs per environment: SH projection, source mips, prefiltered chain; BRDF table;
* per frame: the shade stage (ms) on a particle ball filling most of a WIDTH x HEIGHT image,
  for ibl_mode none / prefiltered / sampled with N = 16 ... 1024, with its ratio to prefiltered;
* the specular IBL error of each mode against a brute-force Monte Carlo reference (2^15 GGX
  samples per pixel, float64) on 64 exact-sphere pixels with n.v in [0.3, 1], copper at
  roughness 0.2 and 0.5, in a smooth coloured test environment (tests/test_shading_ibl.py).

Usage: python benchmarks/bench_shading.py [--width 1280 --height 720 --frames 5]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))  # the numpy references live with the tests

import test_shading_ibl as ibl_tests  # noqa: E402

from sphrender.core.frame import make_frame  # noqa: E402
from sphrender.server.content.lattice import jittered_lattice_ball  # noqa: E402
from sphrender.server.engine.gpu.gl_context import GLContext  # noqa: E402
from sphrender.server.engine.lighting.environment import preset_image  # noqa: E402
from sphrender.server.engine.lighting.ibl import sh9_coefficients  # noqa: E402
from sphrender.server.engine.renderer import SurfaceRenderer  # noqa: E402
from sphrender.server.scene import scene_from_dict  # noqa: E402

MODES: list[tuple[str, int]] = [
    ("none", 0),
    ("prefiltered", 0),
    ("sampled", 16),
    ("sampled", 64),
    ("sampled", 256),
    ("sampled", 1024),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--frames", type=int, default=5)
    args = parser.parse_args()

    env_dir = Path(__import__("tempfile").mkdtemp(prefix="sphrender-bench-"))
    ibl_tests.write_exr(env_dir / "smooth.exr", ibl_tests.smooth_test_environment().pixels)
    positions = jittered_lattice_ball(0.5, 0.01, seed=0)
    frame = make_frame(positions)

    with GLContext() as gl:
        print(f"GL renderer: {gl.renderer}")
        renderer = SurfaceRenderer(gl, environment_dirs=[env_dir])
        try:
            # One-time costs.
            workshop = preset_image("workshop")
            start = time.perf_counter()
            sh9_coefficients(workshop.pixels)
            sh_ms = (time.perf_counter() - start) * 1e3
            ibl = renderer.shade_pass.ibl
            start = time.perf_counter()
            entry = ibl.environment(workshop)
            gl.ctx.finish()
            upload_ms = (time.perf_counter() - start) * 1e3
            print(
                f"workshop {workshop.width}x{workshop.height}: SH9 {sh_ms:.0f} ms; "
                f"upload + mips + SH {upload_ms:.0f} ms"
            )
            for samples in (128, 512, 2048):
                start = time.perf_counter()
                ibl.prefiltered(entry, samples)
                gl.ctx.finish()
                print(
                    f"  prefiltered chain, {samples} samples/texel: "
                    f"{(time.perf_counter() - start) * 1e3:.0f} ms"
                )
            for g_term in ("smith_height_correlated", "cook_torrance"):
                start = time.perf_counter()
                ibl.brdf_lut(g_term)
                gl.ctx.finish()
                print(f"  BRDF table ({g_term}): {(time.perf_counter() - start) * 1e3:.0f} ms")

            # Errors against brute force (specular term only).
            errors: dict[tuple[str, int, float], tuple[float, float]] = {}
            for roughness in (0.2, 0.5):
                normals, _, want = ibl_tests.specular_case(roughness)
                for mode, samples in MODES[1:]:
                    scene = ibl_tests.grid_scene(
                        material={"preset": "copper", "roughness": roughness},
                        environment={"file": "smooth.exr"},
                        shading={
                            "ibl_mode": mode,
                            "ibl_samples": max(samples, 1),
                            "debug_view": "specular_ibl",
                        },
                    )
                    got = ibl_tests.shade_normals(renderer, scene, normals)
                    relative = np.abs(got - want) / want
                    errors[mode, samples, roughness] = (
                        float(relative.mean()),
                        float(relative.max()),
                    )

            # Frame times.
            print(
                f"\nshade stage, {args.width}x{args.height}, {len(positions)} particles, "
                f"median of {args.frames} frames after a warm-up"
            )
            header = (
                "mode            shade ms  x prefiltered   err r=0.2 mean/max   err r=0.5 mean/max"
            )
            print(header)
            base_ms = None
            rows = []
            for mode, samples in MODES:
                scene = scene_from_dict(
                    {
                        "image": {"width": args.width, "height": args.height},
                        "camera": {"eye": [0.0, 0.4, 1.6], "fov_y": 40.0},
                        "particles": {"radius": 0.01},
                        "material": {"preset": "copper", "roughness": 0.35},
                        "lights": [{"direction": [-1.0, -1.0, -1.0], "intensity": 2.0}],
                        "shading": {"ibl_mode": mode, "ibl_samples": max(samples, 1)},
                    }
                )
                for _ in range(2):  # warm-up: programs, prefiltering, driver shader variants
                    renderer.render(frame, scene)
                times = [
                    renderer.render(frame, scene)[1].stage_ms["shade"] for _ in range(args.frames)
                ]
                shade_ms = float(np.median(times))
                if mode == "prefiltered":
                    base_ms = shade_ms
                rows.append((mode, samples, shade_ms))
            for mode, samples, shade_ms in rows:
                label = f"{mode}" + (f" N={samples}" if samples else "")
                ratio = f"{shade_ms / base_ms:6.2f}" if base_ms else "   -  "
                cells = []
                for roughness in (0.2, 0.5):
                    if (mode, samples, roughness) in errors:
                        mean, worst = errors[mode, samples, roughness]
                        cells.append(f"{mean * 100:6.2f}% / {worst * 100:6.2f}%")
                    else:
                        cells.append(" " * 17)
                print(f"{label:<15} {shade_ms:8.1f}  {ratio:>13}   {cells[0]:>19}   {cells[1]:>19}")
        finally:
            renderer.release()


if __name__ == "__main__":
    main()
