"""Regenerates benchmarks/REPORT.md, its tables, Pareto plot and crops: a full `sphrender bench`
with this repository's studies added (benchmarks/studies/report_studies.py).

    .venv/bin/python benchmarks/bench_report.py [--no-peers] [--frames 3]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import repo_path  # noqa: F401

from benchmarks.studies.report_studies import run_studies
from sphrender.server.bench.run import run_bench

OUT = Path(__file__).resolve().parent


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--no-peers", action="store_true", help="skip the peers")
    parser.add_argument("--frames", type=int, default=3, help="timed frames per setting")
    args = parser.parse_args()
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
