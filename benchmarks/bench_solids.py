"""Solid workpieces: the plate and the bevel joint against their analytic truth at 960x540 for
every preset, flagged solid and as fluid (today's path); the costs at 1280x720 side by side in
one run (a frame without solids against the renderer with the solid split bypassed, ~100k
particles flagged solid against the same as fluid, the first frame's surfel build, builds after
it); before / after crops into benchmarks/crops/. Prints the REPORT.md section
(`sphrender bench` writes the same section in a full run).

    .venv/bin/python benchmarks/bench_solids.py [--frames 3] [--out benchmarks]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import repo_path  # noqa: F401

from sphrender.server.bench.scenes import ball_scene
from sphrender.server.bench.solid_bench import (
    run_solid_bench,
    run_solid_costs,
    solid_section,
    today_renderer,
    write_solid_crops,
)
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

OUT = Path(__file__).resolve().parent


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--frames", type=int, default=3, help="timed frames per setting")
    parser.add_argument("--out", type=Path, default=OUT, help="folder for crops/")
    parser.add_argument("--costs-only", action="store_true", help="only the costs")
    args = parser.parse_args()
    rows, crops = [], []
    with GLContext() as gl:
        renderer, today = SurfaceRenderer(gl), today_renderer(gl)
        try:
            if not args.costs_only:
                rows = run_solid_bench(renderer, width=960, height=540, frames=max(1, args.frames))
                crops = write_solid_crops(renderer, args.out)
            costs = run_solid_costs(
                renderer, today, frames=max(3, 2 * args.frames), fluid=ball_scene(90_000)
            )
        finally:
            today.release()
            renderer.release()
    print("\n".join(solid_section(rows, costs, (960, 540), crops)))


if __name__ == "__main__":
    main()
