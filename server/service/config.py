"""Server settings (``configs/server.toml``): typed, documented, validated like the scene.

Each TOML section is a frozen dataclass whose fields are declared with `spec` (default, doc,
range), exactly as in `sphrender.server.scene`; `server_config_from_dict` rejects unknown keys and
out-of-range values with an `InputError` naming the dotted key. Command-line options
(``--host``, ``--port``, ...) and the ``SPHRENDER_TOKEN`` environment variable override the file
through `ServerConfig.with_overrides`, after which the whole configuration is validated again.

Every limit that protects the service from a client lives here, so the operator can see them in
one place and ``GET /v1/info`` can report them.
"""

from __future__ import annotations

import ipaddress
import os
import socket
import tomllib
import typing
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal, TypeVar

from sphrender.core.errors import InputError, kind_of
from sphrender.server.scene import MAX_IMAGE_PIXELS, section_from_dict, spec

#: Environment variable that supplies the bearer token (keeps it out of files and `ps`).
TOKEN_ENV = "SPHRENDER_TOKEN"
#: Shortest token accepted: 16 characters of a random token carry enough entropy.
MIN_TOKEN_LENGTH = 16

MIB = 1 << 20


@dataclass(frozen=True)
class HttpConfig:
    host: str = spec("127.0.0.1", "address the HTTP API binds to (loopback by default)")
    port: int = spec(
        8080, "HTTP port; 0 picks a free port (printed on start-up)", low=0, high=65535
    )
    max_body_bytes: int = spec(
        256 * MIB, "largest request body; larger bodies get 413 unread", low=1024
    )
    read_timeout_s: float = spec(
        30.0,
        "how long one socket read may block (idle keep-alive connections close after this)",
        low=0.0,
        low_open=True,
    )
    body_timeout_s: float = spec(
        120.0,
        "the whole body must arrive within this; a client dribbling bytes cannot hold a thread",
        low=0.0,
        low_open=True,
    )
    header_timeout_s: float = spec(
        10.0,
        "the request line and all headers must arrive within this from the request's first "
        "byte (a client dribbling its headers cannot hold a connection longer)",
        low=0.0,
        low_open=True,
    )
    max_connections: int = spec(
        128,
        "concurrent HTTP connections (one thread each). When full, the connection that has "
        "waited longest for its request line or headers (idle keep-alive or slow client) is "
        "closed to make room; only if none is waiting does a new connection get 503",
        low=1,
        high=4096,
    )
    health_connections: int = spec(
        4,
        "connections kept beyond max_connections for GET /healthz, /readyz and /metrics only "
        "(anything else on them gets 503), so health checks are answered under load",
        low=0,
        high=256,
    )


@dataclass(frozen=True)
class StreamConfig:
    enabled: bool = spec(True, "serve the streaming protocol (PROTOCOL.md)")
    port: int = spec(8081, "stream port; 0 picks a free port", low=0, high=65535)
    max_in_flight: int = spec(
        8,
        "pipelining depth: frames a connection may have unanswered; beyond it the server stops "
        "reading (backpressure)",
        low=1,
        high=256,
    )
    max_header_bytes: int = spec(65536, "largest JSON header of one message", low=256, high=MIB)
    max_payload_bytes: int = spec(
        256 * MIB, "largest payload of one message (u32 on the wire)", low=1024, high=2**32 - 1
    )
    handshake_timeout_s: float = spec(
        10.0, "the HELLO must arrive within this after connecting", low=0.0, low_open=True
    )
    idle_timeout_s: float = spec(
        300.0,
        "a connection with nothing in flight and no new message for this long is closed",
        low=0.0,
        low_open=True,
    )
    message_timeout_s: float = spec(
        30.0,
        "once a message has started, all of it must arrive within this (slow clients)",
        low=0.0,
        low_open=True,
    )
    write_timeout_s: float = spec(
        60.0,
        "an answer the client does not read for this long closes the connection",
        low=0.0,
        low_open=True,
    )
    max_connections: int = spec(
        32,
        "concurrent stream connections, the stream port's and WebSocket ones (GET /v1/stream) "
        "together, separate from limits.max_sessions. When full, a "
        "connection still waiting for its HELLO after 1 s, or else the session idle longest "
        "(past stream.evict_idle_s), is closed to make room",
        low=1,
        high=4096,
    )
    evict_idle_s: float = spec(
        5.0,
        "when all stream.max_connections are taken, a session with nothing in flight and no "
        "message for this long may be closed (GOODBYE evicted) to make room for a new one",
        low=0.0,
        low_open=True,
    )


