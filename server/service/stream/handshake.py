"""The stream's handshake: what a HELLO may say and what WELCOME answers (PROTOCOL.md §4.1).

`check_hello` validates a HELLO's framing and keys (raising `ProtocolError` with the code the
protocol documents); `welcome_header` builds the WELCOME: the session, the mode, the pipelining
depth, the limits, every timeout the stream applies (``timeouts``, distinct from the HTTP
sessions' ``limits.session_idle_timeout_s``) and the session's scene with every default filled
in (``scene``), so a client learns the default camera without reading the server's source.
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass
from typing import Any, Literal

from sphrender.core.errors import show
from sphrender.core.frame_message import ENCODINGS
from sphrender.core.protocol import ErrorCode, MessageType, ProtocolError
from sphrender.server.scene import Scene, scene_to_dict
from sphrender.server.service.config import ServerConfig, public_limits

HELLO_KEYS = ("token", "scene", "mode", "max_in_flight", "client")
#: After GOODBYE, how long the writer waits for the client to close before closing itself.
LINGER_S = 2.0
#: A connection still without a session this long after connecting may be evicted for another.
EVICT_HANDSHAKE_AFTER_S = 1.0


@dataclass(frozen=True)
class Hello:
    mode: Literal["queue", "latest"]
    max_in_flight: int
    scene: dict[str, Any]


def check_hello(
    kind: MessageType,
    header: dict[str, Any],
    payload_len: int,
    config: ServerConfig,
    *,
    authenticated: bool = False,
) -> Hello:
    """The HELLO's settings, or `ProtocolError` (fatal: the connection closes after it).
    `authenticated`: the transport checked the token already; a token HELLO carries must
    still match."""
    if kind != MessageType.HELLO:
        raise ProtocolError(ErrorCode.PROTOCOL, f"expected HELLO, got {kind.name}", "type")
    if payload_len:
        raise ProtocolError(ErrorCode.PROTOCOL, "HELLO has no payload", "payload_length")
    for key in header:
        if key not in HELLO_KEYS:
            raise ProtocolError(
                ErrorCode.BAD_INPUT,
                f"unknown key; allowed: {', '.join(sorted(HELLO_KEYS))}",
                f"header.{key}",
            )
    if not (authenticated and "token" not in header):
        _check_token(header.get("token"), config.security.token)
    scene = header.get("scene", {})
    if not isinstance(scene, dict):
        raise ProtocolError(ErrorCode.BAD_INPUT, "must be a JSON object", "scene")
    return Hello(
        _mode(header.get("mode", "queue")),
        _max_in_flight(header.get("max_in_flight"), config.stream.max_in_flight),
        scene,
    )


def _check_token(presented: Any, token: str | None) -> None:
    if not token:
        return
    given = presented.encode("utf-8") if isinstance(presented, str) else b""
    if not hmac.compare_digest(given, token.encode("utf-8")):
        raise ProtocolError(ErrorCode.UNAUTHORIZED, "missing or wrong token", "token")


def _mode(value: Any) -> Literal["queue", "latest"]:
    if value == "queue":
        return "queue"
    if value == "latest":
        return "latest"
    raise ProtocolError(
        ErrorCode.BAD_INPUT, f'must be "queue" or "latest", got {show(value)}', "mode"
    )


def _max_in_flight(value: Any, limit: int) -> int:
    if value is None:
        return limit
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= limit:
        raise ProtocolError(
            ErrorCode.BAD_INPUT,
            f"must be an integer in [1, {limit}], got {show(value)}",
            "max_in_flight",
        )
    return value


def stream_timeouts(config: ServerConfig) -> dict[str, float]:
    """Every deadline the stream applies to a connection, in seconds (PROTOCOL.md §5)."""
    return {
        "handshake_s": config.stream.handshake_timeout_s,
        "idle_s": config.stream.idle_timeout_s,
        "message_s": config.stream.message_timeout_s,
        "write_s": config.stream.write_timeout_s,
        "render_s": config.limits.render_timeout_s,
        "drain_read_s": config.lifecycle.drain_read_timeout_s,
        "linger_s": LINGER_S,
        "evict_handshake_s": EVICT_HANDSHAKE_AFTER_S,
        "evict_idle_s": config.stream.evict_idle_s,
    }


def welcome_header(
    session_id: str,
    scene: Scene,
    hello: Hello,
    config: ServerConfig,
    server: dict[str, Any],
) -> dict[str, Any]:
    return {
        "session": session_id,
        "mode": hello.mode,
        "max_in_flight": hello.max_in_flight,
        "limits": public_limits(config),
        "frame_encodings": list(ENCODINGS),
        "timeouts": stream_timeouts(config),
        "scene": scene_to_dict(scene),
        "server": server,
    }
