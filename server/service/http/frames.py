"""Frame routes of the HTTP API: ``POST /v1/render`` and ``POST /v1/sessions/{id}/frames``.

A frame body's memory is reserved before it is read; an .npz body's scene is decoded first and
its arrays are admitted against the memory budget before they are read (`admission.py`). The
job is queued and waited for, then answered with the image, its ``Server-Timing`` and
``X-Sphrender-*`` headers, or the error as JSON. A frame still queued after
``limits.render_timeout_s`` is taken back and answered 503 ``busy``; once the renderer has it,
the wait is the renderer's (its watchdog answers a frame past the render limit
``render_failed``), so the answer is never given up on early.
"""

from __future__ import annotations

import json
from concurrent.futures import TimeoutError as FutureTimeout

from sphrender.core.errors import InputError, kind_of
from sphrender.core.frame_message import FRAME_CONTENT_TYPE, decode_frame_body
from sphrender.core.protocol import (
    IMAGE_FORMATS,
    ErrorCode,
    ImageFormat,
    LimitError,
    decode_npz_frame,
    parse_json_object,
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
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.handler import HandlerBase
from sphrender.server.service.http.session_routes import find_session
from sphrender.server.service.render.jobs import (
    CONTENT_TYPES,
    DroppedOutcome,
    ErrorOutcome,
    FrameJob,
    ImageOutcome,
    Outcome,
)
from sphrender.server.service.render.scheduler import QueueFull, SchedulerClosed
from sphrender.server.service.sessions import Session


def input_code(exc: InputError) -> str:
    """too_large for a limit, else bad_input."""
    return ErrorCode.TOO_LARGE if isinstance(exc, LimitError) else ErrorCode.BAD_INPUT


class FrameRoutes:
    """The frame routes of one request on `http` (see the module docstring)."""

    def __init__(self, http: HandlerBase, service: ServiceFacade) -> None:
        self.http = http
        self.service = service

    def _format(self, scene: Scene) -> ImageFormat:  # ?format= overrides output.format
        values = self.http._query.get("format")
        if not values:
            return scene.output.format
        for known in IMAGE_FORMATS:
            if values[-1] == known:
                return known
        allowed = ", ".join(IMAGE_FORMATS)
        raise HttpError(400, ErrorCode.BAD_INPUT, f"must be one of {allowed}", "format")

    def render(self) -> None:
        self._frame_request(None)

    def session_frame(self, session_id: str) -> None:
        session = find_session(self.service, session_id, self.http.command)
        sessions = self.service.sessions
        sessions.begin_frame(session)
        try:
            content_type = self.http.headers.get("Content-Type", "").partition(";")[0].strip()
            if content_type.lower() == "application/json":
                self._json_frame(session)
            else:
                self._frame_request(session)
        finally:
            sessions.end_frame(session)

    def _json_frame(self, session: Session) -> None:
        """A frame of a session whose particles the server holds (a demo session): the body is
        ``{"scene": {...}}``, a partial scene merged onto the session's, as in an .npz frame."""
        service = self.service
        body = self.http._read_body(
            self.http._content_length(limit=service.config.limits.max_scene_bytes)
        )
        try:
            if session.particles is None:
                raise InputError(
                    "body",
                    "a JSON frame needs a session whose particles the server holds (a demo "
                    "session, POST /v1/demo/sessions); send this session's frames as .npz",
                )
            with decoding("body", "http"):
                document = parse_json_object(body, "body") if body.strip() else {}
            for key in document:
                if key != "scene":
                    raise InputError(f"body.{key}", "unknown key; allowed: scene")
            override = document.get("scene", {})
            if not isinstance(override, dict):
                raise InputError("scene", f"must be a JSON object, got {kind_of(override)}")
            scene = service.scenes.from_dict(merge_scene_dicts(session.raw_scene, override))
            service.worker.check_image_size(scene)
        except InputError as exc:
            service.record_invalid_frame("http", input_code(exc))
            raise HttpError.from_input(exc) from None
        # Held from the memory budget like an .npz frame (no particle copy, but the render's
        # buffers and the image are as large).
        count = int(session.particles.positions.shape[0])
        pixels = scene.image.width * scene.image.height
        what = f"{count} particles at {scene.image.width}x{scene.image.height}"
        reservation = self._reserve(frame_estimate(len(body), count, pixels), what, "image")
        try:
            job = FrameJob(session.id, session.particles, scene, self._format(scene), "http")
            self._render_and_answer(job)
        finally:
            reservation.release()

    def _reserve(self, amount: int, what: str, field: str) -> Reservation:
        try:
            reservation = self.service.memory.reserve(amount, what, field)
        except InputError as exc:
            self.service.record_invalid_frame("http", input_code(exc))
            raise HttpError.from_input(exc, close=True) from None
        if reservation is None:
            raise HttpError(
                503,
                ErrorCode.BUSY,
                "the server's memory budget for frames in progress is used up "
                "(limits.memory_budget_bytes); retry later",
                retry_after_s=self.service.retry_after_s(),
                close=True,
            )
        return reservation

    def _scene_for(self, session: Session | None, scene_json: str | None) -> Scene:
        scenes = self.service.scenes
        if session is None:
            scene = scenes.from_dict({}) if scene_json is None else scenes.from_json(scene_json)[0]
        elif scene_json is None:
            return session.scene
        else:
            scenes.check_size(len(scene_json.encode("utf-8", errors="surrogatepass")))
            override = parse_json_object(scene_json.encode("utf-8", "surrogatepass"), "scene")
            scene = scenes.from_dict(merge_scene_dicts(session.raw_scene, override))
        self.service.worker.check_image_size(scene)
        return scene

    def _frame_request(self, session: Session | None) -> None:
        """A frame body: reserve its memory, read it, decode it (scene first, then the arrays,
        admitted against the memory budget before they are read), render, answer."""
        service = self.service
        limits = service.config.limits
        length = self.http._content_length()
        reservation = self._reserve(length, f"a body of {length} bytes", "body")
        try:
            body = self.http._read_body(length)
            decided: list[Scene] = []

            def admit(scene_json: str | None, particles: int, arrays: tuple[str, ...]) -> None:
                scene = self._scene_for(session, scene_json)
                pixels = scene.image.width * scene.image.height
                total = frame_estimate(length, particles, pixels, arrays)
                if content_type.lower() == FRAME_CONTENT_TYPE:
                    total += particles * COMPACT_PARTICLE_BYTES
                what = f"{particles} particles at {scene.image.width}x{scene.image.height}"
                service.memory.check(total, what, "positions")
                extra = service.memory.reserve(total - length, what, "positions")
                if extra is None:
                    raise Busy
                reservation.amount += extra.amount  # one reservation, released once
                extra.amount = 0
                decided.append(scene)

            content_type = self.http.headers.get("Content-Type", "").partition(";")[0].strip()
            try:
                with decoding("body", "http"):
                    if content_type.lower() == FRAME_CONTENT_TYPE:
                        arrays = decode_frame_body(
                            body,
                            max_header_bytes=service.config.stream.max_header_bytes,
                            max_particles=limits.max_particles,
                            max_scene_bytes=limits.max_scene_bytes,
                            admit=admit,
                        )
                    else:
                        arrays = decode_npz_frame(
                            body,
                            max_particles=limits.max_particles,
                            max_uncompressed_bytes=limits.max_request_bytes,
                            max_entries=limits.max_npz_entries,
                            max_scene_bytes=limits.max_scene_bytes,
                            admit=admit,
                        ).arrays
                    del body  # the arrays were copied out of the archive
                    particles = service.make_particles(arrays)
            except InputError as exc:
                service.record_invalid_frame("http", input_code(exc))
                raise HttpError.from_input(exc) from None
            except Busy:
                raise HttpError(
                    503,
                    ErrorCode.BUSY,
                    "the server's memory budget for frames in progress is used up "
                    "(limits.memory_budget_bytes); retry later",
                    retry_after_s=service.retry_after_s(),
                ) from None
            scene = decided[0]
            key = session.id if session is not None else f"http-connection-{id(self.http):x}"
            self._render_and_answer(FrameJob(key, particles, scene, self._format(scene), "http"))
        finally:
            reservation.release()

    def _wait(self, job: FrameJob) -> Outcome:
        """The frame's outcome; 503 busy if it is still queued after the render limit."""
        service = self.service
        limit_s = service.config.limits.render_timeout_s
        try:
            return job.future.result(timeout=limit_s)
        except FutureTimeout:
            pass
        # Not yet handed to the renderer: take it back (the worker skips a resolved job).
        if not job.started_at and job.resolve(DroppedOutcome("cancelled")):
            raise HttpError(
                503,
                ErrorCode.BUSY,
                f"the frame waited in the render queue for longer than limits.render_timeout_s "
                f"({limit_s:g} s); retry later",
                retry_after_s=service.retry_after_s(),
            )
        return job.future.result()  # the renderer's watchdog bounds this wait

    def _render_and_answer(self, job: FrameJob) -> None:
        service = self.service
        try:
            service.submit(job)
        except QueueFull:
            raise HttpError(
                503,
                ErrorCode.BUSY,
                "the render queue is full; retry later",
                retry_after_s=service.retry_after_s(),
            ) from None
        except SchedulerClosed:
            raise HttpError(
                503, ErrorCode.SHUTTING_DOWN, "the server is shutting down", retry_after_s=1
            ) from None
        outcome = self._wait(job)
        if isinstance(outcome, ImageOutcome):
            timing = ", ".join(f"{k};dur={v:.3f}" for k, v in outcome.timings_ms.items())
            headers = {
                "Server-Timing": timing,
                "X-Sphrender-Particles": str(outcome.particles),
                "X-Sphrender-Drawn": str(outcome.drawn),
                "X-Sphrender-Width": str(outcome.width),
                "X-Sphrender-Height": str(outcome.height),
            }
            if outcome.arrays is not None:
                headers["X-Sphrender-Arrays"] = json.dumps(outcome.arrays, separators=(",", ":"))
            if outcome.notes:  # JSON, ASCII (json escapes the rest)
                headers["X-Sphrender-Notes"] = json.dumps(
                    list(outcome.notes), separators=(",", ":")
                )
            self.http._send(200, outcome.data, CONTENT_TYPES[outcome.format], headers)
        elif isinstance(outcome, ErrorOutcome):
            status = ErrorCode.HTTP_STATUS.get(outcome.code, 500)
            raise HttpError(
                status,
                outcome.code,
                outcome.message,
                outcome.field,
                retry_after_s=(outcome.retry_after_s if status == 503 else None),
            )
        elif isinstance(outcome, DroppedOutcome):  # cancelled: session deleted meanwhile
            raise HttpError(
                404, ErrorCode.NOT_FOUND, "the session was deleted before rendering", "session"
            )