@dataclass(frozen=True)
class LimitsConfig:
    max_particles: int = spec(2_000_000, "particles per frame (413 beyond)", low=1, high=50_000_000)
    max_pixels: int = spec(
        3840 * 2160, "image width x height per frame (413 beyond)", low=1, high=MAX_IMAGE_PIXELS
    )
    max_sessions: int = spec(
        64,
        "open HTTP sessions (POST /v1/sessions); 503 beyond. Stream connections are capped "
        "separately by stream.max_connections",
        low=1,
        high=65536,
    )
    max_scene_bytes: int = spec(
        1 << 20,
        "scene JSON text: HELLO's and FRAME's scene, POST /v1/sessions, an .npz scene entry",
        low=1024,
        high=64 * MIB,
    )
    max_npz_entries: int = spec(
        64, "entries in an .npz body (checked before the archive is read)", low=2, high=65536
    )
    max_request_bytes: int = spec(
        1536 * MIB,
        "memory one frame may need, estimated before it is read: the bytes received + "
        "particles x 640 B + pixels x 120 B (PROTOCOL.md, memory budget); 413 beyond",
        low=MIB,
    )
    memory_budget_bytes: int = spec(
        3072 * MIB,
        "memory all frames in progress may need together (the same estimate); beyond it HTTP "
        "gets 503 + Retry-After and the stream waits (TCP backpressure)",
        low=MIB,
    )
    session_idle_timeout_s: float = spec(
        600.0, "an HTTP session unused for this long is deleted", low=0.0, low_open=True
    )
    render_timeout_s: float = spec(
        120.0,
        "a frame whose render (from when the renderer begins it) takes longer is answered "
        "render_failed and the renderer restarted; an HTTP frame still queued after this gets "
        "503",
        low=0.0,
        low_open=True,
    )


@dataclass(frozen=True)
class SchedulerConfig:
    queue_per_session: int = spec(
        8,
        "frames one session (or one HTTP connection) may have queued; HTTP gets 503 beyond, "
        "the stream stops reading",
        low=1,
        high=1024,
    )
    queue_total: int = spec(64, "frames queued over all sessions", low=1, high=65536)
    encoder_threads: int = spec(
        2,
        "PNG/JPEG/EXR encoder threads (overlap with rendering the next frame). 2 suits a "
        "software GL, where rendering shares the cores (more measured no faster); on a GPU "
        "server, where rendering takes milliseconds, one per CPU core less one",
        low=1,
        high=64,
    )


@dataclass(frozen=True)
class SecurityConfig:
    token: str = spec(
        "",
        f"bearer token required on every request except /healthz and /readyz; empty = none. "
        f"${TOKEN_ENV} overrides it. At least {MIN_TOKEN_LENGTH} characters",
    )
    allow_remote_without_token: bool = spec(
        False, "allow binding a non-loopback address without a token (not recommended)"
    )
    allowed_origins: tuple[str, ...] = spec(
        (),
        "web origins (scheme://host[:port]) besides the server's own whose pages may open the "
        "WebSocket stream (GET /v1/stream); a request with another Origin gets 403",
    )
    environment_dirs: tuple[str, ...] = spec(
        (),
        "directories environment maps ([environment] file) and detail images ([finish] "
        "detail_image) may be read from; empty = none",
    )


@dataclass(frozen=True)
class LoggingConfig:
    json: bool = spec(
        False, "structured logs: one JSON object per line on stderr (Python warnings included)"
    )
    level: Literal["debug", "info", "warning", "error"] = spec("info", "log level")


@dataclass(frozen=True)
class LifecycleConfig:
    drain_timeout_s: float = spec(
        30.0,
        "on SIGTERM/SIGINT: how long in-flight frames may take before the process exits anyway",
        low=0.0,
    )
    drain_grace_s: float = spec(
        0.0,
        "on SIGTERM/SIGINT, before the listeners close: how long /readyz answers 503 "
        "'draining' while frames are still accepted, so a load balancer's health checks take "
        "the replica out first (set >= check interval x fall count; see deploy/haproxy/)",
        low=0.0,
    )
    drain_read_timeout_s: float = spec(
        2.0,
        "on SIGTERM/SIGINT: a message or request body that is half received gets this long to "
        "complete; then its connection is closed (it was not accepted, so nothing is lost)",
        low=0.0,
    )


@dataclass(frozen=True)
class WorkerConfig:
    start_timeout_s: float = spec(
        120.0,
        "the renderer process (which owns GL) must be up and warm within this",
        low=0.0,
        low_open=True,
    )
    max_rss_bytes: int = spec(
        4096 * MIB,
        "the renderer process is replaced, between frames, once its resident memory exceeds "
        "this (GL targets of a huge image, allocator growth)",
        low=64 * MIB,
    )


@dataclass(frozen=True)
class ServerConfig:
    http: HttpConfig = field(default_factory=HttpConfig)
    stream: StreamConfig = field(default_factory=StreamConfig)
    limits: LimitsConfig = field(default_factory=LimitsConfig)
    scheduler: SchedulerConfig = field(default_factory=SchedulerConfig)
    security: SecurityConfig = field(default_factory=SecurityConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)
    lifecycle: LifecycleConfig = field(default_factory=LifecycleConfig)
    worker: WorkerConfig = field(default_factory=WorkerConfig)

    def with_overrides(self, overrides: Mapping[str, Mapping[str, Any]]) -> ServerConfig:
        """A copy with ``{section: {key: value}}`` replaced, validated again as a whole."""
        data = server_config_to_dict(self)
        for section, values in overrides.items():
            data.setdefault(section, {}).update(values)
        return server_config_from_dict(data)


