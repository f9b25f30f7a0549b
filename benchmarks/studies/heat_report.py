"""REPORT.md's section on the weld's heat: what the heat tint, molten metal and peak temperatures
cost (benchmarks/bench_heat.py's settings, one renderer per kelvin layout, frames interleaved),
where their error is measured, and the demo's crop. `benchmarks/bench_heat.py --report` writes
it into REPORT.md alone; `bench_report.py` with the rest."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from benchmarks.bench_heat import settings
from sphrender.core.frame import make_frame
from sphrender.server.content.demo import demo_frame, demo_scene
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.encoders import encode_png
from sphrender.server.output.local import render_for_output

HEADING = "## The weld's heat: heat tint, molten metal, the demo"
#: The demo's crop (x0, y0, x1, y1 of the 960x540 image): the pool, the bead, the spatter.
DEMO_CROP = (430, 100, 910, 370)


def measure(
    gl: GLContext, cycles: int = 7, log: Callable[[str], None] = print
) -> dict[str, tuple[float, float]]:
    """Setting -> (median frame ms, median per-cycle ratio to "off"), 100k ball at 640x360."""
    positions = jittered_lattice_ball(0.58, 0.01, seed=0)
    height = (positions[:, 1] - positions[:, 1].min()) / np.ptp(positions[:, 1])
    kelvin = 300.0 + 1700.0 * height
    frames = {
        False: make_frame(positions, temperatures=kelvin),
        True: make_frame(positions, temperatures=kelvin, peak_temperatures=kelvin + 150.0),
    }
    chosen = settings(only_off=False)
    times: dict[str, list[float]] = {name: [] for name in chosen}
    renderers = {False: SurfaceRenderer(gl), True: SurfaceRenderer(gl)}
    try:
        for scene, with_peaks in chosen.values():  # warm-up: programs, targets
            renderers[with_peaks].render(frames[with_peaks], scene)
        for cycle in range(cycles):
            log(f"heat tint: cycle {cycle + 1} of {cycles}")
            for name, (scene, with_peaks) in chosen.items():
                start = time.perf_counter()
                renderers[with_peaks].render(frames[with_peaks], scene)
                times[name].append((time.perf_counter() - start) * 1e3)
    finally:
        for renderer in renderers.values():
            renderer.release()
    base = times["off (today's path)"]
    return {
        name: (
            statistics.median(samples),
            statistics.median(t / b for t, b in zip(samples, base, strict=True)),
        )
        for name, samples in times.items()
    }


def write_demo_crop(renderer: SurfaceRenderer, out: Path) -> Path:
    """The demo rendered now as `sphrender demo` writes it, cropped to the pool and the bead."""
    rendered, _ = render_for_output(renderer, demo_frame(), demo_scene(), "png")
    whole = out / "crops" / "demo-weld-whole.png"
    whole.write_bytes(encode_png(rendered))
    x0, y0, x1, y1 = DEMO_CROP
    pixels = np.asarray(oiio.ImageBuf(str(whole)).get_pixels(oiio.UINT8))[y0:y1, x0:x1, :3]
    whole.unlink()
    path = out / "crops" / "crop-demo-weld-after.png"
    crop = oiio.ImageBuf(oiio.ImageSpec(x1 - x0, y1 - y0, 3, oiio.UINT8))
    crop.set_pixels(oiio.ROI(), np.ascontiguousarray(pixels))
    crop.write(str(path))
    return path


def section(costs: dict[str, tuple[float, float]]) -> list[str]:
    lines = [
        HEADING,
        "",
        "Cost: the bench's jittered-lattice ball (~100k particles, 640x360, balanced, iron, a sun)",
        "carrying temperatures from 300 K to 2000 K, every setting rendered once per cycle in one",
        "process (`benchmarks/bench_heat.py` does the same with CPU times and today's shaders).",
        "",
        "| setting | frame ms (median) | x off (median per-cycle ratio) |",
        "|---|---|---|",
    ]
    lines += [f"| {name} | {ms:.1f} | {ratio:.3f} |" for name, (ms, ratio) in costs.items()]
    return [
        *lines,
        "",
        "Error: the film table against an independent numpy Airy reference",
        "(tests/test_heat_tint.py: within 1e-3 at every thickness and angle it checks). Against",
        "Blender Cycles 5.0.1 (`benchmarks/bench_cycles_thin_film.py`, bpy in a venv of its",
        "own; flat plate, 0-150 nm, both steels, film k 0, no spread) on our metal's n + ik:",
        "Metallic BSDF ΔE2000 ≤ 2.37 head-on, ≤ 2.19 at 60°; Principled BSDF with Specular",
        "Tint F0 / Schlick(82°) (its film then sits on the same n + ik) ≤ 2.37 head-on, ≤ 4.66",
        "at 60° (12 of 14 ≤ 3: its F82 film/metal interface at the 40 nm minimum); with",
        "Specular Tint white ≤ 24.6 (another metal under the film). A numpy of Cycles' rule",
        "(its metal, interface, Airy series cut at m = 3) is within 0.43 of each filmed plate:",
        'STUDIES.md, "Heat tint against Blender Cycles". The demo before the',
        "weld features and now: [before](crops/crop-demo-weld-before.png),",
        "[after](crops/crop-demo-weld-after.png).",
        "",
    ]


def splice(report: str, lines: list[str]) -> str:
    """`report` with this section replaced by `lines` (or inserted before the scaling table)."""
    text = "\n".join(lines).rstrip("\n") + "\n\n"
    if HEADING in report:
        head, rest = report.split(HEADING, 1)
        tail = rest.split("\n## ", 1)
        return head + text + ("## " + tail[1] if len(tail) == 2 else "")
    before = "## Scaling"
    if before in report:
        head, rest = report.split(before, 1)
        return head + text + before + rest
    return report.rstrip("\n") + "\n\n" + text
