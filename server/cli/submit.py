"""`sphrender submit INPUT... (--server URL | --local | --ray [ADDRESS]) -o DIR`: a whole
sequence, resumable."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

from sphrender.core.errors import InputError
from sphrender.server.cli.options import (
    EXIT_FRAMES_FAILED,
    IMAGE_FORMATS,
    ImageFormat,
    Subcommands,
    add_env_dir,
    add_quality,
    environment_dirs,
    load_scene,
)

log = logging.getLogger("sphrender")


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
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
    add_quality(submit)
    add_env_dir(submit)
    submit.add_argument(
        "--format", choices=IMAGE_FORMATS, help="output format (default: the scene's)"
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
    where.add_argument(
        "--ray",
        nargs="?",
        const="",
        metavar="ADDRESS",
        help="render on a Ray cluster (pip install 'sphrender[ray]'): a pool of actors, one GL "
        "context each; ADDRESS is auto (the cluster `ray start` runs here), HOST:PORT or "
        "ray://HOST:PORT; without it $RAY_ADDRESS, else a local Ray instance for this run. "
        "Put it after the inputs or write --ray=ADDRESS",
    )
    submit.add_argument(
        "--ray-actors",
        type=int,
        metavar="N",
        help="--ray: render actors per node without GPUs (default 1; nodes with GPUs get one "
        "per GPU)",
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
        help="frames in flight at once on the server (--server) or per actor (--ray), or input "
        "files read ahead (--local, which renders one frame at a time)",
    )
    submit.add_argument(
        "--attribute",
        action="append",
        default=[],
        metavar="NAME=FILE_NAME",
        help="map an attribute to the file's name for it, e.g. density=rho (repeatable)",
    )
    submit.set_defaults(run=run)


def _parse_attribute_map(pairs: Sequence[str]) -> dict[str, str]:
    mapping: dict[str, str] = {}
    for pair in pairs:
        name, sep, file_name = pair.partition("=")
        if not sep or not name or not file_name:
            raise InputError("--attribute", f"expected NAME=FILE_NAME, got {pair!r}")
        mapping[name] = file_name
    return mapping


def _ray_backend() -> ModuleType:
    try:
        from sphrender.server.cluster import ray_backend
    except ImportError as exc:
        if exc.name is None or not exc.name.startswith("ray"):
            raise
        raise InputError(
            "--ray", "Ray is not installed: pip install 'sphrender[ray]' (Ray 2.x)"
        ) from None
    return ray_backend


def run(args: argparse.Namespace) -> int:
    from sphrender.client.sequences import expand_inputs, plan_jobs
    from sphrender.client.submit import FrameRenderer, RemoteFrameRenderer, run_submission
    from sphrender.server.output import encoders
    from sphrender.server.scene import scene_to_dict

    if args.jobs < 1:
        raise InputError("--jobs", f"must be at least 1, got {args.jobs}")
    if args.ray_actors is not None and args.ray is None:
        raise InputError("--ray-actors", "only applies with --ray")
    if args.ray_actors is not None and args.ray_actors < 1:
        raise InputError("--ray-actors", f"must be at least 1, got {args.ray_actors}")
    scene = load_scene(args)
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
    elif args.ray is not None:
        ray_backend = _ray_backend()
        options = ray_backend.RayOptions(
            address=args.ray or None,
            actors_per_node=args.ray_actors or 1,
            in_flight_per_actor=args.jobs,
        )
        pool = ray_backend.RayFrameRenderer(scene, fmt, environment_dirs(args), options)
        log.info("ray: %d render actors", pool.actor_count)
        backend, close, concurrency = pool, pool.close, pool.capacity
    else:
        from sphrender.server.output.local import LocalFrameRenderer

        local = LocalFrameRenderer(scene, fmt, environment_dirs(args))
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