T = TypeVar("T")


def server_config_from_dict(data: Mapping[str, Any]) -> ServerConfig:
    """Build and validate a `ServerConfig` (missing keys keep their defaults)."""
    if not isinstance(data, Mapping):
        raise InputError("config", f"must be a table, got {kind_of(data)}")
    known = {f.name for f in fields(ServerConfig)}
    hints = typing.get_type_hints(ServerConfig)
    sections: dict[str, Any] = {}
    for key, value in data.items():
        if key not in known:
            raise InputError(key, f"unknown section; allowed: {', '.join(sorted(known))}")
        sections[key] = section_from_dict(hints[key], value, key)
    config = ServerConfig(**sections)
    _check_cross_field(config)
    return config


def _check_cross_field(config: ServerConfig) -> None:
    token = config.security.token
    if token and len(token) < MIN_TOKEN_LENGTH:
        raise InputError(
            "security.token", f"must be at least {MIN_TOKEN_LENGTH} characters, got {len(token)}"
        )
    if token and (token != token.strip() or not token.isprintable()):
        raise InputError("security.token", "must be printable with no surrounding whitespace")
    if config.scheduler.queue_per_session > config.scheduler.queue_total:
        raise InputError(
            "scheduler.queue_per_session",
            f"must not exceed scheduler.queue_total ({config.scheduler.queue_total})",
        )
    if config.limits.max_request_bytes > config.limits.memory_budget_bytes:
        raise InputError(
            "limits.max_request_bytes",
            f"must not exceed limits.memory_budget_bytes ({config.limits.memory_budget_bytes})",
        )
    if config.stream.enabled and config.stream.port != 0 and config.stream.port == config.http.port:
        raise InputError("stream.port", f"must differ from http.port ({config.http.port})")
    for index, directory in enumerate(config.security.environment_dirs):
        if not os.path.isabs(directory):
            raise InputError(
                f"security.environment_dirs[{index}]", f"must be an absolute path, got {directory}"
            )


def server_config_to_dict(config: ServerConfig) -> dict[str, dict[str, Any]]:
    return {
        section.name: {
            f.name: list(v)
            if isinstance(v := getattr(getattr(config, section.name), f.name), tuple)
            else v
            for f in fields(getattr(config, section.name))
        }
        for section in fields(ServerConfig)
    }


def load_server_config(path: str | Path | None) -> ServerConfig:
    """Read a server TOML file (None = defaults); then apply ``$SPHRENDER_TOKEN`` if set."""
    data: dict[str, Any] = {}
    if path is not None:
        try:
            with open(path, "rb") as handle:
                data = tomllib.load(handle)
        except OSError as exc:
            raise InputError("config", f"cannot read {path}: {exc.strerror or exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise InputError("config", f"{path} is not valid TOML: {exc}") from None
    config = server_config_from_dict(data)
    token = os.environ.get(TOKEN_ENV)
    if token:
        config = config.with_overrides({"security": {"token": token}})
    return config


def public_limits(config: ServerConfig) -> dict[str, Any]:
    """The limits a client needs to know (reported by /v1/info and the stream WELCOME)."""
    return {
        "max_particles": config.limits.max_particles,
        "max_pixels": config.limits.max_pixels,
        "max_body_bytes": config.http.max_body_bytes,
        "max_sessions": config.limits.max_sessions,
        "max_stream_connections": config.stream.max_connections,
        "max_scene_bytes": config.limits.max_scene_bytes,
        "max_request_bytes": config.limits.max_request_bytes,
        "session_idle_timeout_s": config.limits.session_idle_timeout_s,
        "max_in_flight": config.stream.max_in_flight,
        "max_header_bytes": config.stream.max_header_bytes,
        "max_payload_bytes": config.stream.max_payload_bytes,
        "queue_per_session": config.scheduler.queue_per_session,
        "queue_total": config.scheduler.queue_total,
    }


def is_loopback(host: str) -> bool:
    """True when every address `host` resolves to is a loopback address."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    addresses = {info[4][0] for info in infos}
    return bool(addresses) and all(
        ipaddress.ip_address(str(a).split("%")[0]).is_loopback for a in addresses
    )


def check_bind_policy(config: ServerConfig) -> None:
    """Refuse a non-loopback bind without a token unless explicitly allowed (see security)."""
    if config.security.token or config.security.allow_remote_without_token:
        return
    hosts = {"http.host": config.http.host}
    for key, host in hosts.items():
        if not is_loopback(host):
            raise InputError(
                key,
                f"{host} is not a loopback address: set a token (security.token or "
                f"${TOKEN_ENV}) or pass --allow-remote-without-token",
            )
