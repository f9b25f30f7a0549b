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
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_frame_ratio import scene_for

from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

GUIDE = {
    "normal_guide": 8.0,
    "normal_guide_width": 12.0,
    "normal_guide_pilot": 1.7,
    "normal_guide_turn": 11.0,
    "normal_guide_convex": 8.0,
    "normal_guide_rim": 3.0,
    "normal_guide_flat": 1.25,
    "normal_guide_flat_angle": 25.0,
}
LIMITS_HALF = {
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
    "guide, limits, skip, half": scene_for(
        "balanced",
        {"quality": {**GUIDE, **LIMITS_HALF}},
    ),
    "guide, ..., half, relative": scene_for(
        "balanced",
        {"quality": {**GUIDE, **LIMITS_HALF, "normal_guide_convex_relative": True}},
    ),
    "guide, limits, skip, quarter": scene_for(
        "balanced",
        {"quality": {**GUIDE, **LIMITS_HALF, "normal_guide_downscale": 4}},
    ),
    "guide, ..., quarter, relative": scene_for(
        "balanced",
        {
            "quality": {
                **GUIDE,
                **LIMITS_HALF,
                "normal_guide_downscale": 4,
                "normal_guide_convex_relative": True,
            }
        },
    ),
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
            for scene in SETTINGS.values():  # warm-up: programs, targets, IBL caches
                renderer.render(frame, scene)
                renderer.render(frame, scene)
            times: dict[str, list[float]] = {name: [] for name in SETTINGS}
            for _ in range(args.cycles):
                for name, scene in SETTINGS.items():
                    start = time.perf_counter()
                    renderer.render(frame, scene)
                    times[name].append((time.perf_counter() - start) * 1e3)
        finally:
            renderer.release()
    base = times["balanced"]
    print(f"{gl.renderer}; {frame.count} particles, 1280x720, {args.cycles} cycles")
    for name, values in times.items():
        per_cycle = statistics.median(a / b for a, b in zip(values, base, strict=True))
        print(
            f"{name:30} median {statistics.median(values):7.1f} ms  ratio of medians "
            f"{statistics.median(values) / statistics.median(base):.3f}  median per-cycle "
            f"ratio {per_cycle:.3f}"
        )


if __name__ == "__main__":
    main()
