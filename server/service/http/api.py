"""The HTTP API on the standard library's ``ThreadingHTTPServer`` (no web framework).

Routes::

    POST   /v1/render                 .npz body (arrays + optional `scene` JSON entry) -> image
    POST   /v1/sessions               scene JSON -> 201 {"id", "scene"}; the scene is warmed here
    GET    /v1/sessions/{id}          session description
    POST   /v1/sessions/{id}/frames   .npz body (arrays + optional partial `scene` override);
                                      for a demo session also a JSON body {"scene": {...}}
    DELETE /v1/sessions/{id}          204
    POST   /v1/demo/sessions          optional partial scene over the demo's -> 201 {"id", "scene"}
    GET    /healthz  /readyz  /v1/info  /metrics
    GET    /  /viewer/*  /v1/status  /v1/schema  /v1/sessions/{id}/latest   (viewer.py)

``POST /v1/sessions`` and ``GET /v1/sessions/{id}`` return the resolved scene (every default
filled in, `scene_to_dict`); frame overrides are merged onto the scene as the client sent it.
A demo session holds the built-in weld bead's particles on the server, so its frames need only
a camera: that is how the viewer page orbits it.

Images come back as ``image/png``, ``image/x-exr``, ``image/jpeg`` or, for raw arrays,
``application/octet-stream`` with ``X-Sphrender-Arrays`` (the scene's ``[output] format``, or
``?format=png|exr|jpeg|raw``) with ``Server-Timing`` per stage. Errors are JSON ``{"error", "field",
"code"}`` with 400 (bad input), 401 (token), 404, 405, 411 (no Content-Length), 413 (over a
limit; the body is not read and the connection closes), 500 (GL failure) or 503 with
``Retry-After`` (queue full, too many sessions or connections, draining).

The handler class gets the `ServiceFacade` bound by `make_handler` (a subclass with the service
as a class attribute, as prometheus_client builds its exposition handler), so there is no global
state and two services can run in one process. The handler thread only reads, decodes and
validates; rendering happens on the render thread.
"""

from __future__ import annotations

import json
import logging
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any
from urllib.parse import parse_qs, urlsplit

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.core.protocol import (
    IMAGE_FORMATS,
    ErrorCode,
    ImageFormat,
    LimitError,
    decode_npz_frame,
    parse_json_object,
)
from sphrender.server.content.demo import demo_scene_dict
from sphrender.server.scene import Scene, merge_scene_dicts, scene_to_dict
from sphrender.server.service.admission import Busy, Reservation, decoding, frame_estimate
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.handler import (
    HEALTH_ROUTES,
    SESSION_FRAMES_PATH,
    SESSION_LATEST_PATH,
    SESSION_PATH,
)
from sphrender.server.service.http.listener import SphrenderHttpServer
from sphrender.server.service.http.viewer import ASSETS, ViewerRoutes
from sphrender.server.service.metrics import CONTENT_TYPE as METRICS_CONTENT_TYPE
from sphrender.server.service.render.jobs import (
    CONTENT_TYPES,
    DroppedOutcome,
    ErrorOutcome,
    FrameJob,
    ImageOutcome,
)
from sphrender.server.service.render.scheduler import QueueFull, SchedulerClosed
from sphrender.server.service.sessions import Session, SessionLimitReached

log = logging.getLogger("sphrender.service.http")


