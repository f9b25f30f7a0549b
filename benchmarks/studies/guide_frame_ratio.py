"""The normal guide's frame time, interleaved as benchmarks/bench_frame_ratio.py does (the
bench's jittered-lattice ball, ~100k particles, 1280x720, one frame per setting per cycle, wall
time of `SurfaceRenderer.render`): balanced without the guide (the default before it) and
balanced (the guide as per-pixel limits at a quarter of the image), as a ratio to the first.

    .venv/bin/python benchmarks/studies/guide_frame_ratio.py [--cycles 10]

STUDIES.md "Adopted: the quarter-size limits in balanced and best" has the results.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_frame_ratio import interleaved_ms, print_ratios, scene_for

from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

SETTINGS = {
    "balanced, no guide": scene_for("balanced", {"quality": {"normal_guide": 0.0}}),
    "balanced": scene_for("balanced", {}),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--cycles", type=int, default=10)
    args = parser.parse_args()
    positions = jittered_lattice_ball(0.58, 0.01, seed=0)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            frame = make_frame(positions)
            times = interleaved_ms(renderer, frame, SETTINGS, args.cycles)
        finally:
            renderer.release()
    print(f"{gl.renderer}; {frame.count} particles, 1280x720, {args.cycles} cycles")
    print_ratios(times, "balanced, no guide", width=30)


if __name__ == "__main__":
    main()
