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
    GET    /v1/stream                 WebSocket upgrade onto the stream (websocket_route.py)
    GET    /v1/sessions/{id}/watch    WebSocket pushing a session's new images (watch_route.py)

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

`ApiHandler` dispatches: the frame routes are in frames.py, the session routes in
session_routes.py, the viewer's in viewer.py. The handler class gets the `ServiceFacade` bound
by `make_handler` (a subclass with the service as a class attribute, as prometheus_client
builds its exposition handler), so there is no global state and two services can run in one
process. The handler thread only reads, decodes and
validates; rendering happens on the render thread.
"""

from __future__ import annotations

import logging
from typing import Any, ClassVar
from urllib.parse import parse_qs, urlsplit

from sphrender.core.errors import InputError, show
from sphrender.core.protocol import (
    ErrorCode,
)
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.frames import FrameRoutes
from sphrender.server.service.http.handler import (
    HEALTH_ROUTES,
    SESSION_FRAMES_PATH,
    SESSION_LATEST_PATH,
    SESSION_PATH,
    SESSION_WATCH_PATH,
)
from sphrender.server.service.http.listener import SphrenderHttpServer
from sphrender.server.service.http.session_routes import SessionRoutes
from sphrender.server.service.http.viewer import ASSETS, ViewerRoutes
from sphrender.server.service.http.watch_route import watch_session
from sphrender.server.service.http.websocket_route import STREAM_PATH, WebSocketRoute
from sphrender.server.service.metrics import CONTENT_TYPE as METRICS_CONTENT_TYPE
from sphrender.server.service.stream.registry import StreamConnections

log = logging.getLogger("sphrender.service.http")


class ApiHandler(ViewerRoutes):
    """Request handler (routes and their work); `service` and `streams` are bound by
    `make_handler`."""

    #: The stream connections of both transports (WebSocket upgrades count in them).
    streams: ClassVar[StreamConnections]

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
                    f"no such resource {show(url.path)}",
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
        frames = FrameRoutes(self, self.service)
        sessions = SessionRoutes(self, self.service)
        table: dict[str, dict[str, Any]] = {
            "/healthz": {"GET": self._healthz},
            "/readyz": {"GET": self._readyz},
            "/v1/info": {"GET": self._info},
            "/metrics": {"GET": self._metrics},
            "/v1/render": {"POST": frames.render},
            "/v1/sessions": {"POST": sessions.create_session},
            "/v1/demo/sessions": {"POST": sessions.create_demo_session},
            "/v1/status": {"GET": self._service_status},
            "/v1/schema": {"GET": self._schema},
            "/v1/demo/frame": {"GET": self._demo_frame},
            STREAM_PATH: {"GET": WebSocketRoute(self, self.service, self.streams).upgrade},
        }
        for asset_path in ASSETS:
            table[asset_path] = {"GET": lambda p=asset_path: self._viewer_asset(p)}
        routes = table.get(path)
        if routes is None and (match := SESSION_LATEST_PATH.match(path)):
            sid = match.group(1)
            routes = {"GET": lambda: self._latest_image(sid)}
        if routes is None and (match := SESSION_WATCH_PATH.match(path)):
            sid = match.group(1)
            routes = {"GET": lambda: watch_session(self, self.service, self.streams, sid)}
        if routes is None and (match := SESSION_FRAMES_PATH.match(path)):
            sid = match.group(1)
            routes = {"POST": lambda: frames.session_frame(sid)}
        elif routes is None and (match := SESSION_PATH.match(path)):
            sid = match.group(1)
            routes = {
                "GET": lambda: sessions.get_session(sid),
                "DELETE": lambda: sessions.delete_session(sid),
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


def make_handler(service: ServiceFacade, streams: StreamConnections) -> type[ApiHandler]:
    """A handler class with `service` bound (no module-level state)."""
    # `timeout` is StreamRequestHandler's per-read socket timeout.
    attributes = {
        "service": service,
        "streams": streams,
        "timeout": service.config.http.read_timeout_s,
    }
    return type("BoundApiHandler", (ApiHandler,), attributes)


def make_http_server(service: ServiceFacade, streams: StreamConnections) -> SphrenderHttpServer:
    config = service.config.http
    try:
        return SphrenderHttpServer(
            (config.host, config.port),
            make_handler(service, streams),
            config.max_connections,
            config.health_connections,
        )
    except OSError as exc:
        raise InputError(
            "http.port", f"cannot listen on {config.host}:{config.port}: {exc.strerror or exc}"
        ) from None
