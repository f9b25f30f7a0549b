"""Regenerates benchmarks/REPORT.md, its tables, Pareto plot and crops: a full `sphrender bench`
with this repository's studies added (benchmarks/studies/report_studies.py).

    .venv/bin/python benchmarks/bench_report.py [--no-peers] [--frames 3]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import repo_path  # noqa: F401

from benchmarks.studies.report_studies import run_studies
from sphrender.server.bench.run import run_bench

OUT = Path(__file__).resolve().parent

#: What the report's peers and studies import from the `bench` extra (pyproject.toml).
BENCH_MODULES = ("pysplashsurf", "vtk", "pyvista", "matplotlib", "blosc2", "DracoPy", "zfpy")


def missing_bench_modules() -> list[str]:
    """The `bench` extra's modules this Python cannot import: checked before a long run."""
    return [name for name in BENCH_MODULES if importlib.util.find_spec(name) is None]


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--no-peers", action="store_true", help="skip the peers")
    parser.add_argument("--frames", type=int, default=3, help="timed frames per setting")
    args = parser.parse_args()
    missing = missing_bench_modules()
    if missing:
        sys.exit(
            f"bench_report: missing {', '.join(missing)}; install the bench extra first: "
            ".venv/bin/pip install -e '.[bench]'"
        )
    run_bench(
        OUT,
        quick=False,
        width=1280,
        height=720,
        frames=max(1, args.frames),
        with_peers=not args.no_peers,
        studies=run_studies,
    )


if __name__ == "__main__":
    main()
