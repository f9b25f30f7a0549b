"""The dam break's surface figures on every frame of the data set, for any settings
(benchmarks/bench_report.py writes them for plain smoothing and balanced into REPORT.md;
benchmarks/studies/dam_frames.py measures). Does what was chosen on frame 5 hold on the others?

Not a test (it needs ../shared/data and pysplashsurf). Run:
    .venv/bin/python benchmarks/bench_dambreak_frames.py [--width 960 --height 540]
        [--frames 1 5 9] [--setting balanced best ...]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import repo_path  # noqa: F401

from benchmarks.studies.dam_frames import (
    band_ratios,
    dam_frame_paths,
    dam_frames_section,
    run_dam_frames,
)
from sphrender.server.bench.surface_bench import PLAIN_SMOOTHING, UNFILTERED
from sphrender.server.bench.sweep import preset_setting
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

CACHE = Path(__file__).parent / ".reference-cache"
SETTINGS = {
    "unfiltered": UNFILTERED,
    "pre-issue": PLAIN_SMOOTHING,
    "fast": preset_setting("fast"),
    "balanced": preset_setting("balanced"),
    "best": preset_setting("best"),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--height", type=int, default=540)
    parser.add_argument("--frames", type=int, nargs="*")
    parser.add_argument("--setting", nargs="*", choices=list(SETTINGS), default=list(SETTINGS))
    args = parser.parse_args()
    settings = [SETTINGS[name] for name in args.setting]
    if PLAIN_SMOOTHING not in settings:
        settings.insert(0, PLAIN_SMOOTHING)  # the band ratios' baseline
    paths = dam_frame_paths(args.frames)
    if not paths:
        raise SystemExit("no dam-break frames under ../shared/data")
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            rows = run_dam_frames(
                gl, renderer, settings, paths, width=args.width, height=args.height, cache=CACHE
            )
        finally:
            renderer.release()
    print("\nband error / plain smoothing's, per frame:")
    for setting in settings:
        ratios = band_ratios(rows, setting.name)
        cells = " ".join(f"{r:5.0%}" for r in ratios.values())
        print(f"  {setting.name[:20]:>20}: {cells}   worst {max(ratios.values()):.0%}")
    for setting in settings:
        if setting is not PLAIN_SMOOTHING:  # REPORT.md's section, each against the baseline
            print("\n" + "\n".join(dam_frames_section(rows, setting.name)))


if __name__ == "__main__":
    main()
