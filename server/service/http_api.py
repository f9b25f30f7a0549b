"""The HTTP API on the standard library's ``ThreadingHTTPServer`` (no web framework).

Routes::

    POST   /v1/render                 .npz body (arrays + optional `scene` JSON entry) -> image
    POST   /v1/sessions               scene JSON -> 201 {"id", "scene"}; the scene is warmed here
    GET    /v1/sessions/{id}          session description
    POST   /v1/sessions/{id}/frames   .npz body (arrays + optional partial `scene` override)
    DELETE /v1/sessions/{id}          204
    GET    /healthz  /readyz  /v1/info  /metrics

Images come back as ``image/png`` or ``image/x-exr`` (the scene's ``[output] format``, or
``?format=png|exr``) with ``Server-Timing`` per stage. Errors are JSON ``{"error", "field",
"code"}`` with 400 (bad input), 401 (token), 404, 405, 411 (no Content-Length), 413 (over a
limit; the body is not read and the connection closes), 500 (GL failure) or 503 with
``Retry-After`` (queue full, too many sessions or connections, draining).

The handler class gets the `ServiceFacade` bound by `make_handler` (a subclass with the service
as a class attribute, as prometheus_client builds its exposition handler), so there is no global
state and two services can run in one process. The handler thread only reads, decodes and
validates; rendering happens on the render thread.
"""

from __future__ import annotations

import contextlib
import hmac
import json
import logging
import re
import time
from concurrent.futures import TimeoutError as FutureTimeout
from http.server import BaseHTTPRequestHandler
from typing import Any, ClassVar
from urllib.parse import parse_qs, urlsplit

from sphrender.client.errors import InputError
from sphrender.client.protocol import (
    ErrorCode,
    LimitError,
    decode_npz_frame,
    parse_json_object,
)
from sphrender.server.scene import Scene, merge_scene_dicts
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.http_errors import HttpError
from sphrender.server.service.http_server import SphrenderHttpServer
from sphrender.server.service.jobs import (
    CONTENT_TYPES,
    DroppedOutcome,
    ErrorOutcome,
    FrameJob,
    ImageFormat,
    ImageOutcome,
)
from sphrender.server.service.metrics import CONTENT_TYPE as METRICS_CONTENT_TYPE
from sphrender.server.service.scheduler import QueueFull, SchedulerClosed
from sphrender.server.service.sessions import Session, SessionLimitReached

log = logging.getLogger("sphrender.service.http")

_SESSION = re.compile(r"^/v1/sessions/([0-9a-f]{32})$")
_SESSION_FRAMES = re.compile(r"^/v1/sessions/([0-9a-f]{32})/frames$")
#: Largest scene JSON body for POST /v1/sessions.
MAX_SCENE_BYTES = 1 << 20
#: Fixed routes; anything else is reported as "other" so metric labels stay bounded.
_ROUTES = ("/healthz", "/readyz", "/v1/info", "/metrics", "/v1/render", "/v1/sessions")


def _route_label(path: str) -> str:
    if _SESSION_FRAMES.match(path):
        return "/v1/sessions/{id}/frames"
    if _SESSION.match(path):
        return "/v1/sessions/{id}"
    return path if path in _ROUTES else "other"


