"""Degenerate-geometry benchmark: render time of each degenerate shape (tests/fuzz_inputs.py's
DEGENERATE_SHAPES) against a random ball of the same particle count, and the time of a frame of
2M coincident particles.

Not a test. Run:  .venv/bin/python benchmarks/bench_degenerate.py [--count 80000] [--large 2000000]

Every frame renders in one process (one GL and one CL context) at the service tests' small
scene; each time is the median of `--frames` renders after a warm-up. The ratios (shape / ball)
are what to compare across machines; a stage that turns quadratic on one shape shows as a ratio
that grows with `--count`.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from fuzz_inputs import DEGENERATE_SHAPES

SCENE: dict[str, Any] = {
    "image": {"width": 64, "height": 48},
    "camera": {"eye": [0.6, 0.5, 0.9], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
    "particles": {"radius": 0.02},
}
#: [sph] settings timed besides the plain render (each runs the SPH stage's kernels).
SPH_VARIANTS: dict[str, dict[str, Any]] = {
    "plain": {},
    "adaptive_radius": {"adaptive_radius": True},
    "anisotropy": {"anisotropy": True},
}


def ball(rng: np.random.Generator, n: int) -> np.ndarray:
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    return np.asarray(direction * 0.3 * rng.random((n, 1)) ** (1.0 / 3.0))


def timed(renderer: SurfaceRenderer, positions: np.ndarray, scene: Scene, frames: int) -> float:
    """Median seconds of `frames` renders of `positions`, after one warm-up."""
    frame = make_frame(positions)
    renderer.render(frame, scene)
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        renderer.render(frame, scene)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--count", type=int, default=80_000, help="particles per shape")
    parser.add_argument("--large", type=int, default=2_000_000, help="coincident particles")
    parser.add_argument("--frames", type=int, default=3, help="timed renders per case")
    args = parser.parse_args()
    rng = np.random.default_rng(1)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        print(f"{gl.renderer}; {args.count} particles; 64x48")
        print(f"{'sph':16} {'shape':16} {'ms':>9} {'x ball':>7}")
        for variant, sph in SPH_VARIANTS.items():
            scene = scene_from_dict({**SCENE, "sph": sph})
            reference = timed(renderer, ball(rng, args.count), scene, args.frames)
            print(f"{variant:16} {'ball':16} {reference * 1e3:9.1f} {1.0:7.2f}", flush=True)
            for name, make in DEGENERATE_SHAPES.items():
                seconds = timed(renderer, make(rng, args.count), scene, args.frames)
                ratio = seconds / reference
                print(f"{variant:16} {name:16} {seconds * 1e3:9.1f} {ratio:7.2f}", flush=True)
        scene = scene_from_dict(SCENE)
        frame = make_frame(np.zeros((args.large, 3)))
        start = time.perf_counter()
        _, stats = renderer.render(frame, scene)
        seconds = time.perf_counter() - start
        stages = ", ".join(f"{k} {v:.0f}" for k, v in stats.stage_ms.items())
        print(f"{args.large} coincident: {seconds:.2f} s ({stages} ms)")
        renderer.release()


if __name__ == "__main__":
    main()
