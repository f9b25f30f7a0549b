"""`sphrender bench`: quality settings and peers timed against error; table, report, plot."""

from __future__ import annotations

import argparse
from pathlib import Path

from sphrender.core.errors import InputError
from sphrender.server.cli.options import Subcommands


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
    bench = commands.add_parser(
        "bench",
        parents=[common],
        help="benchmark quality settings and peers; write a table, report and Pareto plot",
        description="Time quality settings on reference scenes (ball, slab, thin sheet, "
        "droplets, dam break) against their true surfaces, run the peers (VTK fluid mapper, "
        "PyVista, pysplashsurf, scipy) on the same particles and camera, and write "
        "bench-table.csv, REPORT.md and pareto.png into --out. Needs pip install '.[bench]' "
        "for the peers and the plot; missing peers are skipped with the reason.",
    )
    bench.add_argument("--out", type=Path, default=Path("bench-out"), help="output directory")
    bench.add_argument(
        "--quick", action="store_true", help="small scenes, few settings, no peers (smoke test)"
    )
    bench.add_argument("--no-peers", action="store_true", help="skip the peers")
    bench.add_argument("--frames", type=int, default=3, help="timed frames per setting")
    bench.add_argument("--width", type=int, help="sweep image width (default 1280, quick 320)")
    bench.add_argument("--height", type=int, help="sweep image height (default 720, quick 180)")
    bench.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sphrender.server.bench.run import run_bench

    if args.frames < 1:
        raise InputError("--frames", f"must be at least 1, got {args.frames}")
    run_bench(
        args.out,
        quick=args.quick,
        width=args.width or (320 if args.quick else 1280),
        height=args.height or (180 if args.quick else 720),
        frames=1 if args.quick else args.frames,
        with_peers=not args.no_peers,
    )
    return 0
