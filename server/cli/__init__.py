"""The `sphrender` command line: render, sph, demo, submit, serve, bench, info, schema.

One module per subcommand, each with `add_parser` (its options) and `run` (what it does); this
module assembles the parser from them and maps errors to exit statuses (`options.py`).

Bad input (a scene key, a particle array, an unreadable file) prints one line naming the field and
the limit and exits with status 2; a machine without EGL/Mesa, or without a usable OpenCL device
(only commands that need one), prints what to install and exits with status 3. No tracebacks for
either.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence

from sphrender.core.errors import InputError
from sphrender.server.cli import bench, demo, info, render, schema, serve, sph, submit
from sphrender.server.cli.options import EXIT_BAD_INPUT, EXIT_NO_GPU_STACK

#: In the order `sphrender --help` lists them.
SUBCOMMANDS = (render, sph, demo, submit, serve, bench, info, schema)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sphrender",
        description="Render SPH particle simulations as screen-space metal surfaces.",
    )
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "-v", "--verbose", action="store_true", help="log the GL renderer and stage timings"
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for subcommand in SUBCOMMANDS:
        subcommand.add_parser(commands, common)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(name)s: %(message)s",
        stream=sys.stderr,
    )
    from sphrender.server.engine.gpu.cl_context import CLUnavailableError
    from sphrender.server.engine.gpu.gl_context import GLUnavailableError

    try:
        run: Callable[[argparse.Namespace], int] = args.run
        return run(args)
    except InputError as exc:
        print(f"sphrender: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (GLUnavailableError, CLUnavailableError) as exc:
        print(f"sphrender: error: {exc}", file=sys.stderr)
        return EXIT_NO_GPU_STACK
