"""Cost of the heat tint, molten metal and peak temperatures, side by side.

Not a test. Run:  .venv/bin/python benchmarks/bench_heat.py [--cycles 15] [--only-off]
                  [--json out.json]

Renders the bench's jittered-lattice ball (~100k particles, 640x360, balanced preset, iron under
the workshop environment and a sun) carrying temperatures (a gradient from 300 K to 2000 K
across the ball, the top above the liquidus), one frame per setting per cycle, all in one
process on one renderer (the settings share this machine's drift). Settings: tint and molten off
(what a scene with temperatures renders today), heat_tint on (peak = current), heat_tint +
molten, and heat_tint with the frame's own peak_temperatures (the RG32F kelvin path and the
second blur). Prints per setting the median frame time and the median of the per-cycle ratios
to "off". `--only-off` renders only "off" (runs on a checkout without these fields, so "off" on
this branch and on main can be compared by alternating the two processes).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from typing import Any

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.bench.sweep import bench_scene_from_dict
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, merge_scene_dicts
from sphrender.server.scene.presets import preset_sections

VIEW: dict[str, Any] = {
    "image": {"width": 640, "height": 360},
    "camera": {"eye": [1.3, 1.0, 1.7], "fov_y": 40.0},
    "particles": {"radius": 0.01},
    "environment": {"preset": "workshop"},
    "lights": [{"direction": [-0.3, -1.0, -0.4], "intensity": 2.0}],
}


def scene_for(material: dict[str, Any]) -> Scene:
    sections = {**VIEW, "material": {"preset": "iron", **material}}
    return bench_scene_from_dict(merge_scene_dicts(preset_sections("balanced"), sections))


def settings(only_off: bool) -> dict[str, tuple[Scene, bool]]:
    """name -> (scene, whether the frame carries peak_temperatures)."""
    off = {"off (today's path)": (scene_for({}), False)}
    if only_off:
        return off
    return {
        **off,
        "heat_tint": (scene_for({"heat_tint": True}), False),
        "heat_tint + molten": (scene_for({"heat_tint": True, "molten": True}), False),
        "heat_tint + peaks": (scene_for({"heat_tint": True}), True),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=15)
    parser.add_argument("--only-off", action="store_true")
    parser.add_argument("--json", help="write the per-setting frame times (ms) here")
    args = parser.parse_args()
    positions = jittered_lattice_ball(0.58, 0.01, seed=0)
    height = (positions[:, 1] - positions[:, 1].min()) / np.ptp(positions[:, 1])
    kelvin = 300.0 + 1700.0 * height
    plain = make_frame(positions, temperatures=kelvin)
    chosen = settings(args.only_off)
    peaks = plain
    if not args.only_off:
        peaks = make_frame(positions, temperatures=kelvin, peak_temperatures=kelvin + 150.0)
    times: dict[str, list[float]] = {name: [] for name in chosen}
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            for scene, with_peaks in chosen.values():  # warm-up: programs, targets, tables
                renderer.render(peaks if with_peaks else plain, scene)
            for _ in range(args.cycles):
                for name, (scene, with_peaks) in chosen.items():
                    start = time.perf_counter()
                    renderer.render(peaks if with_peaks else plain, scene)
                    times[name].append((time.perf_counter() - start) * 1e3)
        finally:
            renderer.release()
    base = times["off (today's path)"]
    for name, samples in times.items():
        ratios = [t / b for t, b in zip(samples, base, strict=True)]
        print(
            f"{name:24s} median {statistics.median(samples):8.1f} ms"
            f"   x{statistics.median(ratios):.3f} of off (median per-cycle ratio)"
        )
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(times, handle)


if __name__ == "__main__":
    main()
