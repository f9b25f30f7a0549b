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
import socketserver
import threading
import time
from collections import deque
from typing import Any, ClassVar, Literal, cast

from sphrender.core.errors import InputError, show
from sphrender.core.frame import ParticleFrame
from sphrender.core.protocol import (
    MAX_FRAME_ID,
    PREFIX_SIZE,
    ErrorCode,
    LimitError,
    MessageType,
    ProtocolError,
    decode_frame_arrays,
    encode_message,
    parse_header,
    parse_prefix,
    plan_frame_arrays,
)
from sphrender.server.scene import Scene, merge_scene_dicts
from sphrender.server.service.admission import Busy, Reservation, decoding, frame_estimate
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.render.jobs import ErrorOutcome, FrameJob, Outcome
from sphrender.server.service.render.scheduler import QueueFull, SchedulerClosed
from sphrender.server.service.sessions import Session, SessionLimitReached
from sphrender.server.service.stream.handshake import (
    EVICT_HANDSHAKE_AFTER_S,
    LINGER_S,
    check_hello,
    welcome_header,
)
from sphrender.server.service.stream.wire import (
    TICK_S,
    Channel,
    Closed,
    Slot,
    answer_bytes,
    linger,
)

log = logging.getLogger("sphrender.service.stream")

_FRAME_KEYS = ("id", "arrays", "scene")


