"""The normal guide's frame time against balanced's, interleaved as benchmarks/bench_frame_ratio.py
does (the bench's jittered-lattice ball, ~100k particles, 1280x720, one frame per setting per
cycle, wall time of `SurfaceRenderer.render`): balanced, balanced + the guide
(benchmarks/studies/crease_2d.py's `guide`), and the guide as one-sided limits
(`normal_guide_limits`, with and without `normal_guide_limits_skip`, at half and quarter size:
`normal_guide_downscale`, and with `normal_guide_convex_relative`).

    .venv/bin/python benchmarks/studies/guide_frame_ratio.py [--cycles 10]

STUDIES.md "The normal guide as per-pixel one-sided limits" has the results.
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
from studies.crease_2d import GUIDE, GUIDE_LIMITS_QUARTER

LIMITS_HALF = {
    **GUIDE,
    "normal_guide_limits": True,
    "normal_guide_limits_skip": True,
    "normal_guide_downscale": 2,
}
SETTINGS = {
    "balanced": scene_for("balanced", {}),
    "balanced + guide": scene_for("balanced", {"quality": GUIDE}),
    "guide, limits": scene_for("balanced", {"quality": {**GUIDE, "normal_guide_limits": True}}),
    "guide, limits, skip": scene_for(
        "balanced",
        {"quality": {**GUIDE, "normal_guide_limits": True, "normal_guide_limits_skip": True}},
    ),
    "guide, limits, skip, half": scene_for("balanced", {"quality": LIMITS_HALF}),
    "guide, ..., half, relative": scene_for(
        "balanced", {"quality": {**LIMITS_HALF, "normal_guide_convex_relative": True}}
    ),
    "guide, limits, skip, quarter": scene_for(
        "balanced", {"quality": {**LIMITS_HALF, "normal_guide_downscale": 4}}
    ),
    "guide, ..., quarter, relative": scene_for("balanced", {"quality": GUIDE_LIMITS_QUARTER}),
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
    print_ratios(times, "balanced", width=30)


if __name__ == "__main__":
    main()
