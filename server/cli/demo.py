"""`sphrender demo -o demo.png`: the built-in weld bead (`sphrender.server.content.demo`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from sphrender.server.cli.options import Subcommands, add_output_format, choose_format
from sphrender.server.cli.render import render_one


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
    demo = commands.add_parser(
        "demo",
        parents=[common],
        help="render the built-in weld-bead demo scene",
        description="Render a procedurally generated weld bead on a steel plate.",
    )
    demo.add_argument("-o", "--output", type=Path, default=Path("demo.png"), help="output image")
    add_output_format(demo)
    demo.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sphrender.server.content.demo import demo_frame, demo_scene
    from sphrender.server.engine.gpu.gl_context import GLContext
    from sphrender.server.engine.renderer import SurfaceRenderer

    scene = demo_scene()
    fmt = choose_format(args.format, args.output, scene.output.format)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            render_one(renderer, demo_frame(), scene, fmt, args.output)
        finally:
            renderer.release()
    print(f"wrote {args.output}")
    return 0
