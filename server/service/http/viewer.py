"""The viewer page and the read-only documents it (and any client) reads.

Routes::

    GET /                      the viewer page (viewer_page/index.html)
    GET /viewer/viewer.js      its script, /viewer/viewer.css its style sheet
    GET /v1/status             live numbers: sessions, frames/s, queue, latency percentiles
    GET /v1/schema             the scene's JSON Schema (generated, = schema/scene.schema.json)
    GET /v1/demo/frame         the built-in demo's particles as one stream FRAME message (id 0,
                               its scene in the header), which the page streams over
                               ``/v1/stream`` (WebSocket) with a camera per frame
    GET /v1/sessions/{id}/latest   the last image any session (HTTP or stream) was answered,
                               if its format is one a browser shows; ETag = its number, so a
                               poll with If-None-Match costs a 304 until the next frame

The page is plain HTML, CSS and JavaScript shipped as package data (no framework, no build
step), served from memory. It streams the demo over the WebSocket (``GET /v1/stream``,
`websocket_route`), composing stream messages itself; another session's images come pushed
on ``GET /v1/sessions/{id}/watch`` (`watch_route`); it polls only for status. It is behind
the same token rule as the API: with a token configured, open ``/?token=<token>`` once; the
server answers 303 to ``/`` with the token in an HttpOnly, SameSite=Strict cookie, so the
token leaves the address bar and history, and the page's own requests (the WebSocket upgrades
included) carry the cookie (plus the ``X-Sphrender-Viewer`` header on POST/DELETE; see
`HandlerBase._check_auth`).
"""

from __future__ import annotations

import functools
import importlib.resources
from urllib.parse import quote, urlencode

from sphrender.core.protocol import ErrorCode, encode_frame
from sphrender.server.content.demo import demo_frame, demo_scene_dict
from sphrender.server.scene.json_schema import scene_json_schema_text
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.handler import VIEWER_COOKIE, HandlerBase
from sphrender.server.service.render.jobs import CONTENT_TYPES
from sphrender.server.service.sessions import MAX_KEPT_IMAGE_BYTES, VIEWABLE_FORMATS

#: Path -> (file under viewer_page/, content type).
ASSETS = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/viewer/viewer.js": ("viewer.js", "text/javascript; charset=utf-8"),
    "/viewer/viewer.css": ("viewer.css", "text/css; charset=utf-8"),
}
#: The page loads only its own script and style and draws frames from blob: URLs.
_PAGE_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob:; "
        "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-cache",
}


@functools.cache
def asset(name: str) -> bytes:
    """A file of the viewer (package data of sphrender.server.service.http)."""
    page = importlib.resources.files("sphrender.server.service.http").joinpath("viewer_page")
    return page.joinpath(name).read_bytes()


@functools.cache
def demo_frame_message() -> bytes:
    """The demo's particles and scene as a FRAME (deterministic: built once). Without the
    velocities: a view being turned is drawn still (no motion-blur sub-frames)."""
    frame = demo_frame()
    return encode_frame(
        0,
        frame.positions,
        temperatures=frame.temperatures,
        peak_temperatures=frame.peak_temperatures,
        scene=demo_scene_dict(),
    )


@functools.cache
def _schema_body() -> bytes:
    return scene_json_schema_text().encode("utf-8")


class ViewerRoutes(HandlerBase):
    """The viewer's routes; `api.ApiHandler` adds them to its table."""

    _query: dict[str, list[str]]

    def _viewer_asset(self, path: str) -> None:
        if path == "/" and "token" in self._query and self.service.config.security.token:
            self._trade_token_for_cookie()
            return
        name, content_type = ASSETS[path]
        self._send(200, asset(name), content_type, _PAGE_HEADERS)

    def _trade_token_for_cookie(self) -> None:
        """``GET /?token=...`` (already checked by `_check_auth`): set the cookie, go to ``/``
        with the other query parameters."""
        rest = {k: v for k, v in self._query.items() if k != "token"}
        location = "/" + ("?" + urlencode(rest, doseq=True) if rest else "")
        cookie = (
            f"{VIEWER_COOKIE}={quote(self.service.config.security.token, safe='')}; "
            "Path=/; HttpOnly; SameSite=Strict"
        )
        headers = {"Location": location, "Set-Cookie": cookie, **_PAGE_HEADERS}
        self._send(303, b"", "text/plain; charset=utf-8", headers)

    def _service_status(self) -> None:
        self._send_json(200, self.service.status(), {"Cache-Control": "no-store"})

    def _latest_image(self, session_id: str) -> None:
        session = self.service.sessions.get(session_id, touch=False)
        if session is None:
            raise HttpError(
                404, ErrorCode.NOT_FOUND, "no such session (closed or expired)", "session"
            )
        latest = session.latest
        if latest is None:
            raise HttpError(404, ErrorCode.NOT_FOUND, "the session has no image yet", "frame")
        if latest.data is None:
            raise HttpError(
                404,
                ErrorCode.NOT_FOUND,
                f"the session's latest image is {latest.format}, which is not kept for viewers "
                f"(kept: {', '.join(VIEWABLE_FORMATS)} up to {MAX_KEPT_IMAGE_BYTES} bytes)",
                "frame",
            )
        etag = f'"{latest.seq}"'
        headers = {
            "ETag": etag,
            "Cache-Control": "no-cache",
            "X-Sphrender-Image": str(latest.seq),
        }
        if self.headers.get("If-None-Match", "").strip() == etag:
            self._send(304, b"", CONTENT_TYPES.get(latest.format, "image/png"), headers)
            return
        self._send(200, latest.data, CONTENT_TYPES.get(latest.format, "image/png"), headers)

    def _demo_frame(self) -> None:
        self._send(200, demo_frame_message(), "application/octet-stream", _PAGE_HEADERS)

    def _schema(self) -> None:
        self._send(200, _schema_body(), "application/schema+json")
