"""The flicker under both readings of issue 12's jitter (a Gaussian of 2 % r per axis, the
bench's; every particle moved by exactly 2 % r), for any settings, on the spatter and the
dam-break frame (benchmarks/bench_report.py writes them for plain smoothing and balanced into
REPORT.md; benchmarks/studies/jitter_readings.py measures).

The dam break needs ../shared/data and pysplashsurf (or benchmarks/.reference-cache). Run:
    .venv/bin/python benchmarks/bench_jitter_readings.py [--width 960 --height 540]
        [--setting balanced best ...]
"""

from __future__ import annotations

import argparse

import repo_path  # noqa: F401
from bench_dambreak_frames import CACHE, SETTINGS

from benchmarks.studies.jitter_readings import jitter_readings_section, run_jitter_readings
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--height", type=int, default=540)
    parser.add_argument(
        "--setting", nargs="*", choices=list(SETTINGS), default=["pre-issue", "balanced"]
    )
    args = parser.parse_args()
    settings = [SETTINGS[name] for name in args.setting]
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            rows = run_jitter_readings(
                gl, renderer, settings, width=args.width, height=args.height, cache=CACHE
            )
        finally:
            renderer.release()
    print("\n".join(["", *jitter_readings_section(rows)]))


if __name__ == "__main__":
    main()
