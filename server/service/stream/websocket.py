"""The stream protocol over WebSocket (RFC 6455), for browsers: PROTOCOL.md §10.

The HTTP route (`http/websocket_route.py`) checks the upgrade and hands the socket to a
`WebSocketConnection`: the stream connection of `connection.py` (handshake, reader, writer,
answers, idle and drain rules, latest-frame-wins) over a `WebSocketChannel` instead of raw TCP.
Each stream message travels as exactly one binary WebSocket message, in both directions; a
client may fragment it into any number of frames. wsproto (sans-IO) parses and builds the frames;
this module only moves bytes and decides what each protocol violation closes with:

* a frame that breaks RFC 6455 (unmasked client frame, reserved bits, bad opcode, fragmented
  control frame): Close 1002, a reason in words;
* a text message: Close 1003; a message over the stream's own limit (16-byte prefix +
  ``stream.max_header_bytes`` + ``stream.max_payload_bytes``, reported in WELCOME): Close 1009;
* a stream message not exactly filling its WebSocket message: Close 1002;
* after a fatal stream ERROR, Close with the code `CLOSE_CODES` maps its ``code`` to; after
  GOODBYE, Close 1000 (1001 when the server is shutting down).

A Close from the client abandons the session: what it still had in flight is cancelled.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from wsproto.connection import Connection, ConnectionState, ConnectionType
from wsproto.events import (
    BytesMessage,
    CloseConnection,
    Event,
    Ping,
    TextMessage,
)

from sphrender.core.protocol import PREFIX_SIZE, ErrorCode
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.stream.connection import Connections, StreamConnection
from sphrender.server.service.stream.handshake import LINGER_S
from sphrender.server.service.stream.wire import Channel, Closed, linger

#: The WebSocket close code that follows a fatal stream ERROR, by the ERROR's ``code``.
CLOSE_CODES = {
    ErrorCode.PROTOCOL: 1002,
    ErrorCode.UNSUPPORTED_VERSION: 1002,
    ErrorCode.BAD_INPUT: 1007,
    ErrorCode.UNAUTHORIZED: 1008,
    ErrorCode.TIMEOUT: 1008,
    ErrorCode.NOT_FOUND: 1008,
    ErrorCode.TOO_LARGE: 1009,
    ErrorCode.RENDER_FAILED: 1011,
    ErrorCode.SHUTTING_DOWN: 1001,
    ErrorCode.BUSY: 1013,
}
#: Bytes asked of the socket per read (a message's data is handed on as it arrives).
_READ_BYTES = 1 << 18
#: What wsproto's frame errors mean, in this protocol's words (anything else: generic).
_FRAME_ERRORS = {
    "unmasked": "client frames must be masked (RFC 6455 section 5.1)",
    "reserved bit": "reserved bits set without a negotiated extension (RFC 6455 section 5.2)",
    "opcode": "unknown WebSocket opcode (RFC 6455 section 5.2)",
    "control frame": "control frames must be unfragmented and at most 125 bytes (section 5.5)",
    "continuation": "a continuation frame without a message to continue, or a new message "
    "inside a fragmented one (RFC 6455 section 5.4)",
    "utf-8": "a close reason that is not UTF-8 (RFC 6455 section 5.5.1)",
}


def max_message_bytes(service: ServiceFacade) -> int:
    """The largest WebSocket message accepted: one stream message at the stream's limits."""
    stream = service.config.stream
    return PREFIX_SIZE + stream.max_header_bytes + stream.max_payload_bytes


def frame_error_text(detail: str) -> str:
    lowered = detail.lower()
    for needle, text in _FRAME_ERRORS.items():
        if needle in lowered:
            return text
    return "malformed WebSocket frame (RFC 6455 section 5.2)"


