"""The `sphrender` command line: render, sph, demo, submit, serve, info.

Bad input (a scene key, a particle array, an unreadable file) prints one line naming the field and
the limit and exits with status 2; a machine without EGL/Mesa, or without a usable OpenCL device
(only commands that need one), prints what to install and exits with status 3. No tracebacks for
either.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from sphrender.client.errors import InputError
from sphrender.server.presets import PRESETS

if TYPE_CHECKING:
    from sphrender.client.frame import ParticleFrame
    from sphrender.server.engine.frame_output import RenderedFrame
    from sphrender.server.engine.renderer import RenderStats, SurfaceRenderer
    from sphrender.server.scene import Scene

ImageFormat = Literal["png", "exr"]

EXIT_BAD_INPUT = 2
EXIT_NO_GPU_STACK = 3
EXIT_FRAMES_FAILED = 4

log = logging.getLogger("sphrender")


def _add_output_format(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--format",
        choices=["png", "exr"],
        help="output format (default: the scene's [output] format, or the suffix of -o)",
    )


def _add_cl_device(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cl-device",
        metavar="SPEC",
        help="OpenCL device for the SPH pass: 'P' or 'P:D' indices or a name substring "
        "(default: PYOPENCL_CTX, else the first device that builds kernels; see `info`)",
    )


def _add_env_dir(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--env-dir",
        type=Path,
        action="append",
        default=[],
        metavar="DIR",
        help="directory that [environment] file may name files in (repeatable; default: the "
        "scene file's directory)",
    )


def _add_quality(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--quality",
        choices=PRESETS,
        help="quality preset (configs/quality-NAME.toml) the scene file is laid over; the "
        "scene's own keys win (default: balanced = the built-in defaults)",
    )


def _load_scene(args: argparse.Namespace) -> Scene:
    from sphrender.server.presets import load_scene_with_preset

    return load_scene_with_preset(args.scene, args.quality)


def _environment_dirs(args: argparse.Namespace) -> list[Path]:
    return list(args.env_dir) or ([args.scene.resolve().parent] if args.scene else [])


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
    _add_quality(render)
    _add_env_dir(render)
    render.add_argument(
        "-o",
        "--output",
        type=Path,
        required=True,
        help="output file for one input, or a directory for several (named after the inputs)",
    )
    _add_output_format(render)
    _add_cl_device(render)

    sph = commands.add_parser(
        "sph",
        parents=[common],
        help="compute the SPH quantities the renderer uses and write them to .npz",
        description="Compute per-particle density, colour field (eq 26), its gradient (eq 27), "
        "surface flags (eq 28, |n| > t) and radius (eq 29 when [sph] adaptive_radius is on) on "
        "OpenCL, as the renderer sees them, and write them to an .npz: density, color_field, "
        "color_gradient (N x 3), surface (bool), radius, splat (bool: drawn by surface-only "
        "splatting), support_radius, mass and surface_density (absent without surface).",
    )
    sph.add_argument("input", metavar="INPUT", help="particle file (as for render)")
    sph.add_argument("--scene", type=Path, help="scene TOML (default: built-in defaults)")
    sph.add_argument("-o", "--output", type=Path, required=True, help="output .npz file")
    sph.add_argument(
        "--densities",
        choices=["input", "compute"],
        default="input",
        help="input: use the file's densities when it has them, as the renderer does "
        "(default); compute: always compute them (eq 2)",
    )
    _add_cl_device(sph)

    demo = commands.add_parser(
        "demo",
        parents=[common],
        help="render the built-in weld-bead demo scene",
        description="Render a procedurally generated weld bead on a steel plate.",
    )
    demo.add_argument("-o", "--output", type=Path, default=Path("demo.png"), help="output image")
    _add_output_format(demo)

    submit = commands.add_parser(
        "submit",
        parents=[common],
        help="render a whole sequence, one output per input frame (resumable)",
        description="Render a sequence of particle files into DIR, one image per input, named "
        "after it. Inputs may be files, globs or directories; frames are ordered by the numbers "
        "in their names. Outputs are written atomically; --resume skips frames whose output is "
        "already a complete image. A bad frame is reported and the others still render; the exit "
        "status is non-zero when any frame failed.",
    )
    submit.add_argument("inputs", nargs="+", metavar="INPUT", help="files, globs or directories")
    submit.add_argument("-o", "--output", type=Path, required=True, help="output directory")
    submit.add_argument("--scene", type=Path, help="scene TOML (default: built-in defaults)")
    _add_quality(submit)
    _add_env_dir(submit)
    submit.add_argument(
        "--format", choices=["png", "exr"], help="output format (default: the scene's)"
    )
    where = submit.add_mutually_exclusive_group(required=True)
    where.add_argument(
        "--server", metavar="URL", help="render on a running `sphrender serve` (http://HOST:PORT)"
    )
    where.add_argument(
        "--local",
        action="store_true",
        help="render with the embedded engine in this process (no server)",
    )
    submit.add_argument("--token", help="bearer token for --server (default: $SPHRENDER_TOKEN)")
    submit.add_argument(
        "--resume", action="store_true", help="skip frames whose output is a complete image"
    )
    submit.add_argument(
        "--jobs",
        type=int,
        default=2,
        metavar="N",
        help="frames in flight at once on the server (--server), or input files read ahead "
        "(--local, which renders one frame at a time)",
    )
    submit.add_argument(
        "--attribute",
        action="append",
        default=[],
        metavar="NAME=FILE_NAME",
        help="map an attribute to the file's name for it, e.g. density=rho (repeatable)",
    )

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

    scene = _load_scene(args)
    fmt = _choose_format(args.format, args.output, scene.output.format)
    paths = _output_paths(args.inputs, args.output, encoders.file_suffix(fmt))
    frames = [(name, path) for name, path in zip(args.inputs, paths, strict=True)]
    failures: list[str] = []
    env_dirs = _environment_dirs(args)
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
    from sphrender.server.local_backend import render_for_output

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
    from sphrender.server.local_backend import encode_for_scene

    try:
        write_atomically(path, encode_for_scene(frame, scene, fmt))
    except OSError as exc:
        raise InputError("output", f"cannot write {path}: {exc.strerror or exc}") from None
    stages = " ".join(f"{k}={v:.1f}ms" for k, v in stats.stage_ms.items())
    now = time.perf_counter()
    log.info(
        "%s: %d particles (%d visible, %d splatted), %s, total %.1f ms, written at %.3f s",
        path,
        stats.particles_in,
        stats.particles_drawn,
        stats.particles_splatted,
        stages,
        (now - start) * 1e3,
        now - command_start,
    )


def _render_one(
    renderer: SurfaceRenderer, particles: ParticleFrame, scene: Scene, fmt: ImageFormat, path: Path
) -> None:
    start = time.perf_counter()
    frame, stats = _render_for_output(renderer, particles, scene, fmt)
    _encode_and_write(frame, stats, scene, fmt, path, start, start)


def _run_sph(args: argparse.Namespace) -> int:
    import io

    import numpy as np

    from sphrender.client.readers import read_particles
    from sphrender.client.submit import write_atomically
    from sphrender.server.engine.cl_context import CLContext
    from sphrender.server.engine.sph import (
        SphEngine,
        SphParameters,
        eq29_radii,
        frame_particle_radius,
        surface_density,
    )
    from sphrender.server.scene import Scene, load_scene

    scene = load_scene(args.scene) if args.scene else Scene()
    frame = read_particles(args.input)
    start = time.perf_counter()
    radius = frame_particle_radius(frame, scene)
    params = SphParameters.from_scene(scene, radius)
    with CLContext(args.cl_device) as cl:
        log.info("OpenCL device: %s", cl.device_info.label)
        engine = SphEngine(cl)
        try:
            result = engine.compute(
                frame.positions,
                params,
                frame.densities if args.densities == "input" else None,
                gradient=True,
                splat_mask=True,
            )
        finally:
            engine.release()
    d_surface = surface_density(result.density, result.surface)
    if scene.sph.adaptive_radius:
        radii = eq29_radii(result, frame, scene)
    elif frame.radii is not None:
        radii = frame.radii
    else:
        radii = np.full(frame.count, scene.particles.radius, dtype=np.float32)
    assert result.splat_keep is not None and result.color_gradient is not None
    arrays = {
        "density": result.density,
        "color_field": result.color_field,
        "color_gradient": result.color_gradient,
        "surface": result.surface,
        "radius": radii,
        "splat": result.splat_keep if scene.sph.surface_only else np.ones(frame.count, bool),
        "support_radius": np.float64(params.support_radius),
        "mass": np.float64(params.mass),
    }
    if d_surface is not None:
        arrays["surface_density"] = np.float64(d_surface)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    try:
        write_atomically(args.output, buffer.getvalue())
    except OSError as exc:
        raise InputError("output", f"cannot write {args.output}: {exc.strerror or exc}") from None
    surface_share = float(result.surface.mean()) if frame.count else 0.0
    print(
        f"wrote {args.output}: {frame.count} particles, densities "
        f"{'computed' if result.density_computed else 'from input'}, "
        f"{surface_share:.1%} on the surface, {(time.perf_counter() - start) * 1e3:.0f} ms"
    )
    return 0


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


def _parse_attribute_map(pairs: Sequence[str]) -> dict[str, str]:
    mapping: dict[str, str] = {}
    for pair in pairs:
        name, sep, file_name = pair.partition("=")
        if not sep or not name or not file_name:
            raise InputError("--attribute", f"expected NAME=FILE_NAME, got {pair!r}")
        mapping[name] = file_name
    return mapping


def _run_submit(args: argparse.Namespace) -> int:
    from sphrender.client.sequences import expand_inputs, plan_jobs
    from sphrender.client.submit import FrameRenderer, RemoteFrameRenderer, run_submission
    from sphrender.server import encoders
    from sphrender.server.scene import scene_to_dict

    if args.jobs < 1:
        raise InputError("--jobs", f"must be at least 1, got {args.jobs}")
    scene = _load_scene(args)
    fmt: ImageFormat = args.format or scene.output.format
    attribute_map = _parse_attribute_map(args.attribute)
    jobs = plan_jobs(expand_inputs(args.inputs), args.output, encoders.file_suffix(fmt))
    try:
        args.output.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError("output", f"cannot create {args.output}: {exc.strerror}") from None
    backend: FrameRenderer
    if args.server:
        # The validated scene with the quality preset applied; the server validates it again
        # under its own limits.
        raw_scene = scene_to_dict(scene)
        token = args.token or os.environ.get("SPHRENDER_TOKEN")
        backend = RemoteFrameRenderer(args.server, raw_scene, fmt, token=token)
        close = None
        concurrency = args.jobs
    else:
        from sphrender.server.local_backend import LocalFrameRenderer

        local = LocalFrameRenderer(scene, fmt, _environment_dirs(args))
        log.info("GL renderer: %s", local.gl_renderer)
        backend, close, concurrency = local, local.close, 1
    try:
        summary = run_submission(
            jobs,
            backend,
            resume=args.resume,
            attribute_map=attribute_map,
            read_ahead=args.jobs,
            concurrency=concurrency,
        )
    finally:
        if close is not None:
            close()
    print(summary.report(), file=sys.stderr)
    return 0 if summary.ok else EXIT_FRAMES_FAILED


def _run_bench(args: argparse.Namespace) -> int:
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


def _run_info(_args: argparse.Namespace) -> int:
    """Print what the renderer would use as JSON; without GL, print why (and still the OpenCL
    devices) and exit like any other command that cannot create its context."""
    from sphrender.server.engine.cl_context import CLUnavailableError, icd_load_errors, list_devices
    from sphrender.server.engine.gl_context import GLContext, GLUnavailableError

    info: dict[str, object] = {}
    gl_error: GLUnavailableError | None = None
    try:
        with GLContext() as gl:
            info.update(
                gl_renderer=gl.renderer,
                gl_version=gl.version,
                software=gl.is_software,
                max_image_side=gl.limits.max_image_side,
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
    from sphrender.server.engine.cl_context import CLUnavailableError
    from sphrender.server.engine.gl_context import GLUnavailableError

    runners = {
        "render": _run_render,
        "sph": _run_sph,
        "demo": _run_demo,
        "submit": _run_submit,
        "serve": _run_serve,
        "bench": _run_bench,
        "info": _run_info,
    }
    try:
        return runners[args.command](args)
    except InputError as exc:
        print(f"sphrender: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (GLUnavailableError, CLUnavailableError) as exc:
        print(f"sphrender: error: {exc}", file=sys.stderr)
        return EXIT_NO_GPU_STACK


if __name__ == "__main__":
    sys.exit(main())
