"""The brushed plate's section of REPORT.md on its own (benchmarks/studies/brushed_plate.py):
frame cost of the anisotropic lobe and the surface detail against the finish off, and the crop.
`bench_report.py` runs the same study inside the full report.

    .venv/bin/python benchmarks/bench_finish.py [--frames 9]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import repo_path  # noqa: F401

from benchmarks.studies.brushed_plate import measure, section, write_crop, write_marks
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

OUT = Path(__file__).resolve().parent


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument(
        "--frames", type=int, default=9, help="timed frames per setting (the fastest counts)"
    )
    args = parser.parse_args()
    with GLContext() as gl, tempfile.TemporaryDirectory() as assets:
        write_marks(Path(assets))
        renderer = SurfaceRenderer(gl, environment_dirs=[assets])
        try:
            rows = measure(renderer, max(1, args.frames))
            print(f"crops: {', '.join(str(p) for p in write_crop(renderer, OUT))}")
        finally:
            renderer.release()
    print("\n".join(section(rows)))


if __name__ == "__main__":
    main()