class WebSocketChannel(Channel):
    """A `Channel` whose bytes are the payloads of binary WebSocket messages, one stream
    message per WebSocket message (module docstring). Reads keep the stream's deadlines; the
    socket is read only when the reader needs bytes, so a FRAME is still judged from its header
    before its payload is received."""

    def __init__(
        self,
        sock: socket.socket,
        *,
        trailing: bytes,
        max_message_bytes: int,
        message_timeout_s: float,
        gone: Callable[[], None],
        **options: Any,
    ) -> None:
        super().__init__(sock, **options)
        self._message_timeout_s = message_timeout_s
        #: When bytes of a frame that has yielded nothing yet arrived: a message has begun.
        self._partial_since: float | None = None
        self._ws = Connection(ConnectionType.SERVER)
        self._lock = threading.Lock()  # wsproto's state and whole frames on the socket
        self._unfed = trailing  # bytes that came with the upgrade request
        self._max = max_message_bytes
        self._gone = gone
        self._chunks: deque[tuple[bytes, bool]] = deque()  # (data, ends its message)
        self._offset = 0  # bytes of the first chunk already handed on
        self._in_message = False  # the reader is inside a message whose end it has not taken
        self._received = 0  # bytes of the message being received (the size limit)
        self._closing = False  # our Close frame is sent
        self._lingered = False

    # -- reading ----------------------------------------------------------------------------------

    def recv_into(
        self, buffer: bytearray | memoryview, deadline: float, *, idle_deadline: float | None = None
    ) -> None:
        view = memoryview(buffer).cast("B")
        first = idle_deadline is not None
        if idle_deadline is not None:
            idle_deadline = self._take_boundary(deadline, idle_deadline)
        got = 0
        while got < len(view):
            if not self._chunks:
                starting = first and not got and not self._in_message
                if starting and self._partial_since is not None:  # a frame has begun
                    limit = self._partial_since + self._message_timeout_s
                    self._pull(limit, True, None)
                    continue
                idle_deadline = self._pull(deadline, not starting, idle_deadline)
                continue
            data, ends = self._chunks[0]
            n = min(len(data) - self._offset, len(view) - got)
            view[got : got + n] = data[self._offset : self._offset + n]
            self._offset += n
            got += n
            self._in_message = True
            if self._offset < len(data):
                continue
            self._chunks.popleft()
            self._offset = 0
            if ends:
                self._in_message = False
                if got < len(view):
                    self._fail(
                        1002,
                        "each stream message must be exactly one binary WebSocket message; "
                        "this one ended inside a stream message",
                    )

    def _take_boundary(self, deadline: float, idle_deadline: float | None) -> float | None:
        """Before a stream message: the previous WebSocket message must be over. Bytes it
        carried past its stream message are read to its end (so its size decides: 1009 once
        over the limit, else 1002), never kept."""
        excess = 0
        while self._in_message:
            if not self._chunks:
                idle_deadline = self._pull(deadline, False, idle_deadline)
                continue
            data, ends = self._chunks.popleft()
            excess += len(data) - self._offset
            self._offset = 0
            self._in_message = not ends
        if excess:
            self._fail(
                1002,
                "each stream message must be exactly one binary WebSocket message; "
                f"the last one went on {excess} bytes past its stream message",
            )
        return idle_deadline

    def _pull(self, deadline: float, started: bool, idle_deadline: float | None) -> float | None:
        """One socket read fed to wsproto and its events handled; returns the idle deadline."""
        if self._unfed:
            data, self._unfed = self._unfed, b""
        else:
            limit = self._wait_limit(deadline, started, idle_deadline)
            if not started:
                idle_deadline = limit
            try:
                data = self.sock.recv(_READ_BYTES)
            except TimeoutError:
                return idle_deadline
            except OSError:
                raise Closed("gone") from None
            if not data:
                raise Closed("vanished" if started or self._in_message else "eof")
        with self._lock:
            self._ws.receive_data(data)
            events = list(self._ws.events())
        if events:
            self._partial_since = None
        elif self._partial_since is None:
            self._partial_since = time.monotonic()
        for event in events:
            self._handle(event)
        return idle_deadline

    def _handle(self, event: Event) -> None:
        if isinstance(event, BytesMessage):
            self._received += len(event.data)
            if self._received > self._max:
                self._fail(
                    1009,
                    f"message over the limit of {self._max} bytes (16 + stream.max_header_bytes"
                    " + stream.max_payload_bytes)",
                    "too_large",
                )
            self._chunks.append((bytes(event.data), event.message_finished))
            if event.message_finished:
                self._received = 0
        elif isinstance(event, TextMessage):
            self._fail(1003, "text messages are not part of this protocol; send binary messages")
        elif isinstance(event, Ping):
            self._send_event(event.response())
        elif isinstance(event, CloseConnection):
            if self._ws.state is ConnectionState.REMOTE_CLOSING:  # the client's Close
                self._send_event(CloseConnection(code=1000, reason="closed by the client"))
                self._closing = True
                self._gone()
                raise Closed("client_close")
            self._fail(event.code, frame_error_text(event.reason or ""))

    # -- writing and closing ----------------------------------------------------------------------

    def _send_event(self, event: Event) -> None:
        with self._lock:
            if self._ws.state not in (ConnectionState.OPEN, ConnectionState.REMOTE_CLOSING):
                return
            data = self._ws.send(event)
            with contextlib.suppress(Closed):
                super().send_all(data)

    def _fail(self, code: int, reason: str, end: str = "protocol") -> None:
        """Close with `code` and `reason` (a violation found while reading) and end reading."""
        self._close(code, reason)
        raise Closed(end)

    def _close(self, code: int, reason: str) -> None:
        if not self._closing:
            self._closing = True
            self._send_event(CloseConnection(code=code, reason=reason))

    def send_all(self, data: bytes) -> None:
        """One stream message as one binary WebSocket message."""
        with self._lock:
            if self._closing or self._ws.state is not ConnectionState.OPEN:
                raise Closed("gone")
            super().send_all(self._ws.send(BytesMessage(data=data)))

    def close_for_error(self, code: str, message: str) -> None:
        self._close(CLOSE_CODES.get(code, 1011), f"{code}: {message}")

    def end_orderly(self, reason: str, seconds: float) -> None:
        self._close(1001 if reason == "shutdown" else 1000, reason)
        self._lingered = True
        linger(self.sock, seconds)

    def shutdown(self) -> None:
        """After our Close, wait (bounded) for the client's before closing: closing with
        unread bytes would reset the connection and could destroy the Close on its way."""
        if self._closing and not self._lingered:
            self._lingered = True
            linger(self.sock, LINGER_S)
        super().shutdown()


class WebSocketConnection(StreamConnection):
    """A stream connection over a WebSocket the HTTP route has upgraded (module docstring)."""

    def __init__(
        self,
        sock: socket.socket,
        peer: Any,
        service: ServiceFacade,
        server: Connections,
        *,
        trailing: bytes = b"",
    ) -> None:
        self._trailing = trailing
        super().__init__(sock, peer, service, server)
        # The upgrade passed the HTTP token rule: HELLO needs no token of its own.
        self.authenticated = True

    def _make_channel(self, sock: socket.socket) -> Channel:
        return WebSocketChannel(
            sock,
            trailing=self._trailing,
            max_message_bytes=max_message_bytes(self.service),
            message_timeout_s=self.config.message_timeout_s,
            gone=self.answers.dead.set,
            **self._channel_options(),
        )

    def run(self) -> None:
        try:
            super().run()
        finally:
            self.channel.shutdown()
