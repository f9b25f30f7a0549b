"""What several subcommands share: exit statuses, common options, scene and format choice."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TypeAlias

from sphrender.server.scene.presets import PRESETS

if TYPE_CHECKING:
    from sphrender.server.scene import Scene

from sphrender.core.protocol import IMAGE_FORMATS, ImageFormat

#: The `commands` argument of each subcommand's `add_parser`.
Subcommands: TypeAlias = "argparse._SubParsersAction[argparse.ArgumentParser]"

EXIT_BAD_INPUT = 2
EXIT_NO_GPU_STACK = 3
EXIT_FRAMES_FAILED = 4


def add_output_format(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--format",
        choices=IMAGE_FORMATS,
        help="output format (default: the scene's [output] format, or the suffix of -o: .png, "
        ".exr, .jpg/.jpeg, .raw)",
    )


def add_cl_device(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cl-device",
        metavar="SPEC",
        help="OpenCL device for the SPH pass: 'P' or 'P:D' indices or a name substring "
        "(default: PYOPENCL_CTX, else the first device that builds kernels; see `info`)",
    )


def add_env_dir(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--env-dir",
        type=Path,
        action="append",
        default=[],
        metavar="DIR",
        help="directory that [environment] file and [finish] detail_image may name files in "
        "(repeatable; default: the scene file's directory)",
    )


def add_quality(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--quality",
        choices=PRESETS,
        help="quality preset (configs/quality-NAME.toml) the scene file is laid over; the "
        "scene's own keys win (default: balanced = the built-in defaults)",
    )


def load_scene(args: argparse.Namespace) -> Scene:
    from sphrender.server.scene.presets import load_scene_with_preset

    return load_scene_with_preset(args.scene, args.quality)


def environment_dirs(args: argparse.Namespace) -> list[Path]:
    return list(args.env_dir) or ([args.scene.resolve().parent] if args.scene else [])


def output_paths(inputs: Sequence[str], output: Path, suffix: str) -> list[Path]:
    if len(inputs) == 1 and not output.is_dir():
        return [output]
    output.mkdir(parents=True, exist_ok=True)
    return [output / (Path(name).name.split(".")[0] + suffix) for name in inputs]


def choose_format(explicit: str | None, output: Path, scene_format: ImageFormat) -> ImageFormat:
    """--format wins, then the output file's suffix, then the scene's [output] format."""
    suffix = output.suffix.lower().lstrip(".")
    for candidate in (explicit, "jpeg" if suffix == "jpg" else suffix):
        for known in IMAGE_FORMATS:
            if candidate == known:
                return known
    return scene_format
