"""Shadow cost per light and map size, and the error against the ray-traced truth
(benchmarks/studies/shadows.py); `--write` puts the section into REPORT.md in place of the old
one. `--no-shadow-cost N` instead prints the fastest of N frames of the scene with a point light
and no shadows (run it under this checkout's and another's interpreter, alternately, to compare).

    .venv/bin/python benchmarks/bench_shadows.py [--frames 7] [--write]
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

import repo_path  # noqa: F401

from benchmarks.studies.shadows import LIGHTS, shadows_section
from sphrender.core.frame import ParticleFrame
from sphrender.server.bench.shadow_scene import BallOverPlate
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

REPORT = Path(__file__).resolve().parent / "REPORT.md"


def replace_section(text: str, section: list[str]) -> str:
    """`text` with its "## Shadows" section (up to the next "## ") replaced, or appended."""
    body = "\n".join(section)
    pattern = re.compile(r"^## Shadows\n.*?(?=^## |\Z)", re.S | re.M)
    if pattern.search(text):
        return pattern.sub(lambda _: body + "\n", text)
    return text.rstrip("\n") + "\n\n" + body + "\n"


def no_shadow_min_ms(renderer: SurfaceRenderer, setup: BallOverPlate, frames: int) -> float:
    """The fastest of `frames` frames under a point light without shadows: on a shared machine
    the minimum is what the load disturbs least."""
    frame, scene = ParticleFrame(setup.positions()), setup.scene([LIGHTS["point"]])
    renderer.render(frame, scene)
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        renderer.render(frame, scene)
        times.append((time.perf_counter() - start) * 1e3)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--frames", type=int, default=7)
    parser.add_argument("--write", action="store_true", help="update REPORT.md")
    parser.add_argument("--no-shadow-cost", type=int, default=0, metavar="FRAMES")
    args = parser.parse_args()
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            if args.no_shadow_cost:
                setup = BallOverPlate(radius=0.025, size=320)
                print(f"{no_shadow_min_ms(renderer, setup, args.no_shadow_cost):.2f}")
                return
            section = shadows_section(renderer, max(1, args.frames))
        finally:
            renderer.release()
    print("\n".join(section))
    if args.write:
        REPORT.write_text(replace_section(REPORT.read_text(), section))


if __name__ == "__main__":
    main()