class StreamConnection:
    """Both halves of one client connection (see the module docstring)."""

    def __init__(
        self, sock: socket.socket, peer: Any, service: ServiceFacade, server: StreamServer
    ) -> None:
        self.sock = sock
        self.peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        self.service = service
        self.server = server
        self.config = service.config.stream
        self._cond = threading.Condition()
        self._answers: deque[Slot] = deque()
        self._in_flight = 0
        self._reading_done = False
        self._goodbye: str | None = None
        self._dead = threading.Event()
        self._draining = threading.Event()
        self.session: Session | None = None
        self.mode: Literal["queue", "latest"] = "queue"
        self.max_in_flight = self.config.max_in_flight
        self.connected_at = time.monotonic()
        self.channel = Channel(
            sock,
            idle_timeout_s=self.config.idle_timeout_s,
            write_timeout_s=self.config.write_timeout_s,
            dead=self._dead.is_set,
            draining=self._draining.is_set,
            drain_deadline=lambda: service.drain_read_deadline,
            in_flight=lambda: self._in_flight,
        )

    def begin_drain(self) -> None:
        self._draining.set()

    def evict(self) -> None:
        """Close a connection that has not finished its handshake (room for a newcomer)."""
        self._dead.set()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)

    # -- socket I/O -----------------------------------------------------------------------------

    def _read_head(
        self, idle_deadline: float, message_deadline: float | None = None
    ) -> tuple[MessageType, dict[str, Any], int, float]:
        """A message's prefix and header; returns (type, header, payload length, deadline).
        The payload is left on the socket for the caller to read or discard."""
        first = self.channel.recv(1, message_deadline or 0.0, idle_deadline=idle_deadline)
        deadline = message_deadline or time.monotonic() + self.config.message_timeout_s
        prefix = first + self.channel.recv(PREFIX_SIZE - 1, deadline)
        kind, header_len, payload_len = parse_prefix(
            prefix,
            max_header_bytes=self.config.max_header_bytes,
            max_payload_bytes=self.config.max_payload_bytes,
        )
        header = parse_header(self.channel.recv(header_len, deadline)) if header_len else {}
        self.service.metrics.bytes_in.inc("stream", amount=PREFIX_SIZE + header_len)
        return kind, header, payload_len, deadline

    def _send_all(self, data: bytes) -> None:
        self.channel.send_all(data)
        self.service.metrics.bytes_out.inc("stream", amount=len(data))

    def _send_fatal(self, code: str, message: str, field: str | None) -> None:
        """An immediate fatal ERROR (handshake only; later ones go through the answer list)."""
        with contextlib.suppress(Closed):
            self._send_all(
                encode_message(
                    MessageType.ERROR,
                    {"id": None, "code": code, "error": message, "field": field, "fatal": True},
                )
            )

    # -- lifecycle ------------------------------------------------------------------------------

    def run(self) -> None:
        end = "gone"
        try:
            if not self.server.register(self):
                self._send_fatal(ErrorCode.BUSY, "too many stream connections", None)
                end = "busy"
                return
            try:
                end = self._handshake()
                if end != "ok":
                    return
                writer = threading.Thread(
                    target=self._write_loop, name="sphrender-stream-writer", daemon=True
                )
                writer.start()
                try:
                    end = self._read_loop()
                finally:  # whatever happened, the writer answers what is owed and ends
                    with self._cond:
                        self._reading_done = True
                        self._cond.notify_all()
                    writer.join()
            finally:
                self.server.unregister(self)
        finally:
            # Counted before the session goes, so "no stream session open" implies "every
            # ended connection is counted" for anyone reading /metrics.
            self.service.metrics.connections.inc(end)
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

    def _handshake(self) -> str:
        deadline = time.monotonic() + self.config.handshake_timeout_s
        try:
            kind, header, payload_len, _deadline = self._read_head(deadline, deadline)
        except Closed as closed:
            if closed.reason in ("slow", "idle_timeout"):
                self._send_fatal(ErrorCode.TIMEOUT, "no HELLO within handshake_timeout_s", None)
                return "timeout"
            return closed.reason
        except ProtocolError as exc:
            self._send_fatal(exc.code, exc.message, exc.field)
            return "protocol"
        try:
            hello = check_hello(kind, header, payload_len, self.service.config)
            self.mode, self.max_in_flight = hello.mode, hello.max_in_flight
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
            self._send_fatal(ErrorCode.RENDER_FAILED, f"preparing the scene failed: {exc}", None)
            return "handshake"
        server = {
            "version": self.service.info()["version"],
            "gl_renderer": self.service.worker.gl_renderer,
        }
        welcome = welcome_header(
            self.session.id, self.session.scene, hello, self.service.config, server
        )
        try:
            self._send_all(encode_message(MessageType.WELCOME, welcome))
        except Closed as closed:
            return closed.reason
        return "ok"

    # -- reader ---------------------------------------------------------------------------------

    def _read_loop(self) -> str:
        while True:
            with self._cond:
                while (
                    self._in_flight >= self.max_in_flight
                    and not self._dead.is_set()
                    and not self._draining.is_set()
                ):
                    self._cond.wait(TICK_S)
            if self._dead.is_set():
                return "gone"
            try:
                end = self._read_one()
            except Closed as closed:
                return self._reader_closed(closed.reason)
            except Exception:  # a bug, not the client's doing: end this connection cleanly
                log.exception("stream reader failed", extra={"event": "stream_bug"})
                message = "internal error while reading this message; the connection is closed"
                self._push(
                    Slot(None, outcome=ErrorOutcome(ErrorCode.PROTOCOL, message), fatal=True)
                )
                return "error"
            if end is not None:
                return end

    def _read_one(self) -> str | None:
        """Read and handle one message; returns how the connection ends, or None to go on."""
        idle_deadline = time.monotonic() + self.config.idle_timeout_s
        try:
            kind, header, payload_len, deadline = self._read_head(idle_deadline)
        except ProtocolError as exc:
            self._push(
                Slot(None, outcome=ErrorOutcome(exc.code, exc.message, exc.field), fatal=True)
            )
            return "protocol"
        if kind == MessageType.BYE:
            problem = self._bad_bye(header, payload_len)
            if problem is not None:
                self._push(Slot(None, outcome=problem, fatal=True))
                return "protocol"
            self._goodbye = "bye"
            return "bye"
        if kind != MessageType.FRAME:
            message = f"unexpected {kind.name} after the handshake"
            self._push(
                Slot(None, outcome=ErrorOutcome(ErrorCode.PROTOCOL, message, "type"), fatal=True)
            )
            return "protocol"
        fatal = self._accept_frame(header, payload_len, deadline)
        if fatal is not None:
            self._push(fatal)
            return "protocol"
        return None

    @staticmethod
    def _bad_bye(header: dict[str, Any], payload_len: int) -> ErrorOutcome | None:
        """BYE carries ``{}`` and no payload (PROTOCOL.md §1: unknown keys are rejected)."""
        if header:
            key = sorted(header)[0]
            return ErrorOutcome(ErrorCode.PROTOCOL, "BYE takes no keys", f"header.{key}")
        if payload_len:
            return ErrorOutcome(ErrorCode.PROTOCOL, "BYE has no payload", "payload_length")
        return None

    def _reader_closed(self, reason: str) -> str:
        if reason == "slow":
            message = (
                f"message not complete within message_timeout_s ({self.config.message_timeout_s} s)"
            )
            self._push(Slot(None, outcome=ErrorOutcome(ErrorCode.TIMEOUT, message), fatal=True))
        elif reason == "shutdown_mid_message":
            log.info(
                "draining: half-received message dropped",
                extra={"event": "stream_drain_cut", "peer": self.peer},
            )
            self._goodbye = reason = "shutdown"
        elif reason in ("eof", "shutdown", "idle_timeout"):
            self._goodbye = reason
        elif reason == "vanished":
            log.info(
                "client vanished mid-message", extra={"event": "stream_vanished", "peer": self.peer}
            )
            self._dead.set()
        return reason

    def _frame_scene(self, header: dict[str, Any]) -> Scene:
        assert self.session is not None
        if "scene" not in header:
            return self.session.scene
        override = header["scene"]
        if not isinstance(override, dict):
            raise InputError("scene", "must be a JSON object (a partial scene)")
        scene = self.service.scenes.from_dict(merge_scene_dicts(self.session.raw_scene, override))
        self.service.worker.check_image_size(scene)
        return scene

    def _refuse(
        self, frame_id: int, exc: InputError | Busy, payload_len: int, deadline: float
    ) -> None:
        """Answer a frame refused from its header; its payload is read and dropped."""
        if isinstance(exc, Busy):
            outcome = ErrorOutcome(ErrorCode.BUSY, str(exc))
        else:
            code = ErrorCode.TOO_LARGE if isinstance(exc, LimitError) else ErrorCode.BAD_INPUT
            outcome = ErrorOutcome(code, exc.message, exc.field)
        self.service.record_invalid_frame("stream", outcome.code)
        self._push(Slot(frame_id, outcome=outcome))
        self.channel.discard(payload_len, deadline)
        self.service.metrics.bytes_in.inc("stream", amount=payload_len)

    def _accept_frame(
        self, header: dict[str, Any], payload_len: int, deadline: float
    ) -> Slot | None:
        """Queue one FRAME (or answer its error); returns a fatal slot if it has no usable id."""
        frame_id = header.get("id")
        if (
            isinstance(frame_id, bool)
            or not isinstance(frame_id, int)
            or not (0 <= frame_id <= MAX_FRAME_ID)
        ):
            message = f"FRAME needs an integer id in [0, 2^53 - 1], got {show(frame_id)}"
            return Slot(None, outcome=ErrorOutcome(ErrorCode.PROTOCOL, message, "id"), fatal=True)
        assert self.session is not None
        try:
            scene, reservation = self._plan_frame(header, payload_len, deadline)
        except (InputError, Busy) as exc:
            self._refuse(frame_id, exc, payload_len, deadline)
            return None
        particles = self._receive_particles(header, payload_len, deadline, frame_id, reservation)
        if particles is None:
            return None
        self.session.frames += 1  # only this connection's reader thread touches it
        job = FrameJob(
            self.session.id, particles, scene, scene.output.format, "stream", frame_id=frame_id
        )
        self._push(Slot(frame_id, job=job, release=reservation.release))
        # On QueueFull/SchedulerClosed the job has been answered with the error; its slot has it.
        with contextlib.suppress(QueueFull, SchedulerClosed):
            self.service.submit(
                job,
                latest=self.mode == "latest",
                block=self.mode == "queue",
                abort=self._dead.is_set,
            )
        return None

    def _plan_frame(
        self, header: dict[str, Any], payload_len: int, deadline: float
    ) -> tuple[Scene, Reservation]:
        """The FRAME's scene and its memory reservation, from the header alone (the payload is
        still unread); `InputError` for a bad header, `Busy` when the budget stays used up."""
        service = self.service
        with decoding("arrays", "stream"):
            for key in header:
                if key not in _FRAME_KEYS:
                    allowed = ", ".join(_FRAME_KEYS)
                    raise InputError(f"header.{key}", f"unknown key; allowed: {allowed}")
            _slots, count = plan_frame_arrays(
                header.get("arrays"), payload_len, max_particles=service.config.limits.max_particles
            )
            scene = self._frame_scene(header)
        image = scene.image
        estimate = frame_estimate(payload_len, count, image.width * image.height)
        what = f"{count} particles at {image.width}x{image.height}"
        reservation = service.memory.reserve(
            estimate,
            what,
            "arrays",
            timeout=max(0.0, deadline - time.monotonic()),
            abort=lambda: self._dead.is_set() or self._draining.is_set(),
        )
        if reservation is None:
            raise Busy(
                "the server's memory budget for frames in progress is used up "
                "(limits.memory_budget_bytes); send it again later"
            )
        return scene, reservation

    def _receive_particles(
        self,
        header: dict[str, Any],
        payload_len: int,
        deadline: float,
        frame_id: int,
        reservation: Reservation,
    ) -> ParticleFrame | None:
        """The FRAME's payload read and decoded into particles; None (the error answered, the
        reservation released) when its arrays are bad."""
        service = self.service
        max_particles = service.config.limits.max_particles
        try:
            payload = self.channel.recv(payload_len, deadline) if payload_len else bytearray()
            service.metrics.bytes_in.inc("stream", amount=payload_len)
            with decoding("arrays", "stream"):
                arrays = decode_frame_arrays(header["arrays"], payload, max_particles=max_particles)
                return service.make_particles(arrays)
        except InputError as exc:
            reservation.release()
            code = ErrorCode.TOO_LARGE if isinstance(exc, LimitError) else ErrorCode.BAD_INPUT
            service.record_invalid_frame("stream", code)
            self._push(Slot(frame_id, outcome=ErrorOutcome(code, exc.message, exc.field)))
            return None
        except BaseException:
            reservation.release()
            raise

    def _push(self, slot: Slot) -> None:
        with self._cond:
            self._answers.append(slot)
            self._in_flight += 1
            self._cond.notify_all()

    # -- writer ---------------------------------------------------------------------------------

    def _outcome(self, slot: Slot) -> Outcome | None:
        if slot.outcome is not None:
            return slot.outcome
        assert slot.job is not None
        while not self._dead.is_set():
            try:
                return slot.job.future.result(timeout=TICK_S)
            except TimeoutError:
                continue
        return None

    def _write_loop(self) -> None:
        try:
            while True:
                with self._cond:
                    while not self._answers and not self._reading_done:
                        self._cond.wait(TICK_S)
                    if not self._answers:
                        break
                    slot = self._answers[0]
                outcome = self._outcome(slot)
                if outcome is None:
                    raise Closed("gone")
                self._send_all(answer_bytes(slot, outcome))
                if slot.release is not None:
                    slot.release()
                with self._cond:
                    self._answers.popleft()
                    self._in_flight -= 1
                    self._cond.notify_all()
                if slot.fatal:
                    return
            if self._goodbye is not None:
                self._send_all(encode_message(MessageType.GOODBYE, {"reason": self._goodbye}))
                linger(self.sock, LINGER_S)
        except Closed as closed:
            log.info(
                "stream client gone while answering",
                extra={"event": "stream_write_failed", "peer": self.peer, "reason": closed.reason},
            )
            self._dead.set()
        finally:
            self._abandon()
            with contextlib.suppress(OSError):
                self.sock.shutdown(socket.SHUT_RDWR)

    def _abandon(self) -> None:
        """Cancel whatever is still owed (the client cannot receive it any more)."""
        with self._cond:
            slots = list(self._answers)
            self._answers.clear()
            self._in_flight = 0
            self._cond.notify_all()
        for slot in slots:
            if slot.job is not None:
                slot.job.cancel()
            if slot.release is not None:
                slot.release()
        if self.session is not None:
            self.service.scheduler.cancel_key(self.session.id)