class ApiHandler(BaseHTTPRequestHandler):
    """Request handler; `service` is bound by `make_handler`."""

    service: ClassVar[ServiceFacade]
    protocol_version = "HTTP/1.1"  # keep-alive; every answer carries Content-Length
    server_version = "sphrender"

    def version_string(self) -> str:
        return self.server_version

    # -- plumbing -------------------------------------------------------------------------------

    def handle(self) -> None:
        server: SphrenderHttpServer = self.server  # type: ignore[assignment]
        if not server.enter_connection():
            self._raw_busy()
            return
        try:
            super().handle()
        except (ConnectionError, TimeoutError):
            pass  # client went away or idled out between requests
        finally:
            server.leave_connection()

    def _raw_busy(self) -> None:
        body = json.dumps(
            {"error": "too many connections", "field": None, "code": ErrorCode.BUSY}
        ).encode()
        head = (
            "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
            f"Content-Length: {len(body)}\r\nRetry-After: 1\r\nConnection: close\r\n\r\n"
        )
        with contextlib.suppress(OSError):
            self.wfile.write(head.encode("ascii") + body)

    def log_message(self, format: str, *args: Any) -> None:
        log.debug(format % args, extra={"peer": self.client_address[0]})

    def handle_expect_100(self) -> bool:
        """curl sends ``Expect: 100-continue`` for large bodies: refuse before the upload."""
        try:
            self._check_auth()
            self._content_length()
        except HttpError as error:
            self._send_error(error, method="POST")
            return False
        return super().handle_expect_100()

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

    def _count_request(self, status: int) -> None:
        """Counted before the answer is written, so a client that reads /metrics right after
        its answer sees its own request."""
        self._status = status
        route = _route_label(urlsplit(self.path).path)
        self.service.metrics.http_requests.inc(self.command, route, str(status))

    def _route(self, method: str, path: str) -> tuple[Any, list[str]]:
        table: dict[str, dict[str, Any]] = {
            "/healthz": {"GET": self._healthz},
            "/readyz": {"GET": self._readyz},
            "/v1/info": {"GET": self._info},
            "/metrics": {"GET": self._metrics},
            "/v1/render": {"POST": self._render},
            "/v1/sessions": {"POST": self._create_session},
        }
        routes = table.get(path)
        if routes is None and (match := _SESSION_FRAMES.match(path)):
            sid = match.group(1)
            routes = {"POST": lambda: self._session_frame(sid)}
        elif routes is None and (match := _SESSION.match(path)):
            sid = match.group(1)
            routes = {
                "GET": lambda: self._get_session(sid),
                "DELETE": lambda: self._delete_session(sid),
            }
        if routes is None:
            return None, []
        return routes.get(method), sorted(routes)

    # -- auth and bodies ------------------------------------------------------------------------

    def _check_auth(self) -> None:
        token = self.service.config.security.token
        if not token:
            return
        presented = self.headers.get("Authorization", "")
        scheme, _, value = presented.partition(" ")
        ok = scheme.lower() == "bearer" and hmac.compare_digest(
            value.strip().encode("utf-8"), token.encode("utf-8")
        )
        if not ok:
            raise HttpError(
                401,
                ErrorCode.UNAUTHORIZED,
                "missing or wrong bearer token",
                "Authorization",
                close=self.command in ("POST", "PUT"),
                headers={"WWW-Authenticate": 'Bearer realm="sphrender"'},
            )

    def _content_length(self, limit: int | None = None) -> int:
        limit = self.service.config.http.max_body_bytes if limit is None else limit
        if self.headers.get("Transfer-Encoding"):
            raise HttpError(
                411,
                ErrorCode.BAD_INPUT,
                "chunked bodies are not supported; send Content-Length",
                "Transfer-Encoding",
                close=True,
            )
        text = self.headers.get("Content-Length")
        if text is None:
            raise HttpError(
                411, ErrorCode.BAD_INPUT, "Content-Length is required", "Content-Length", close=True
            )
        if not text.strip().isdigit():
            raise HttpError(
                400,
                ErrorCode.BAD_INPUT,
                f"Content-Length must be a non-negative integer, got {text!r}",
                "Content-Length",
                close=True,
            )
        length = int(text)
        if length > limit:
            raise HttpError(
                413,
                ErrorCode.TOO_LARGE,
                f"body of {length} bytes exceeds the limit of {limit}",
                "body",
                close=True,
            )
        return length

    def _read_body(self, limit: int | None = None) -> bytes:
        """Exactly Content-Length bytes within ``http.body_timeout_s`` (each read also times out
        after ``http.read_timeout_s``), so a dribbling client cannot hold the thread."""
        length = self._content_length(limit)
        deadline = time.monotonic() + self.service.config.http.body_timeout_s
        chunks: list[bytes] = []
        remaining = length
        while remaining:
            if time.monotonic() > deadline:
                raise HttpError(
                    408, ErrorCode.TIMEOUT, "the body did not arrive in time", "body", close=True
                )
            try:
                chunk = self.rfile.read1(min(remaining, 1 << 20))
            except TimeoutError:
                raise HttpError(
                    408,
                    ErrorCode.TIMEOUT,
                    "the body stalled (http.read_timeout_s)",
                    "body",
                    close=True,
                ) from None
            if not chunk:
                raise ConnectionError("client closed the connection mid-body")
            chunks.append(chunk)
            remaining -= len(chunk)
        self.service.metrics.bytes_in.inc("http", amount=length)
        return b"".join(chunks)

    # -- answers --------------------------------------------------------------------------------

    def _send(
        self,
        status: int,
        body: bytes,
        content_type: str,
        headers: dict[str, str] | None = None,
        *,
        close: bool = False,
    ) -> None:
        self._count_request(status)
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        for name, value in (headers or {}).items():
            self.send_header(name, value)
        if close or self.service.draining.is_set():
            self.send_header("Connection", "close")
            self.close_connection = True
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)
        self.service.metrics.bytes_out.inc("http", amount=len(body))

    def _send_json(
        self, status: int, payload: Any, headers: dict[str, str] | None = None, **kw: Any
    ) -> None:
        body = (json.dumps(payload, allow_nan=False) + "\n").encode("utf-8")
        self._send(status, body, "application/json", headers, **kw)

    def _send_error(self, error: HttpError, *, method: str) -> None:
        headers = dict(error.headers)
        if error.retry_after_s is not None:
            headers["Retry-After"] = str(error.retry_after_s)
        payload = {"error": error.message, "field": error.field, "code": error.code}
        log.info(
            "request failed",
            extra={
                "event": "http_error",
                "status": error.status,
                "code": error.code,
                "field": error.field,
                "path": self.path,
            },
        )
        try:
            self._send_json(error.status, payload, headers, close=error.close)
        except OSError:
            self.close_connection = True

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

    def _format(self, scene: Scene) -> ImageFormat:
        values = self._query.get("format")
        if not values:
            return scene.output.format
        if values[-1] not in CONTENT_TYPES:
            raise HttpError(400, ErrorCode.BAD_INPUT, "must be png or exr", "format")
        return "png" if values[-1] == "png" else "exr"

    def _decode_body(self) -> tuple[dict[str, Any], str | None]:
        service = self.service
        body = self._read_body()
        limits = service.config.limits
        try:
            npz = decode_npz_frame(
                body,
                max_particles=limits.max_particles,
                max_uncompressed_bytes=16 * 6 * limits.max_particles + (1 << 20),
            )
        except InputError as exc:
            service.record_invalid_frame("http", _code(exc))
            raise HttpError.from_input(exc) from None
        return npz.arrays, npz.scene_json

    def _render(self) -> None:
        arrays, scene_json = self._decode_body()
        try:
            if scene_json is None:
                scene = Scene()
            else:
                scene, _raw = self.service.scenes.from_json(scene_json)
            self.service.worker.check_image_size(scene)
            particles = self.service.make_particles(arrays)
        except InputError as exc:
            self.service.record_invalid_frame("http", _code(exc))
            raise HttpError.from_input(exc) from None
        key = f"http-connection-{id(self.connection):x}"
        self._render_and_answer(FrameJob(key, particles, scene, self._format(scene), "http"))

    def _session(self, session_id: str, *, touch: bool = True) -> Session:
        session = self.service.sessions.get(session_id, touch=touch)
        if session is None:
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
            arrays, scene_json = self._decode_body()
            try:
                scene = session.scene
                if scene_json is not None:
                    override = parse_json_object(scene_json.encode("utf-8"), "scene")
                    scene = self.service.scenes.from_dict(
                        merge_scene_dicts(session.raw_scene, override)
                    )
                    self.service.worker.check_image_size(scene)
                particles = self.service.make_particles(arrays)
            except InputError as exc:
                self.service.record_invalid_frame("http", _code(exc))
                raise HttpError.from_input(exc) from None
            job = FrameJob(session.id, particles, scene, self._format(scene), "http")
            self._render_and_answer(job)
        finally:
            sessions.end_frame(session)

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
            self._send(
                200,
                outcome.data,
                CONTENT_TYPES[outcome.format],
                {
                    "Server-Timing": timing,
                    "X-Sphrender-Particles": str(outcome.particles),
                    "X-Sphrender-Drawn": str(outcome.drawn),
                },
            )
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
        service = self.service
        body = self._read_body(limit=MAX_SCENE_BYTES)
        try:
            raw = parse_json_object(body, "scene") if body.strip() else {}
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
        self._send_json(
            201,
            {"id": session.id, "scene": session.raw_scene},
            {"Location": f"/v1/sessions/{session.id}"},
        )

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
            (config.host, config.port), make_handler(service), config.max_connections
        )
    except OSError as exc:
        raise InputError(
            "http.port", f"cannot listen on {config.host}:{config.port}: {exc.strerror or exc}"
        ) from None
