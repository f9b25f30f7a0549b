"""The streaming socket for live frontends (the wire format is specified in PROTOCOL.md).

One connection = one session. Per connection there are two threads:

* the **reader** (the socketserver handler thread) reads a message, validates it and, for a
  FRAME, appends an answer slot to the connection's ordered answer list *before* queueing the
  job, so answers leave in the order frames arrived whatever happens to each frame;
* the **writer** takes the slots in order, waits for each one's outcome (image, error or dropped)
  and sends it.

Backpressure: the reader stops reading while ``max_in_flight`` frames are unanswered. In ``queue``
mode a frame waits for room in the scheduler (nothing is dropped); in ``latest`` mode a new frame
supersedes the session's frames that have not started rendering, which are answered DROPPED.

Every wait is bounded: the HELLO within ``handshake_timeout_s``; a started message within
``message_timeout_s``; with nothing in flight, the next message within ``idle_timeout_s``; an
answer must be taken by the client within ``write_timeout_s``. The socket is polled with a short
timeout so the threads also notice a drain or the other thread's failure quickly.

Framing errors (bad magic, unknown type, oversized lengths, a header that is not JSON, a frame
without a usable id) are fatal: the connection gets one ERROR with ``"id": null`` after the
answers already owed, then closes. Errors in a frame's content answer that frame only.

A FRAME is judged from its header before its payload is read: the arrays must add up to
``payload_length``, the particles must be within the limits and the frame's memory estimate
must fit the budget (`admission.py`); a refused frame's payload is read and dropped in small
chunks, never allocated. Every decode step runs inside `admission.decoding`, so no client
input can raise anything but a documented error; any other failure of the reader ends the
connection with a fatal ERROR after the owed answers, and the writer always finishes.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from typing import Any, Protocol

from sphrender.core.errors import InputError
from sphrender.core.protocol import (
    ErrorCode,
    LimitError,
    MessageType,
    ProtocolError,
    encode_message,
)
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.render.scheduler import SchedulerClosed
from sphrender.server.service.sessions import WARM_FAILED, Session, SessionLimitReached
from sphrender.server.service.stream.answers import Answers
from sphrender.server.service.stream.handshake import Hello, check_hello, welcome_header
from sphrender.server.service.stream.reader import FrameReader, read_head
from sphrender.server.service.stream.wire import Channel, Closed
from sphrender.server.service.stream.writer import AnswerWriter, send_counted

log = logging.getLogger("sphrender.service.stream")


class Connections(Protocol):
    """What a connection needs of its listener (listener.StreamServer)."""

    def register(self, connection: StreamConnection) -> bool: ...

    def unregister(self, connection: StreamConnection) -> None: ...


class StreamConnection:
    """One client connection: the handshake, then a `FrameReader` on this thread and an
    `AnswerWriter` on another (see the module docstring)."""

    def __init__(
        self, sock: socket.socket, peer: Any, service: ServiceFacade, server: Connections
    ) -> None:
        self.sock = sock
        self.peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        self.service = service
        self.server = server
        self.config = service.config.stream
        self.answers = Answers()
        self.session: Session | None = None
        self.hello: Hello | None = None
        self.connected_at = time.monotonic()
        self.welcomed = False
        self.channel = self._make_channel(sock)

    def _make_channel(self, sock: socket.socket) -> Channel:
        """The transport under the stream's messages (a WebSocket connection overrides it)."""
        return Channel(sock, **self._channel_options())

    def _channel_options(self) -> dict[str, Any]:
        """The deadlines and states a channel reads (the stream's idle and drain rules)."""
        service = self.service
        return {
            "idle_timeout_s": self.config.idle_timeout_s,
            "write_timeout_s": self.config.write_timeout_s,
            "dead": self.answers.dead.is_set,
            "draining": self.answers.draining.is_set,
            "evicted": self.answers.evicted.is_set,
            "drain_deadline": lambda: service.drain_read_deadline,
            "in_flight": lambda: self.answers.owed,
        }

    #: True when the transport authenticated the client already (a WebSocket upgrade that
    #: passed the HTTP token rule): HELLO then needs no token, though one it carries is checked.
    authenticated = False

    def begin_drain(self) -> None:
        self.answers.draining.set()

    def evict(self) -> None:
        """Close a connection that has not finished its handshake (room for a newcomer)."""
        self.answers.dead.set()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)

    def idle_for(self, now: float) -> float:
        """Seconds this session has been idle (0 before its WELCOME or with a frame in flight)."""
        return self.answers.idle_for(now) if self.welcomed else 0.0

    def evict_idle(self) -> None:
        """End an idle session with GOODBYE ``evicted`` (room for a newcomer)."""
        self.answers.evicted.set()

    def _send_fatal(self, code: str, message: str, field: str | None) -> None:
        """An immediate fatal ERROR (handshake only; later ones go through the answer list)."""
        with contextlib.suppress(Closed):
            send_counted(
                self.channel,
                self.service,
                encode_message(
                    MessageType.ERROR,
                    {"id": None, "code": code, "error": message, "field": field, "fatal": True},
                ),
            )
        self.channel.close_for_error(code, message)

    def run(self) -> None:
        end = "gone"
        try:
            if not self.server.register(self):
                message = (
                    "too many stream connections (stream.max_connections) and none idle for "
                    f"stream.evict_idle_s ({self.config.evict_idle_s:g} s); retry later"
                )
                self._send_fatal(ErrorCode.BUSY, message, None)
                end = "busy"
                return
            try:
                end = self._handshake()
                if end != "ok":
                    return
                end = self._serve()
            finally:
                self.server.unregister(self)
        finally:
            # Counted before the session goes, so "no stream session open" implies "every
            # ended connection is counted" for anyone reading /metrics.
            self.service.metrics.transport.connections.inc(end)
            if self.session is not None:
                self.service.close_session(self.session.id)
            log.info(
                "stream connection ended",
                extra={
                    "event": "stream_end",
                    "peer": self.peer,
                    "reason": end,
                    "session": self.session.id if self.session else None,
                },
            )

    def _serve(self) -> str:
        """After the handshake: the reader here, the writer on its own thread."""
        assert self.session is not None and self.hello is not None
        session, hello = self.session, self.hello
        writer = AnswerWriter(
            self.sock, self.channel, self.service, self.answers, session.id, self.peer
        )
        thread = threading.Thread(target=writer.run, name="sphrender-stream-writer", daemon=True)
        thread.start()
        reader = FrameReader(
            self.channel,
            self.service,
            self.answers,
            session,
            hello.mode,
            hello.max_in_flight,
            self.peer,
        )
        try:
            return reader.run()
        finally:  # whatever happened, the writer answers what is owed and ends
            self.answers.finish_reading()
            thread.join()

    def _handshake(self) -> str:
        deadline = time.monotonic() + self.config.handshake_timeout_s
        try:
            kind, header, payload_len, _deadline = read_head(
                self.channel, self.service, deadline, deadline
            )
        except Closed as closed:
            if closed.reason in ("slow", "idle_timeout"):
                self._send_fatal(ErrorCode.TIMEOUT, "no HELLO within handshake_timeout_s", None)
                return "timeout"
            return closed.reason
        except ProtocolError as exc:
            self._send_fatal(exc.code, exc.message, exc.field)
            return "protocol"
        try:
            hello = check_hello(
                kind, header, payload_len, self.service.config, authenticated=self.authenticated
            )
            self.hello = hello
            self.session = self.service.create_session(hello.scene, "stream")
        except ProtocolError as exc:
            self._send_fatal(exc.code, exc.message, exc.field)
            return "unauthorized" if exc.code == ErrorCode.UNAUTHORIZED else "handshake"
        except InputError as exc:
            code = ErrorCode.TOO_LARGE if isinstance(exc, LimitError) else ErrorCode.BAD_INPUT
            self._send_fatal(code, exc.message, exc.field)
            return "handshake"
        except SessionLimitReached:
            self._send_fatal(ErrorCode.BUSY, "too many sessions (limits.max_sessions)", None)
            return "busy"
        except SchedulerClosed:
            self._send_fatal(ErrorCode.SHUTTING_DOWN, "the server is shutting down", None)
            return "shutdown"
        except Exception as exc:  # GL failure while warming the scene, or a warm timeout
            log.warning("warm failed", extra={"event": "warm_failed", "detail": str(exc)})
            self._send_fatal(ErrorCode.RENDER_FAILED, WARM_FAILED, None)
            return "handshake"
        info = self.service.info()
        server = {
            "version": info["version"],
            "gl_renderer": self.service.worker.gl_renderer,
            **{key: info[key] for key in ("opencl", "formats", "raw_types", "frame_arrays")},
        }
        welcome = welcome_header(
            self.session.id, self.session.scene, hello, self.service.config, server
        )
        try:
            send_counted(self.channel, self.service, encode_message(MessageType.WELCOME, welcome))
        except Closed as closed:
            return closed.reason
        self.answers.last_active = time.monotonic()
        self.welcomed = True
        return "ok"
