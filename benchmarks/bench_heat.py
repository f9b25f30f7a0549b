"""Cost of the heat tint, molten metal and peak temperatures, side by side.

Not a test. Run:  .venv/bin/python benchmarks/bench_heat.py [--cycles 15] [--only-off]
                  [--json out.json] [--today-shaders DIR]

Renders the bench's jittered-lattice ball (~100k particles, 640x360, balanced preset, iron under
the workshop environment and a sun) carrying temperatures (a gradient from 300 K to 2000 K
across the ball, the top above the liquidus), one frame per setting per cycle, all in one
process on one renderer (the settings share this machine's drift). Settings: tint and molten off
(what a scene with temperatures renders today), heat_tint on (peak = current), heat_tint +
molten, and heat_tint with the frame's own peak_temperatures (the RG32F kelvin path and the
second blur). Prints per setting the median frame time and the median of the per-cycle ratios
to "off", as wall time and as the process's CPU time (every thread: llvmpipe's rasterisers are
in the process), which on a shared, oversubscribed machine tracks the work far more steadily.
`--only-off` renders only "off" (runs on a checkout without these fields). `--report` writes
REPORT.md's heat section instead (benchmarks/studies/heat_report.py: cost, error, demo crop).
`--today-shaders DIR` (the `shaders/` folder of a checkout from before these features, e.g.
`git archive main shaders | tar -x -C /tmp/main`) adds "today": a renderer whose GL programs
are built from those files (the define names this code sets declared there as no-ops), so the
GL half of "off" is compared with today's in the same process, frame by frame.
"""

from __future__ import annotations

import argparse
import importlib.resources
import json
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import repo_path  # noqa: F401

from sphrender.core.frame import make_frame
from sphrender.server.bench.sweep import bench_scene_from_dict
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.shader_loader import ShaderLoader
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


#: Define names this code passes that today's shaders do not declare (declared there as 0).
_NEW_DEFINES = {
    "shade/shade_pbr.frag.glsl": ("HEAT_TINT", "MOLTEN"),
    "splat/splat_ellipsoid.frag.glsl": ("HAS_PEAK",),
    "splat/splat_sphere.frag.glsl": ("HAS_PEAK",),
    "common/image_pack.frag.glsl": ("CHANNEL",),
}


def todays_shaders(today: Path, into: Path) -> Path:
    """This code's shader folder with every file `today` has replaced by today's version."""
    shutil.copytree(Path(str(importlib.resources.files("sphrender.shaders"))), into)
    for source in today.rglob("*.glsl"):
        shutil.copy(source, into / source.relative_to(today))
    for name, defines in _NEW_DEFINES.items():
        first, rest = (into / name).read_text().split("\n", 1)
        declared = "".join(f"#define {d} 0\n" for d in defines if f"#define {d} " not in rest)
        (into / name).write_text(f"{first}\n{declared}{rest}")
    return into


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=15)
    parser.add_argument("--only-off", action="store_true")
    parser.add_argument("--json", help="write the per-setting frame times (ms) here")
    parser.add_argument("--today-shaders", type=Path, help="shaders/ from before these features")
    parser.add_argument("--report", action="store_true", help="write REPORT.md's heat section")
    args = parser.parse_args()
    if args.report:
        write_report(args.cycles)
        return
    positions = jittered_lattice_ball(0.58, 0.01, seed=0)
    height = (positions[:, 1] - positions[:, 1].min()) / np.ptp(positions[:, 1])
    kelvin = 300.0 + 1700.0 * height
    plain = make_frame(positions, temperatures=kelvin)
    chosen = settings(args.only_off)
    peaks = plain
    if not args.only_off:
        peaks = make_frame(positions, temperatures=kelvin, peak_temperatures=kelvin + 150.0)
    times: dict[str, list[float]] = {name: [] for name in chosen}
    scratch = tempfile.TemporaryDirectory()
    if args.today_shaders is not None:
        chosen = {"today": (chosen["off (today's path)"][0], False), **chosen}
        times = {"today": [], **times}
    cpu_times: dict[str, list[float]] = {name: [] for name in times}
    with GLContext() as gl:
        # Frames with peaks use an RG32F kelvin target: their own renderer, so that alternating
        # settings do not rebuild targets every frame (a session's frames carry peaks or not).
        renderers = {False: SurfaceRenderer(gl), True: SurfaceRenderer(gl)}
        if args.today_shaders is not None:
            today = SurfaceRenderer(gl)
            root = todays_shaders(args.today_shaders, Path(scratch.name) / "shaders")
            today._context.programs._loader = ShaderLoader(root)  # bench only
        try:
            for name, (scene, with_peaks) in chosen.items():  # warm-up: programs, targets
                pick = today if name == "today" else renderers[with_peaks]
                pick.render(peaks if with_peaks else plain, scene)
            for _ in range(args.cycles):
                for name, (scene, with_peaks) in chosen.items():
                    pick = today if name == "today" else renderers[with_peaks]
                    start, cpu = time.perf_counter(), time.process_time()
                    pick.render(peaks if with_peaks else plain, scene)
                    times[name].append((time.perf_counter() - start) * 1e3)
                    cpu_times[name].append((time.process_time() - cpu) * 1e3)
        finally:
            for renderer in renderers.values():
                renderer.release()
            if args.today_shaders is not None:
                today.release()
    scratch.cleanup()
    for label, table in (("wall", times), ("cpu", cpu_times)):
        base = table["off (today's path)"]
        for name, samples in table.items():
            ratios = [t / b for t, b in zip(samples, base, strict=True)]
            print(
                f"{label} {name:24s} median {statistics.median(samples):8.1f} ms"
                f"   x{statistics.median(ratios):.3f} of off (median per-cycle ratio)"
            )
    if args.json:
        with open(args.json, "w") as handle:
            json.dump({"wall": times, "cpu": cpu_times}, handle)


def write_report(cycles: int) -> None:
    from benchmarks.studies import heat_report

    report = Path(__file__).resolve().parent / "REPORT.md"
    with GLContext() as gl:
        lines = heat_report.section(heat_report.measure(gl, cycles))
        renderer = SurfaceRenderer(gl)
        try:
            heat_report.write_demo_crop(renderer, report.parent)
        finally:
            renderer.release()
    print("\n".join(lines))
    report.write_text(heat_report.splice(report.read_text(), lines))


if __name__ == "__main__":
    main()
