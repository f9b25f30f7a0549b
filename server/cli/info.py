"""`sphrender info`: the OpenGL renderer, its limits and the OpenCL devices, as JSON."""

from __future__ import annotations

import argparse
import json

from sphrender.server.cli.options import Subcommands


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
    info = commands.add_parser(
        "info",
        parents=[common],
        help="print the OpenGL renderer and limits as JSON",
        description="Create the headless GL context and report renderer, version and limits.",
    )
    info.set_defaults(run=run)


def run(_args: argparse.Namespace) -> int:
    """Print what the renderer would use as JSON; without GL, print why (and still the OpenCL
    devices) and exit like any other command that cannot create its context."""
    from sphrender.server.engine.gpu.cl_context import (
        CLUnavailableError,
        icd_load_errors,
        list_devices,
    )
    from sphrender.server.engine.gpu.gl_context import GLContext, GLUnavailableError
    from sphrender.server.engine.passes.prepare_stage import resolve_mode

    info: dict[str, object] = {}
    gl_error: GLUnavailableError | None = None
    try:
        with GLContext() as gl:
            info.update(
                gl_renderer=gl.renderer,
                gl_version=gl.version,
                software=gl.is_software,
                max_image_side=gl.limits.max_image_side,
                prepare=resolve_mode("auto", gl.is_software),
                batch_rasteriser_threads=gl.batch_rasteriser_threads,
            )
    except GLUnavailableError as exc:
        gl_error = exc
        info["gl_error"] = str(exc)
    try:
        info["opencl_devices"] = [device.label for device, _ in list_devices()]
    except CLUnavailableError as exc:
        info["opencl_devices"] = []
        info["opencl_error"] = str(exc)
    if icd_errors := icd_load_errors():
        info["opencl_icd_errors"] = icd_errors
    print(json.dumps(info, indent=2))
    if gl_error is not None:
        raise gl_error
    return 0