class StreamHandler(socketserver.BaseRequestHandler):
    service: ClassVar[ServiceFacade]

    def handle(self) -> None:
        server = cast(StreamServer, self.server)
        StreamConnection(self.request, self.client_address, self.service, server).run()


class StreamServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 128

    def __init__(self, address: tuple[str, int], service: ServiceFacade) -> None:
        if ":" in address[0]:
            self.address_family = socket.AF_INET6
        handler = type("BoundStreamHandler", (StreamHandler,), {"service": service})
        super().__init__(address, handler)
        self._max = service.config.stream.max_connections
        self._lock = threading.Lock()
        self._connections: set[StreamConnection] = set()

    def register(self, connection: StreamConnection) -> bool:
        """Count a connection in; when full, the oldest one still without a session after
        1 s (a client that connected and is not saying HELLO) is closed to make room."""
        with self._lock:
            if len(self._connections) >= self._max:
                now = time.monotonic()
                waiting = [
                    c
                    for c in self._connections
                    if c.session is None and now - c.connected_at > EVICT_HANDSHAKE_AFTER_S
                ]
                if not waiting:
                    return False
                victim = min(waiting, key=lambda c: c.connected_at)
                self._connections.discard(victim)
                victim.evict()
            self._connections.add(connection)
            return True

    def unregister(self, connection: StreamConnection) -> None:
        with self._lock:
            self._connections.discard(connection)

    def open_connections(self) -> int:
        with self._lock:
            return len(self._connections)

    def drain_connections(self) -> None:
        with self._lock:
            connections = list(self._connections)
        for connection in connections:
            connection.begin_drain()


def make_stream_server(service: ServiceFacade) -> StreamServer:
    host, port = service.config.http.host, service.config.stream.port
    try:
        return StreamServer((host, port), service)
    except OSError as exc:
        raise InputError(
            "stream.port", f"cannot listen on {host}:{port}: {exc.strerror or exc}"
        ) from None
