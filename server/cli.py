"""The `sphrender` command line: render, demo, info, serve.

Bad input (a scene key, a particle array, an unreadable file) prints one line naming the field and
the limit and exits with status 2; a machine without EGL/Mesa prints which Debian packages to
install and exits with status 3. No tracebacks for either.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from sphrender.client.errors import InputError

if TYPE_CHECKING:
    from sphrender.client.frame import ParticleFrame
    from sphrender.server.engine.renderer import SurfaceRenderer
    from sphrender.server.scene import Scene

ImageFormat = Literal["png", "exr"]

EXIT_BAD_INPUT = 2
EXIT_NO_GPU_STACK = 3

log = logging.getLogger("sphrender")


def _add_output_format(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--format",
        choices=["png", "exr"],
        help="output format (default: the scene's [output] format, or the suffix of -o)",
    )


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sphrender",
        description="Render SPH particle simulations as screen-space metal surfaces.",
    )
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "-v", "--verbose", action="store_true", help="log the GL renderer and stage timings"
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

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
    render.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="output file for one input, or a directory for several (named after the inputs)",
    )
    _add_output_format(render)

    demo = commands.add_parser(
        "demo",
        parents=[common],
        help="render the built-in weld-bead demo scene",
        description="Render a procedurally generated weld bead on a steel plate.",
    )
    demo.add_argument("-o", "--output", type=Path, default=Path("demo.png"), help="output image")
    _add_output_format(demo)

    serve = commands.add_parser(
        "serve",
        parents=[common],
        help="run the render service (HTTP API and streaming socket)",
        description="Run the long-running render service: one render thread owns the GL "
        "context; clients send frames over HTTP (POST /v1/render, sessions) or the streaming "
        "protocol (PROTOCOL.md). Settings come from --config (see configs/server.toml); the "
        "options below override it. The token comes from the config or $SPHRENDER_TOKEN. On "
        "start-up one JSON line with the bound ports is printed on stdout. SIGTERM or SIGINT "
        "drains (in-flight frames are answered) and exits 0.",
    )
    serve.add_argument("--config", type=Path, help="server settings TOML (default: built-in)")
    serve.add_argument("--host", help="address to bind both listeners (default 127.0.0.1)")
    serve.add_argument("--port", type=int, help="HTTP port (0 = any free port)")
    serve.add_argument("--stream-port", type=int, help="stream port (0 = any free port)")
    serve.add_argument(
        "--no-stream", action="store_true", help="serve HTTP only (no streaming socket)"
    )
    serve.add_argument(
        "--allow-remote-without-token",
        action="store_true",
        help="allow a non-loopback --host without a token (anyone who can reach it may render)",
    )
    serve.add_argument(
        "--log-json", action="store_true", help="structured logs: one JSON object per line"
    )

    commands.add_parser(
        "info",
        parents=[common],
        help="print the OpenGL renderer and limits as JSON",
        description="Create the headless GL context and report renderer, version and limits.",
    )
    return parser


def _output_paths(inputs: Sequence[str], output: Path, suffix: str) -> list[Path]:
    if len(inputs) == 1 and not output.is_dir():
        return [output]
    output.mkdir(parents=True, exist_ok=True)
    return [output / (Path(name).name.split(".")[0] + suffix) for name in inputs]


def _choose_format(explicit: str | None, output: Path, scene_format: ImageFormat) -> ImageFormat:
    """--format wins, then the output file's suffix, then the scene's [output] format."""
    for candidate in (explicit, output.suffix.lower().lstrip(".")):
        if candidate == "png":
            return "png"
        if candidate == "exr":
            return "exr"
    return scene_format


def _run_render(args: argparse.Namespace) -> int:
    from sphrender.client.readers import read_particles
    from sphrender.server import encoders
    from sphrender.server.engine.gl_context import GLContext
    from sphrender.server.engine.renderer import SurfaceRenderer
    from sphrender.server.scene import Scene, load_scene

    scene = load_scene(args.scene) if args.scene else Scene()
    fmt = _choose_format(args.format, args.output, scene.output.format)
    paths = _output_paths(args.inputs, args.output, encoders.file_suffix(fmt))
    frames = [(name, path) for name, path in zip(args.inputs, paths, strict=True)]
    failures: list[str] = []
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        renderer.check_image_size(scene)
        log.info("GL renderer: %s (%s)", gl.renderer, gl.version)
        try:
            for name, path in frames:
                try:
                    _render_one(renderer, read_particles(name), scene, fmt, path)
                except InputError as exc:
                    # One bad frame of a sequence does not stop the others; all are reported.
                    failures.append(f"{name}: {exc}")
        finally:
            renderer.release()
    if failures:
        for failure in failures:
            print(f"sphrender: error: {failure}", file=sys.stderr)
        if len(frames) > 1:
            print(f"sphrender: {len(failures)} of {len(frames)} inputs failed", file=sys.stderr)
        return EXIT_BAD_INPUT
    return 0


def _render_one(
    renderer: SurfaceRenderer, particles: ParticleFrame, scene: Scene, fmt: ImageFormat, path: Path
) -> None:
    from sphrender.server import encoders

    start = time.perf_counter()
    want_aovs = fmt == "exr"
    frame, stats = renderer.render(
        particles,
        scene,
        depth=want_aovs and "Z" in scene.output.aovs,
        normals=want_aovs and "N" in scene.output.aovs,
    )
    # Written next to the target and renamed into place: a failed or killed run never leaves a
    # partial image under the final name.
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        if fmt == "png":
            options = encoders.PngOptions(
                bits=scene.output.png_bits, exposure=scene.output.exposure
            )
            encoders.write_png(frame, partial, options)
        else:
            exr = encoders.ExrOptions(
                pixel_type=scene.output.exr_pixel_type, aovs=scene.output.aovs
            )
            encoders.write_exr(frame, partial, exr)
        os.replace(partial, path)
    except OSError as exc:
        raise InputError("output", f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        partial.unlink(missing_ok=True)
    stages = " ".join(f"{k}={v:.1f}ms" for k, v in stats.stage_ms.items())
    log.info(
        "%s: %d particles (%d drawn), %s, total %.1f ms",
        path,
        stats.particles_in,
        stats.particles_drawn,
        stages,
        (time.perf_counter() - start) * 1e3,
    )


def _run_demo(args: argparse.Namespace) -> int:
    from sphrender.server.demo import demo_frame, demo_scene
    from sphrender.server.engine.gl_context import GLContext
    from sphrender.server.engine.renderer import SurfaceRenderer

    scene = demo_scene()
    fmt = _choose_format(args.format, args.output, scene.output.format)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            _render_one(renderer, demo_frame(), scene, fmt, args.output)
        finally:
            renderer.release()
    print(f"wrote {args.output}")
    return 0


def _run_info(_args: argparse.Namespace) -> int:
    from sphrender.server.engine.gl_context import GLContext

    with GLContext() as gl:
        info = {
            "gl_renderer": gl.renderer,
            "gl_version": gl.version,
            "software": gl.is_software,
            "max_image_side": gl.limits.max_image_side,
        }
    print(json.dumps(info, indent=2))
    return 0


def _run_serve(args: argparse.Namespace) -> int:
    from sphrender.server.service.app import serve
    from sphrender.server.service.config import load_server_config

    config = load_server_config(args.config)
    overrides: dict[str, dict[str, object]] = {"http": {}, "stream": {}, "security": {}}
    if args.host is not None:
        overrides["http"]["host"] = args.host
    if args.port is not None:
        overrides["http"]["port"] = args.port
    if args.stream_port is not None:
        overrides["stream"]["port"] = args.stream_port
    if args.no_stream:
        overrides["stream"]["enabled"] = False
    if args.allow_remote_without_token:
        overrides["security"]["allow_remote_without_token"] = True
    overrides["logging"] = {"json": True} if args.log_json else {}
    if args.verbose:
        overrides["logging"]["level"] = "debug"
    return serve(config.with_overrides(overrides))


def main(argv: Sequence[str] | None = None) -> int:
    args = _build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(name)s: %(message)s",
        stream=sys.stderr,
    )
    from sphrender.server.engine.gl_context import GLUnavailableError

    runners = {"render": _run_render, "demo": _run_demo, "info": _run_info, "serve": _run_serve}
    try:
        return runners[args.command](args)
    except InputError as exc:
        print(f"sphrender: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except GLUnavailableError as exc:
        print(f"sphrender: error: {exc}", file=sys.stderr)
        return EXIT_NO_GPU_STACK


if __name__ == "__main__":
    sys.exit(main())
