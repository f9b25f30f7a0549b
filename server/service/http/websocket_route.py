"""``GET /v1/stream``: the WebSocket upgrade (RFC 6455 section 4) onto the stream protocol.

The request has already passed the HTTP token rule (`HandlerBase._check_auth`: a bearer
token, or on this GET the viewer's cookie). Here, before anything is upgraded, each refusal is
the API's JSON error: an ``Origin`` that is neither this server's own (scheme + ``Host``) nor
listed in ``security.allowed_origins`` (403; a request without ``Origin`` is no browser's and
passes), a missing or wrong ``Upgrade``/``Connection``/``Sec-WebSocket-Key`` (400) or version
(426 with ``Sec-WebSocket-Version: 13``), and a draining server (503). Then 101, and the
handler thread carries a `WebSocketConnection` (stream/websocket.py) until it ends; the
connection counts against ``stream.max_connections`` with the stream port's.

Subprotocol ``sphrender.stream.v1`` is selected when offered (never required); no extensions
are negotiated (images are compressed already).
"""

from __future__ import annotations

import base64
import binascii

from wsproto.utilities import generate_accept_token

from sphrender.core.errors import show
from sphrender.core.protocol import ErrorCode
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.handler import HandlerBase
from sphrender.server.service.stream.registry import StreamConnections
from sphrender.server.service.stream.websocket import WebSocketConnection

#: The path of the upgrade and the subprotocol it selects when a client offers it.
STREAM_PATH = "/v1/stream"
SUBPROTOCOL = "sphrender.stream.v1"


def _tokens(value: str) -> list[str]:
    return [part.strip().lower() for part in value.split(",") if part.strip()]


class WebSocketRoute:
    """The upgrade of one request on `http` (module docstring)."""

    def __init__(self, http: HandlerBase, service: ServiceFacade, table: StreamConnections) -> None:
        self.http = http
        self.service = service
        self.table = table

    def upgrade(self) -> None:
        trailing = self.accept()
        http = self.http
        WebSocketConnection(
            http.connection, http.client_address, self.service, self.table, trailing=trailing
        ).run()

    def accept(self) -> bytes:
        """Check the upgrade and answer 101; returns what the client sent after its request
        (the start of its first frames). Every refusal raises `HttpError` before any 101."""
        headers = self.http.headers
        self._check_origin(headers.get("Origin"), headers.get("Host", ""))
        key = self._check_upgrade_headers()
        if self.service.draining.is_set():
            raise HttpError(
                503, ErrorCode.SHUTTING_DOWN, "the server is shutting down", retry_after_s=1
            )
        offered = _tokens(headers.get("Sec-WebSocket-Protocol", ""))
        http = self.http
        http._count_request(101)
        http.send_response(101)
        http.send_header("Upgrade", "websocket")
        http.send_header("Connection", "Upgrade")
        accept = generate_accept_token(key.encode("ascii")).decode("ascii")
        http.send_header("Sec-WebSocket-Accept", accept)
        if SUBPROTOCOL in offered:
            http.send_header("Sec-WebSocket-Protocol", SUBPROTOCOL)
        http.end_headers()
        http.close_connection = True  # after the WebSocket, no more HTTP on this socket
        http._reader.detach()
        return http.rfile.read1(1 << 16) or b""

    def _check_origin(self, origin: str | None, host: str) -> None:
        if origin is None:
            return
        allowed = {f"http://{host}".lower(), f"https://{host}".lower()}
        allowed.update(o.lower().rstrip("/") for o in self.service.config.security.allowed_origins)
        if origin.strip().lower().rstrip("/") not in allowed:
            raise HttpError(
                403,
                ErrorCode.UNAUTHORIZED,
                f"origin {show(origin, 80)} may not open the stream: only this server's own "
                "pages and security.allowed_origins may",
                "Origin",
            )

    def _check_upgrade_headers(self) -> str:
        """The client's key, once the upgrade headers are as RFC 6455 section 4.1 requires."""
        headers = self.http.headers
        if "websocket" not in _tokens(headers.get("Upgrade", "")):
            raise HttpError(
                426,
                ErrorCode.BAD_INPUT,
                f"{STREAM_PATH} speaks WebSocket only: send Upgrade: websocket",
                "Upgrade",
                headers={"Upgrade": "websocket", "Connection": "Upgrade"},
            )
        if "upgrade" not in _tokens(headers.get("Connection", "")):
            raise HttpError(400, ErrorCode.BAD_INPUT, "must include Upgrade", "Connection")
        if headers.get("Sec-WebSocket-Version", "").strip() != "13":
            raise HttpError(
                426,
                ErrorCode.UNSUPPORTED_VERSION,
                "WebSocket version 13 (RFC 6455) is the only one spoken",
                "Sec-WebSocket-Version",
                headers={"Sec-WebSocket-Version": "13"},
            )
        key = headers.get("Sec-WebSocket-Key", "").strip()
        try:
            valid = len(base64.b64decode(key, validate=True)) == 16
        except (binascii.Error, ValueError):
            valid = False
        if not valid:
            raise HttpError(
                400,
                ErrorCode.BAD_INPUT,
                "must be 16 random bytes in base64 (24 characters)",
                "Sec-WebSocket-Key",
            )
        return key