class ApiHandler(ViewerRoutes):
    """Request handler (routes and their work); `service` is bound by `make_handler`."""

    def do_GET(self) -> None:
        self._dispatch("GET")

    def do_POST(self) -> None:
        self._dispatch("POST")

    def do_DELETE(self) -> None:
        self._dispatch("DELETE")

    def do_PUT(self) -> None:
        self._dispatch("PUT")

    def do_HEAD(self) -> None:
        self._dispatch("HEAD")

    def _dispatch(self, method: str) -> None:
        service = self.service
        self._reader.end_head()
        service.enter_http_request()
        self._status = 0
        try:
            url = urlsplit(self.path)
            self._query = parse_qs(url.query)
            handler, allowed = self._route(method, url.path)
            if handler is None:
                if allowed:
                    raise HttpError(
                        405,
                        ErrorCode.BAD_INPUT,
                        f"method {method} not allowed",
                        "method",
                        headers={"Allow": ", ".join(allowed)},
                        close=method in ("POST", "PUT"),
                    )
                raise HttpError(
                    404,
                    ErrorCode.NOT_FOUND,
                    f"no such resource {url.path}",
                    "path",
                    close=method in ("POST", "PUT"),
                )
            if self._mode == "health" and url.path not in HEALTH_ROUTES:
                raise HttpError(
                    503,
                    ErrorCode.BUSY,
                    "too many connections; this one may only ask /healthz, /readyz or /metrics",
                    retry_after_s=1,
                    close=True,
                )
            if url.path not in ("/healthz", "/readyz"):
                self._check_auth()
            # Counted as active (above) before looking at the flag: a request that passes this
            # check is waited for by the drain; one that arrives later is refused here.
            if service.draining.is_set() and method in ("POST", "PUT"):
                raise HttpError(
                    503,
                    ErrorCode.SHUTTING_DOWN,
                    "the server is shutting down",
                    retry_after_s=1,
                    close=True,
                )
            handler()
        except HttpError as error:
            self._send_error(error, method=method)
        except (ConnectionError, TimeoutError):
            self.close_connection = True
            log.info("client went away", extra={"event": "http_client_gone", "path": self.path})
        except Exception:
            log.exception("unexpected error", extra={"event": "http_error", "path": self.path})
            self._send_error(
                HttpError(500, ErrorCode.RENDER_FAILED, "internal error", close=True),
                method=method,
            )
        finally:
            if not self._status:
                self._count_request(0)  # no answer could be sent
            service.leave_http_request()

    def _route(self, method: str, path: str) -> tuple[Any, list[str]]:
        table: dict[str, dict[str, Any]] = {
            "/healthz": {"GET": self._healthz},
            "/readyz": {"GET": self._readyz},
            "/v1/info": {"GET": self._info},
            "/metrics": {"GET": self._metrics},
            "/v1/render": {"POST": self._render},
            "/v1/sessions": {"POST": self._create_session},
            "/v1/demo/sessions": {"POST": self._create_demo_session},
            "/v1/status": {"GET": self._service_status},
            "/v1/schema": {"GET": self._schema},
        }
        for asset_path in ASSETS:
            table[asset_path] = {"GET": lambda p=asset_path: self._viewer_asset(p)}
        routes = table.get(path)
        if routes is None and (match := SESSION_LATEST_PATH.match(path)):
            sid = match.group(1)
            routes = {"GET": lambda: self._latest_image(sid)}
        if routes is None and (match := SESSION_FRAMES_PATH.match(path)):
            sid = match.group(1)
            routes = {"POST": lambda: self._session_frame(sid)}
        elif routes is None and (match := SESSION_PATH.match(path)):
            sid = match.group(1)
            routes = {
                "GET": lambda: self._get_session(sid),
                "DELETE": lambda: self._delete_session(sid),
            }
        if routes is None:
            return None, []
        return routes.get(method), sorted(routes)

    # -- simple GET endpoints -------------------------------------------------------------------

    def _healthz(self) -> None:
        self._send_json(200, {"status": "ok"})

    def _readyz(self) -> None:
        ready, state = self.service.readiness()
        headers = {} if ready else {"Retry-After": "1"}
        self._send_json(200 if ready else 503, {"status": state}, headers)

    def _info(self) -> None:
        self._send_json(200, self.service.info())

    def _metrics(self) -> None:
        body = self.service.metrics.exposition().encode("utf-8")
        self._send(200, body, METRICS_CONTENT_TYPE)

    # -- rendering ------------------------------------------------------------------------------

    def _format(self, scene: Scene) -> ImageFormat:  # ?format= overrides output.format
        values = self._query.get("format")
        if not values:
            return scene.output.format
        for known in IMAGE_FORMATS:
            if values[-1] == known:
                return known
        allowed = ", ".join(IMAGE_FORMATS)
        raise HttpError(400, ErrorCode.BAD_INPUT, f"must be one of {allowed}", "format")

    def _render(self) -> None:
        self._frame_request(None)

    def _session(self, session_id: str, *, touch: bool = True) -> Session:
        session = self.service.sessions.get(session_id, touch=touch)
        if session is None or session.transport != "http":
            raise HttpError(
                404,
                ErrorCode.NOT_FOUND,
                "no such session (deleted or expired)",
                "session",
                close=self.command == "POST",
            )
        return session

    def _session_frame(self, session_id: str) -> None:
        session = self._session(session_id)
        sessions = self.service.sessions
        sessions.begin_frame(session)
        try:
            content_type = self.headers.get("Content-Type", "").partition(";")[0].strip()
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
        body = self._read_body(self._content_length(limit=service.config.limits.max_scene_bytes))
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
                raise InputError("scene", f"must be a JSON object, got {type(override).__name__}")
            scene = service.scenes.from_dict(merge_scene_dicts(session.raw_scene, override))
            service.worker.check_image_size(scene)
        except InputError as exc:
            service.record_invalid_frame("http", _code(exc))
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
            self.service.record_invalid_frame("http", _code(exc))
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
        length = self._content_length()
        reservation = self._reserve(length, f"a body of {length} bytes", "body")
        try:
            body = self._read_body(length)
            decided: list[Scene] = []

            def admit(scene_json: str | None, particles: int) -> None:
                scene = self._scene_for(session, scene_json)
                pixels = scene.image.width * scene.image.height
                total = frame_estimate(length, particles, pixels)
                what = f"{particles} particles at {scene.image.width}x{scene.image.height}"
                service.memory.check(total, what, "positions")
                extra = service.memory.reserve(total - length, what, "positions")
                if extra is None:
                    raise Busy
                reservation.amount += extra.amount  # one reservation, released once
                extra.amount = 0
                decided.append(scene)

            try:
                with decoding("body", "http"):
                    npz = decode_npz_frame(
                        body,
                        max_particles=limits.max_particles,
                        max_uncompressed_bytes=limits.max_request_bytes,
                        max_entries=limits.max_npz_entries,
                        max_scene_bytes=limits.max_scene_bytes,
                        admit=admit,
                    )
                    del body  # the arrays were copied out of the archive
                    particles = service.make_particles(npz.arrays)
            except InputError as exc:
                service.record_invalid_frame("http", _code(exc))
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
            key = session.id if session is not None else f"http-connection-{id(self):x}"
            self._render_and_answer(FrameJob(key, particles, scene, self._format(scene), "http"))
        finally:
            reservation.release()

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
        try:
            outcome = job.future.result(timeout=service.config.limits.render_timeout_s)
        except FutureTimeout:
            job.cancel()
            raise HttpError(
                503,
                ErrorCode.BUSY,
                "the frame was not rendered within limits.render_timeout_s",
                retry_after_s=service.retry_after_s(),
            ) from None
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
            self._send(200, outcome.data, CONTENT_TYPES[outcome.format], headers)
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

    # -- sessions -------------------------------------------------------------------------------

    def _create_session(self) -> None:
        raw = self._scene_body()
        session = self._open_session(raw)
        self._answer_session(session)

    def _create_demo_session(self) -> None:
        """A session of the built-in demo (the weld bead of `sphrender demo`), whose particles
        the server holds; the body, if any, is a partial scene laid over the demo's."""
        raw = merge_scene_dicts(demo_scene_dict(), self._scene_body())
        session = self._open_session(raw, self.service.demo_particles())
        self._answer_session(session)

    def _scene_body(self) -> dict[str, Any]:
        body = self._read_body(
            self._content_length(limit=self.service.config.limits.max_scene_bytes)
        )
        try:
            with decoding("scene", "http"):
                return parse_json_object(body, "scene") if body.strip() else {}
        except InputError as exc:
            raise HttpError.from_input(exc) from None

    def _answer_session(self, session: Session) -> None:
        self._send_json(
            201,
            {"id": session.id, "scene": scene_to_dict(session.scene)},
            {"Location": f"/v1/sessions/{session.id}"},
        )

    def _open_session(self, raw: dict[str, Any], particles: ParticleFrame | None = None) -> Session:
        service = self.service
        try:
            session = service.create_session(raw, "http")
        except InputError as exc:
            raise HttpError.from_input(exc) from None
        except SessionLimitReached:
            raise HttpError(
                503,
                ErrorCode.BUSY,
                f"the server has {service.config.limits.max_sessions} sessions open "
                "(limits.max_sessions)",
                "session",
                retry_after_s=max(1, int(service.config.limits.session_idle_timeout_s / 4)),
            ) from None
        except SchedulerClosed:
            raise HttpError(
                503, ErrorCode.SHUTTING_DOWN, "the server is shutting down", retry_after_s=1
            ) from None
        except TimeoutError:
            raise HttpError(
                503, ErrorCode.BUSY, "the scene could not be prepared in time", retry_after_s=1
            ) from None
        except Exception as exc:  # GL failure while warming: the context has been rebuilt
            raise HttpError(
                500, ErrorCode.RENDER_FAILED, f"preparing the scene failed: {exc}"
            ) from None
        session.particles = particles  # before anyone knows the id
        return session

    def _get_session(self, session_id: str) -> None:
        self._send_json(200, self._session(session_id, touch=False).describe())

    def _delete_session(self, session_id: str) -> None:
        if not self.service.close_session(session_id):
            raise HttpError(404, ErrorCode.NOT_FOUND, "no such session", "session")
        self._count_request(204)
        self.send_response(204)
        self.send_header("Content-Length", "0")
        self.end_headers()


def _code(exc: InputError) -> str:
    return ErrorCode.TOO_LARGE if isinstance(exc, LimitError) else ErrorCode.BAD_INPUT


def make_handler(service: ServiceFacade) -> type[ApiHandler]:
    """A handler class with `service` bound (no module-level state)."""
    # `timeout` is StreamRequestHandler's per-read socket timeout.
    attributes = {"service": service, "timeout": service.config.http.read_timeout_s}
    return type("BoundApiHandler", (ApiHandler,), attributes)


def make_http_server(service: ServiceFacade) -> SphrenderHttpServer:
    config = service.config.http
    try:
        return SphrenderHttpServer(
            (config.host, config.port),
            make_handler(service),
            config.max_connections,
            config.health_connections,
        )
    except OSError as exc:
        raise InputError(
            "http.port", f"cannot listen on {config.host}:{config.port}: {exc.strerror or exc}"
        ) from None
