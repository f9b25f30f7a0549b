"""`sphrender render INPUT... -o OUT`: particle files rendered locally, one GL context for all.

Also the encode-and-write step `demo` shares.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

from sphrender.core.errors import InputError
from sphrender.server.cli.options import (
    EXIT_BAD_INPUT,
    ImageFormat,
    Subcommands,
    add_cl_device,
    add_env_dir,
    add_output_format,
    add_quality,
    choose_format,
    environment_dirs,
    load_scene,
    output_paths,
)

if TYPE_CHECKING:
    from sphrender.core.frame import ParticleFrame
    from sphrender.server.engine.frame_output import RenderedFrame, RenderStats
    from sphrender.server.engine.renderer import SurfaceRenderer
    from sphrender.server.scene import Scene

log = logging.getLogger("sphrender")


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
    render = commands.add_parser(
        "render",
        parents=[common],
        help="render particle files locally (no server)",
        description="Render one or more particle files with the embedded engine. One GL "
        "context is reused for every frame.",
    )
    render.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="particle files: .npz .npy .vtk .vtu .ply .bgeo .csv",
    )
    render.add_argument("--scene", type=Path, help="scene TOML (default: built-in defaults)")
    add_quality(render)
    add_env_dir(render)
    render.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="output file for one input, or a directory for several (named after the inputs)",
    )
    add_output_format(render)
    add_cl_device(render)
    render.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sphrender.core.readers import read_particles
    from sphrender.server.engine.gpu.gl_context import GLContext
    from sphrender.server.engine.renderer import SurfaceRenderer
    from sphrender.server.output import encoders

    scene = load_scene(args)
    fmt = choose_format(args.format, args.output, scene.output.format)
    paths = output_paths(args.inputs, args.output, encoders.file_suffix(fmt))
    frames = [(name, path) for name, path in zip(args.inputs, paths, strict=True)]
    failures: list[str] = []
    env_dirs = environment_dirs(args)
    # Encoding + writing frame N (numpy and OpenImageIO, no GL) runs on one worker thread while
    # this (the GL owner) thread reads and renders frame N + 1: on a CPU-rendered machine the
    # PNG encode was a fifth of the per-frame time.
    command_start = time.perf_counter()
    with GLContext() as gl, ThreadPoolExecutor(max_workers=1) as encoder:
        renderer = SurfaceRenderer(gl, cl_device=args.cl_device, environment_dirs=env_dirs)
        renderer.check_image_size(scene)
        log.info("GL renderer: %s (%s)", gl.renderer, gl.version)
        pending: list[tuple[str, Future[None]]] = []
        try:
            for name, path in frames:
                try:
                    start = time.perf_counter()
                    rendered = _render_for_output(renderer, read_particles(name), scene, fmt)
                except InputError as exc:
                    # One bad frame of a sequence does not stop the others; all are reported.
                    failures.append(f"{name}: {exc}")
                    continue
                if len(pending) >= MAX_FRAMES_IN_ENCODER:  # bounded: frames are ~15 MB each
                    _collect(*pending.pop(0), failures)
                job = encoder.submit(
                    _encode_and_write, *rendered, scene, fmt, path, start, command_start
                )
                pending.append((name, job))
        finally:
            renderer.release()
            for name, job in pending:
                _collect(name, job, failures)
    if failures:
        for failure in failures:
            print(f"sphrender: error: {failure}", file=sys.stderr)
        if len(frames) > 1:
            print(f"sphrender: {len(failures)} of {len(frames)} inputs failed", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


MAX_FRAMES_IN_ENCODER = 2


def _collect(name: str, job: Future[None], failures: list[str]) -> None:
    try:
        job.result()
    except InputError as exc:
        failures.append(f"{name}: {exc}")


def _render_for_output(
    renderer: SurfaceRenderer, particles: ParticleFrame, scene: Scene, fmt: ImageFormat
) -> tuple[RenderedFrame, RenderStats]:
    from sphrender.server.output.local import render_for_output

    return render_for_output(renderer, particles, scene, fmt)


def _encode_and_write(
    frame: RenderedFrame,
    stats: RenderStats,
    scene: Scene,
    fmt: ImageFormat,
    path: Path,
    start: float,
    command_start: float,
) -> None:
    """Encode and write one rendered frame (any thread: no GL); logs its stage times, the time
    from render start to written file, and when it was written (seconds since the command
    started: the spacing of those is the steady per-frame time `sphrender bench` reports)."""
    from sphrender.client.submit import write_atomically
    from sphrender.server.output.local import encode_for_scene

    try:
        write_atomically(path, encode_for_scene(frame, scene, fmt))
    except OSError as exc:
        raise InputError("output", f"cannot write {path}: {exc.strerror or exc}") from None
    stages = " ".join(f"{k}={v:.1f}ms" for k, v in stats.stage_ms.items())
    now = time.perf_counter()
    log.info(
        "%s: %d particles (%d visible, %d splatted), %s, host %.2f ms, total %.1f ms, "
        "written at %.3f s",
        path,
        stats.particles_in,
        stats.particles_drawn,
        stats.particles_splatted,
        stages,
        stats.host_ms,
        (now - start) * 1e3,
        now - command_start,
    )


def render_one(
    renderer: SurfaceRenderer, particles: ParticleFrame, scene: Scene, fmt: ImageFormat, path: Path
) -> None:
    start = time.perf_counter()
    frame, stats = _render_for_output(renderer, particles, scene, fmt)
    _encode_and_write(frame, stats, scene, fmt, path, start, start)
