"""The reader half of a stream connection (connection.py): reads messages after the handshake,
judges each FRAME from its header before reading its payload, and queues the frames it accepts.

For every FRAME it appends an answer slot *before* queueing the job, so answers leave in the
order frames arrived; it stops reading while ``max_in_flight`` answers are owed. A framing
error is fatal (one ERROR with ``"id": null`` after the owed answers); an error in a frame's
content answers that frame only. Every decode step runs inside `admission.decoding`.
"""

from __future__ import annotations

import contextlib
import logging
import time
from typing import Any, Literal

from sphrender.core.errors import InputError, show
from sphrender.core.frame import ParticleFrame
from sphrender.core.frame_message import FrameDecoder, plan_frame
from sphrender.core.protocol import (
    MAX_FRAME_ID,
    PREFIX_SIZE,
    ErrorCode,
    LimitError,
    MessageType,
    ProtocolError,
    parse_header,
    parse_prefix,
)
from sphrender.server.scene import Scene, merge_scene_dicts
from sphrender.server.service.admission import (
    COMPACT_PARTICLE_BYTES,
    Busy,
    Reservation,
    decoding,
    frame_estimate,
)
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.render.jobs import ErrorOutcome, FrameJob
from sphrender.server.service.render.scheduler import QueueFull, SchedulerClosed
from sphrender.server.service.sessions import Session
from sphrender.server.service.stream.answers import Answers, Slot
from sphrender.server.service.stream.wire import Channel, Closed

log = logging.getLogger("sphrender.service.stream")

_FRAME_KEYS = ("id", "arrays", "scene", "encoding", "base")


def read_head(
    channel: Channel,
    service: ServiceFacade,
    idle_deadline: float,
    message_deadline: float | None = None,
) -> tuple[MessageType, dict[str, Any], int, float]:
    """A message's prefix and header; returns (type, header, payload length, deadline).
    The payload is left on the socket for the caller to read or discard."""
    first = channel.recv(1, message_deadline or 0.0, idle_deadline=idle_deadline)
    deadline = message_deadline or time.monotonic() + service.config.stream.message_timeout_s
    prefix = first + channel.recv(PREFIX_SIZE - 1, deadline)
    kind, header_len, payload_len = parse_prefix(
        prefix,
        max_header_bytes=service.config.stream.max_header_bytes,
        max_payload_bytes=service.config.stream.max_payload_bytes,
    )
    header = parse_header(channel.recv(header_len, deadline)) if header_len else {}
    service.metrics.transport.bytes_in.inc("stream", amount=PREFIX_SIZE + header_len)
    return kind, header, payload_len, deadline


