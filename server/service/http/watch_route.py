"""``GET /v1/sessions/{id}/watch``: a WebSocket on which the server pushes every new image of a
session (any transport), for viewers (PROTOCOL.md §10.1).

The upgrade is checked as ``/v1/stream``'s (`WebSocketRoute.accept`: token, origin, headers,
drain), and an unknown session is 404 before it. Then each image the session answers, in a
format a browser shows and kept for viewers (`sessions.VIEWABLE_FORMATS`), goes out as one
binary message holding an IMAGE message (PROTOCOL.md §2 framing) whose header is ``{"session",
"image", "format", "width", "height"}`` (``image``: the session's image number, as
``X-Sphrender-Image``); images answered faster than the viewer reads are skipped, never queued.
When the session ends: GOODBYE ``{"reason": "session_closed"}`` and Close 1000; when the server
drains: Close 1001. The client only listens: a data message from it closes 1003; pings are
answered. Watching does not keep a session alive.
"""

from __future__ import annotations

import contextlib
import socket

from wsproto.connection import Connection, ConnectionState, ConnectionType
from wsproto.events import BytesMessage, CloseConnection, Event, Ping, TextMessage

from sphrender.core.protocol import ErrorCode, MessageType, encode_message
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.handler import HandlerBase
from sphrender.server.service.http.websocket_route import WebSocketRoute
from sphrender.server.service.stream.handshake import LINGER_S
from sphrender.server.service.stream.registry import StreamConnections
from sphrender.server.service.stream.websocket import frame_error_text
from sphrender.server.service.stream.wire import linger

#: How often the watcher looks for a new image and for the client's frames (seconds).
WATCH_TICK_S = 0.03


def watch_session(
    http: HandlerBase, service: ServiceFacade, streams: StreamConnections, session_id: str
) -> None:
    """The route: 404 for an unknown session, then the upgrade and the watch."""
    if service.sessions.get(session_id, touch=False) is None:
        raise HttpError(404, ErrorCode.NOT_FOUND, "no such session (closed or expired)", "session")
    trailing = WebSocketRoute(http, service, streams).accept()
    SessionWatch(http.connection, service, session_id, trailing).run()


class SessionWatch:
    """One watching connection, run on its HTTP handler thread after the 101."""

    def __init__(
        self, sock: socket.socket, service: ServiceFacade, session_id: str, trailing: bytes
    ) -> None:
        self.sock = sock
        self.service = service
        self.session_id = session_id
        self.ws = Connection(ConnectionType.SERVER)
        self.trailing = trailing
        self.sent = 0  # the number of the last image sent

    def run(self) -> None:
        self.sock.settimeout(WATCH_TICK_S)
        try:
            if self.trailing:
                self._feed(self.trailing)
            while self.ws.state is ConnectionState.OPEN and self._push():
                try:
                    data = self.sock.recv(1 << 16)
                except TimeoutError:
                    continue
                if not data:
                    return
                self._feed(data)
        except OSError:
            return  # the client went away (a send failed or timed out)
        finally:
            if self.ws.state is ConnectionState.LOCAL_CLOSING:
                linger(self.sock, LINGER_S)
            with contextlib.suppress(OSError):
                self.sock.shutdown(socket.SHUT_RDWR)

    def _push(self) -> bool:
        """Send the session's newest image if it is new; False once the watch is over."""
        if self.service.draining.is_set():
            self._close(1001, "the server is shutting down")
            return False
        session = self.service.sessions.get(self.session_id, touch=False)
        if session is None:
            self._send(encode_message(MessageType.GOODBYE, {"reason": "session_closed"}))
            self._close(1000, "session closed")
            return False
        latest = session.latest
        if latest is not None and latest.seq != self.sent and latest.data is not None:
            header = {
                "session": self.session_id,
                "image": latest.seq,
                "format": latest.format,
                "width": latest.width,
                "height": latest.height,
            }
            self._send(encode_message(MessageType.IMAGE, header, latest.data))
            self.sent = latest.seq
        return True

    def _feed(self, data: bytes) -> None:
        self.ws.receive_data(data)
        for event in self.ws.events():
            self._handle(event)

    def _handle(self, event: Event) -> None:
        if isinstance(event, Ping):
            self._send_event(event.response())
        elif isinstance(event, BytesMessage | TextMessage):
            self._close(1003, "this socket only sends images; send nothing but Close or ping")
        elif isinstance(event, CloseConnection):
            if self.ws.state is ConnectionState.REMOTE_CLOSING:
                self._send_event(CloseConnection(code=1000, reason="closed by the client"))
            else:
                self._close(event.code, frame_error_text(event.reason or ""))

    def _send(self, message: bytes) -> None:
        self._send_event(BytesMessage(data=message))
        self.service.metrics.transport.bytes_out.inc("http", amount=len(message))

    def _close(self, code: int, reason: str) -> None:
        if self.ws.state is ConnectionState.OPEN:
            self._send_event(CloseConnection(code=code, reason=reason))

    def _send_event(self, event: Event) -> None:
        data = self.ws.send(event)
        self.sock.settimeout(self.service.config.stream.write_timeout_s)
        try:
            self.sock.sendall(data)
        finally:
            self.sock.settimeout(WATCH_TICK_S)
