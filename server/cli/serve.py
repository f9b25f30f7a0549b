"""`sphrender serve`: the render service (HTTP API and streaming socket)."""

from __future__ import annotations

import argparse
from pathlib import Path

from sphrender.server.cli.options import Subcommands


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
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
    serve.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from sphrender.server.service.config import load_server_config
    from sphrender.server.service.serve import serve

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