class FrameReader:
    """See the module docstring; `run` on the connection's handler thread."""

    def __init__(
        self,
        channel: Channel,
        service: ServiceFacade,
        answers: Answers,
        session: Session,
        mode: Literal["queue", "latest"],
        max_in_flight: int,
        peer: str,
    ) -> None:
        self.channel = channel
        self.service = service
        self.config = service.config.stream
        self.answers = answers
        self.session = session
        self.mode = mode
        self.max_in_flight = max_in_flight
        self.peer = peer
        self.decoder = FrameDecoder()  # holds the last compact frame, for frame prediction

    def run(self) -> str:
        """Read messages until the connection ends; returns how it ended."""
        while True:
            self.answers.wait_for_room(self.max_in_flight)
            if self.answers.dead.is_set():
                return "gone"
            try:
                end = self._read_one()
            except Closed as closed:
                return self._closed(closed.reason)
            except Exception:  # a bug, not the client's doing: end this connection cleanly
                log.exception("stream reader failed", extra={"event": "stream_bug"})
                message = "internal error while reading this message; the connection is closed"
                self.answers.push(
                    Slot(None, outcome=ErrorOutcome(ErrorCode.PROTOCOL, message), fatal=True)
                )
                return "error"
            if end is not None:
                return end

    def _read_one(self) -> str | None:
        """Read and handle one message; returns how the connection ends, or None to go on."""
        idle_deadline = time.monotonic() + self.config.idle_timeout_s
        try:
            kind, header, payload_len, deadline = read_head(
                self.channel, self.service, idle_deadline
            )
        except ProtocolError as exc:
            self.answers.push(
                Slot(None, outcome=ErrorOutcome(exc.code, exc.message, exc.field), fatal=True)
            )
            return "protocol"
        if kind == MessageType.BYE:
            problem = self._bad_bye(header, payload_len)
            if problem is not None:
                self.answers.push(Slot(None, outcome=problem, fatal=True))
                return "protocol"
            self.answers.goodbye = "bye"
            return "bye"
        if kind != MessageType.FRAME:
            message = f"unexpected {kind.name} after the handshake"
            self.answers.push(
                Slot(None, outcome=ErrorOutcome(ErrorCode.PROTOCOL, message, "type"), fatal=True)
            )
            return "protocol"
        fatal = self._accept_frame(header, payload_len, deadline)
        if fatal is not None:
            self.answers.push(fatal)
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

    def _closed(self, reason: str) -> str:
        if reason == "slow":
            message = (
                f"message not complete within message_timeout_s ({self.config.message_timeout_s} s)"
            )
            self.answers.push(
                Slot(None, outcome=ErrorOutcome(ErrorCode.TIMEOUT, message), fatal=True)
            )
        elif reason == "shutdown_mid_message":
            log.info(
                "draining: half-received message dropped",
                extra={"event": "stream_drain_cut", "peer": self.peer},
            )
            self.answers.goodbye = reason = "shutdown"
        elif reason in ("eof", "shutdown", "idle_timeout", "evicted"):
            self.answers.goodbye = reason
        elif reason == "vanished":
            log.info(
                "client vanished mid-message", extra={"event": "stream_vanished", "peer": self.peer}
            )
            self.answers.dead.set()
        return reason

    def _frame_scene(self, header: dict[str, Any]) -> Scene:
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
        self.answers.push(Slot(frame_id, outcome=outcome))
        self.decoder.forget()
        self.channel.discard(payload_len, deadline)
        self.service.metrics.transport.bytes_in.inc("stream", amount=payload_len)

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
        self.answers.push(Slot(frame_id, job=job, release=reservation.release))
        # On QueueFull/SchedulerClosed the job has been answered with the error; its slot has it.
        with contextlib.suppress(QueueFull, SchedulerClosed):
            self.service.submit(
                job,
                latest=self.mode == "latest",
                block=self.mode == "queue",
                abort=self.answers.dead.is_set,
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
            plan = plan_frame(
                header, payload_len, max_particles=service.config.limits.max_particles
            )
            scene = self._frame_scene(header)
        image = scene.image
        count = plan.count
        estimate = frame_estimate(payload_len, count, image.width * image.height, plan.names)
        if plan.encoding != "raw":
            estimate += count * COMPACT_PARTICLE_BYTES
        what = f"{count} particles at {image.width}x{image.height}"
        reservation = service.memory.reserve(
            estimate,
            what,
            "arrays",
            timeout=max(0.0, deadline - time.monotonic()),
            abort=lambda: self.answers.dead.is_set() or self.answers.draining.is_set(),
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
            service.metrics.transport.bytes_in.inc("stream", amount=payload_len)
            with decoding("arrays", "stream"):
                arrays = self.decoder.decode(header, payload, max_particles=max_particles)
                return service.make_particles(arrays)
        except InputError as exc:
            reservation.release()
            code = ErrorCode.TOO_LARGE if isinstance(exc, LimitError) else ErrorCode.BAD_INPUT
            service.record_invalid_frame("stream", code)
            self.answers.push(Slot(frame_id, outcome=ErrorOutcome(code, exc.message, exc.field)))
            return None
        except BaseException:
            reservation.release()
            raise
