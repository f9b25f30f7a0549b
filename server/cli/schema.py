"""`sphrender schema [-o FILE]`: the scene's JSON Schema (draft 2020-12), generated from the
scene dataclasses (`sphrender.server.scene.json_schema`). ``schema/scene.schema.json`` in the
repository is this command's output; ``GET /v1/schema`` serves the same document."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sphrender.core.errors import InputError
from sphrender.server.cli.options import Subcommands


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
    schema = commands.add_parser(
        "schema",
        parents=[common],
        help="print or write the scene's JSON Schema",
        description="Write the JSON Schema (draft 2020-12) of scene files and JSON scenes, "
        "generated from the scene dataclasses: types, descriptions, units, defaults, ranges.",
    )
    schema.add_argument(
        "-o", "--output", type=Path, default=None, help="write to this file (default: stdout)"
    )
    schema.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sphrender.server.scene.json_schema import scene_json_schema_text

    text = scene_json_schema_text()
    if args.output is None:
        sys.stdout.write(text)
        return 0
    try:
        args.output.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise InputError("output", f"cannot write {args.output}: {exc.strerror or exc}") from None
    print(f"wrote {args.output}")
    return 0
