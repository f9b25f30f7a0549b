"""Engine benchmark: stage times and normal error per filter setting on a ~100k-particle ball.

Not a test. Run:  .venv/bin/python benchmarks/bench_engine.py [--width 1280 --height 720]

For each quality setting it renders the same jittered-lattice ball several times in one process
(one GL context), reports the median per stage and in total, the normal error against the analytic
sphere (mean / p95 degrees over pixels with n.v >= 0.3) and silhouette IoU, and the time ratio
against the unfiltered render measured in the same run.
"""

from __future__ import annotations

import argparse
import statistics
from dataclasses import replace
from typing import Any

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.bench.analytic import ball_errors
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import QualityConfig, scene_from_dict

SETTINGS: list[tuple[str, dict[str, Any]]] = [
    ("none", {"filter": "none"}),
    ("narrow_range (default)", {}),
    ("narrow_range 1 iter", {"iterations": 1}),
    ("narrow_range k=3 1 iter", {"iterations": 1, "kernel_scale": 3.0}),
    ("narrow_range 2-D", {"separable": False}),
    ("bilateral", {"filter": "bilateral"}),
    ("bilateral 2-D", {"filter": "bilateral", "separable": False}),
    ("gaussian", {"filter": "gaussian"}),
    ("gaussian 2-D 1 iter", {"filter": "gaussian", "separable": False, "iterations": 1}),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--height", type=int, default=720)
    parser.add_argument("--frames", type=int, default=5, help="timed frames per setting")
    parser.add_argument("--ball-radius", type=float, default=0.58, help="0.58 -> ~100k particles")
    args = parser.parse_args()

    r = 0.01
    positions = jittered_lattice_ball(args.ball_radius, r)
    frame = make_frame(positions)
    base = scene_from_dict(
        {
            "image": {"width": args.width, "height": args.height},
            "camera": {"eye": [1.3, 1.0, 1.7], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
            "particles": {"radius": r},
        }
    )
    camera = Camera.from_config(base.camera, args.width, args.height)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        print(f"{gl.renderer}; {frame.count} particles; {args.width}x{args.height}")
        header = (
            f"{'setting':26} {'prepare':>8} {'splat':>8} {'smooth':>8} {'normals':>8} "
            f"{'shade':>7} {'readback':>8} {'total':>8} {'x none':>7} "
            f"{'mean°':>6} {'p95°':>6} {'IoU':>6}"
        )
        print(header)
        baseline = None
        for name, overrides in SETTINGS:
            scene = replace(base, quality=replace(QualityConfig(), **overrides))
            renderer.render(frame, scene, depth=True, normals=True)  # warm-up: compile, allocate
            stage_runs: dict[str, list[float]] = {}
            totals = []
            for _ in range(args.frames):
                rendered, stats = renderer.render(frame, scene, depth=True, normals=True)
                for stage, ms in stats.stage_ms.items():
                    stage_runs.setdefault(stage, []).append(ms)
                totals.append(stats.total_ms)
            medians = {k: statistics.median(v) for k, v in stage_runs.items()}
            total = statistics.median(totals)
            baseline = baseline or total
            errors = ball_errors(rendered, camera, np.zeros(3), args.ball_radius + r)
            cells = " ".join(
                f"{medians.get(stage, 0.0):8.1f}"
                for stage in ("prepare", "splat", "smooth", "normals")
            )
            print(
                f"{name:26} {cells} {medians.get('shade', 0.0):7.1f} "
                f"{medians.get('readback', 0.0):8.1f} {total:8.1f} {total / baseline:7.2f} "
                f"{errors.mean_deg:6.2f} {errors.p95_deg:6.2f} {errors.silhouette_iou:6.3f}"
            )
        renderer.release()


if __name__ == "__main__":
    main()
