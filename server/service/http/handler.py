"""The HTTP handler's plumbing: connection admission, deadlines, bodies and answers.

`HandlerBase` is what `api.ApiHandler` routes on top of. Every answer it writes is JSON
(``{"error", "field", "code"}`` for errors), including the ones the standard library would
write as HTML (malformed request line 400, 414, 431, 501, 505: `send_error` is overridden).
Bodies are read into one preallocated buffer under the body deadline (`listener`), after
``Content-Length`` has been checked: ASCII digits only, one value, within the limit.
"""

from __future__ import annotations

import contextlib
import hmac
import io
import json
import logging
import re
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler
from typing import Any, ClassVar, cast
from urllib.parse import parse_qs, unquote, urlsplit

from sphrender.core.errors import show
from sphrender.core.protocol import ErrorCode
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.listener import (
    ConnectionMode,
    DeadlineReader,
    SphrenderHttpServer,
)

log = logging.getLogger("sphrender.service.http")

SESSION_PATH = re.compile(r"^/v1/sessions/([0-9a-f]{32})$")
SESSION_FRAMES_PATH = re.compile(r"^/v1/sessions/([0-9a-f]{32})/frames$")
SESSION_LATEST_PATH = re.compile(r"^/v1/sessions/([0-9a-f]{32})/latest$")
SESSION_WATCH_PATH = re.compile(r"^/v1/sessions/([0-9a-f]{32})/watch$")
#: Fixed routes; anything else is reported as "other" so metric labels stay bounded.
_ROUTES = (
    "/healthz",
    "/readyz",
    "/v1/info",
    "/metrics",
    "/v1/render",
    "/v1/sessions",
    "/v1/status",
    "/v1/schema",
    "/v1/demo/sessions",
    "/",
    "/viewer/viewer.js",
    "/viewer/viewer.css",
    "/v1/stream",
    "/v1/demo/frame",
)
#: Routes a health-reserve connection may use (see listener).
HEALTH_ROUTES = ("/healthz", "/readyz", "/metrics")
#: The head of a health-reserve connection must arrive within this (seconds).
_HEALTH_HEAD_TIMEOUT_S = 2.0
_CONTENT_LENGTH = re.compile(r"[0-9]{1,19}")
#: The HTTP versions served (PROTOCOL.md 9); any other is answered 400 unsupported_version.
_VERSIONS = ("HTTP/1.0", "HTTP/1.1")
_VERSION_TEXT = "HTTP version not supported; use HTTP/1.1 or HTTP/1.0"
#: The viewer page's credential: the token, percent-encoded (`viewer` sets it).
VIEWER_COOKIE = "sphrender_token"
#: Sent by the viewer's scripts with every request that is not a GET (see `_check_auth`).
VIEWER_HEADER = "X-Sphrender-Viewer"
#: What the standard library's own errors mean in this API's codes.
#: 501 (unknown method) and 505 (HTTP version) are answered 405 and 400: a client's mistake
#: is never a 5xx here.
#: The texts are this API's own: the standard library's quote the request Python-style.
_STDLIB_CODES = {
    HTTPStatus.REQUEST_URI_TOO_LONG: (
        414,
        ErrorCode.TOO_LARGE,
        "request line",
        "the request line exceeds the limit of 65536 bytes",
    ),
    HTTPStatus.REQUEST_HEADER_FIELDS_TOO_LARGE: (
        431,
        ErrorCode.TOO_LARGE,
        "headers",
        "a header line exceeds 65536 bytes or there are more than 100 headers",
    ),
    HTTPStatus.NOT_IMPLEMENTED: (
        405,
        ErrorCode.BAD_INPUT,
        "method",
        "unknown method; allowed: GET, POST, DELETE",
    ),
    HTTPStatus.HTTP_VERSION_NOT_SUPPORTED: (
        400,
        ErrorCode.UNSUPPORTED_VERSION,
        "version",
        _VERSION_TEXT,
    ),
    HTTPStatus.REQUEST_TIMEOUT: (
        408,
        ErrorCode.TIMEOUT,
        "request",
        "the request did not arrive in time",
    ),
}
_MALFORMED = (
    400,
    ErrorCode.BAD_INPUT,
    "request",
    "malformed request line: expected METHOD PATH HTTP/1.1",
)


def viewer_cookie(headers: list[str]) -> str | None:
    """The value of the viewer's cookie among ``Cookie`` headers (percent-decoded), or None."""
    for header in headers:
        for part in header.split(";"):
            name, sep, value = part.strip().partition("=")
            if sep and name == VIEWER_COOKIE:
                return unquote(value.strip().strip('"'), errors="surrogateescape")
    return None


def _write_busy(wfile: io.BufferedIOBase) -> None:
    """503 for a connection over ``http.max_connections``, written before any request."""
    body = json.dumps(
        {"error": "too many connections", "field": None, "code": ErrorCode.BUSY}
    ).encode()
    head = (
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: application/json\r\n"
        f"Content-Length: {len(body)}\r\nRetry-After: 1\r\nConnection: close\r\n\r\n"
    )
    with contextlib.suppress(OSError):
        wfile.write(head.encode("ascii") + body)


def route_label(path: str) -> str:
    if SESSION_FRAMES_PATH.match(path):
        return "/v1/sessions/{id}/frames"
    if SESSION_LATEST_PATH.match(path):
        return "/v1/sessions/{id}/latest"
    if SESSION_WATCH_PATH.match(path):
        return "/v1/sessions/{id}/watch"
    if SESSION_PATH.match(path):
        return "/v1/sessions/{id}"
    return path if path in _ROUTES else "other"


class HandlerBase(BaseHTTPRequestHandler):
    """Request handler plumbing; `service` is bound by `api.make_handler`."""

    service: ClassVar[ServiceFacade]
    protocol_version = "HTTP/1.1"  # keep-alive; every answer carries Content-Length
    server_version = "sphrender"
    _mode: ConnectionMode = "normal"
    #: The query string of the request being handled (set by `api.ApiHandler` per request).
    _query: dict[str, list[str]]
    _status = 0

    def version_string(self) -> str:
        return self.server_version

    # -- connection -----------------------------------------------------------------------------

    def setup(self) -> None:
        super().setup()
        config = self.service.config.http
        self._reader = DeadlineReader(
            self.connection,
            idle_timeout_s=config.read_timeout_s,
            write_timeout_s=config.read_timeout_s,
            drain_deadline=lambda: self.service.drain_read_deadline,
        )
        self.rfile = io.BufferedReader(self._reader, 65536)

    def handle(self) -> None:
        server = cast(SphrenderHttpServer, self.server)
        mode = server.enter_connection(id(self), self._reader)
        if mode is None:
            _write_busy(self.wfile)
            return
        self._mode = mode
        try:
            super().handle()
        except (ConnectionError, TimeoutError):
            pass  # client went away or idled out between requests
        finally:
            server.leave_connection(id(self), mode)

    def handle_one_request(self) -> None:
        head = self.service.config.http.header_timeout_s
        if self._mode == "health":
            head = min(head, _HEALTH_HEAD_TIMEOUT_S)
        self._reader.expect_request(head)
        self._status = 0
        super().handle_one_request()

    def log_message(self, format: str, *args: Any) -> None:
        log.debug(format % args, extra={"peer": self.client_address[0]})

    def parse_request(self) -> bool:
        """The standard parsing, then any version but 1.0/1.1 refused (HTTP/0.9's two-word
        request line included: the standard library would answer it without a status line)."""
        raw: bytes = getattr(self, "raw_requestline", b"")  # set by the standard library
        words = str(raw, "iso-8859-1").rstrip("\r\n").split()
        other = len(words) == 3 and words[2].startswith("HTTP/") and words[2] not in _VERSIONS
        if len(words) == 2 or other:
            self.command, self.path, self.requestline = "", "", ""
            self.request_version = "HTTP/1.1"  # the refusal has a status line and headers
            self.send_error(HTTPStatus.HTTP_VERSION_NOT_SUPPORTED)
            return False
        return super().parse_request()

    def send_error(self, code: int, message: str | None = None, explain: str | None = None) -> None:
        """The standard library's errors (bad request line, 414, 431, 501, 505) as JSON, in
        this API's words (`message` and `explain` are the library's and are not shown)."""
        code, error_code, field, text = _STDLIB_CODES.get(HTTPStatus(code), _MALFORMED)
        if not hasattr(self, "command") or self.command is None:
            self.command = ""
        if getattr(self, "request_version", "HTTP/0.9") == "HTTP/0.9":
            self.request_version = "HTTP/1.1"  # always a status line and headers (no HTTP/0.9)
        self._reader.end_head()
        headers = {"Allow": "GET, POST, DELETE"} if code == 405 else None
        error = HttpError(code, error_code, text, field, close=True, headers=headers)
        self._send_error(error, method="")

    def handle_expect_100(self) -> bool:
        """curl sends ``Expect: 100-continue`` for large bodies: refuse before the upload."""
        try:
            self._check_auth()
            self._content_length()
        except HttpError as error:
            self._send_error(error, method="POST")
            return False
        return super().handle_expect_100()

    # -- auth and bodies ------------------------------------------------------------------------

    def _count_request(self, status: int) -> None:
        """Counted before the answer is written, so a client that reads /metrics right after
        its answer sees its own request."""
        self._status = status
        route = route_label(urlsplit(self.path).path) if getattr(self, "path", "") else "other"
        self.service.metrics.transport.http_requests.inc(
            self.command or "other", route, str(status)
        )

    def _check_auth(self) -> None:
        """With a token configured, a request needs one of: ``Authorization: Bearer <token>``;
        the viewer's cookie (set by ``GET /?token=<token>``, see `viewer`) on a GET/HEAD,
        or on another method together with the ``X-Sphrender-Viewer`` header (which a page of
        another site cannot send without the CORS preflight this server never grants); or the
        ``token`` query parameter itself on ``GET /`` (the viewer's entry, which trades it for
        the cookie at once)."""
        token = self.service.config.security.token
        if not token:
            return
        expected = token.encode("utf-8")

        def same(value: str) -> bool:
            return hmac.compare_digest(value.encode("utf-8", errors="surrogateescape"), expected)

        presented = self.headers.get("Authorization", "")
        scheme, _, value = presented.partition(" ")
        ok = scheme.lower() == "bearer" and same(value.strip())
        if not ok and (cookie := viewer_cookie(self.headers.get_all("Cookie") or [])) is not None:
            ok = same(cookie) and (self.command in ("GET", "HEAD") or VIEWER_HEADER in self.headers)
        url = urlsplit(getattr(self, "path", ""))
        if not ok and self.command == "GET" and url.path == "/":
            ok = any(same(v) for v in parse_qs(url.query).get("token", []))
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
        values = self.headers.get_all("Content-Length") or []
        if not values:
            raise HttpError(
                411, ErrorCode.BAD_INPUT, "Content-Length is required", "Content-Length", close=True
            )
        texts = {value.strip(" \t") for value in values}
        text = next(iter(texts))
        if len(texts) != 1 or not _CONTENT_LENGTH.fullmatch(text):
            shown = ", ".join(show(v, 40) for v in values[:3])
            raise HttpError(
                400,
                ErrorCode.BAD_INPUT,
                f"Content-Length must be one decimal number of ASCII digits 0-9, got {shown}",
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

    def _read_body(self, length: int) -> bytearray:
        """Exactly `length` bytes into one buffer within ``http.body_timeout_s`` (a deadline for
        the whole body, shortened by a drain), so a dribbling client cannot hold the thread."""
        self._reader.begin_body(self.service.config.http.body_timeout_s)
        body = bytearray(length)
        view = memoryview(body)
        got = 0
        try:
            while got < length:
                n = self.rfile.readinto(view[got:])
                if not n:
                    raise ConnectionError("client closed the connection mid-body")
                got += n
        except TimeoutError:
            raise HttpError(
                408,
                ErrorCode.TIMEOUT,
                "the body did not arrive within http.body_timeout_s"
                if self.service.drain_read_deadline is None
                else "the server is shutting down and the body was not complete",
                "body",
                close=True,
            ) from None
        finally:
            view.release()
            self._reader.end_head()
        self.service.metrics.transport.bytes_in.inc("http", amount=length)
        return body

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
        self.service.metrics.transport.bytes_out.inc("http", amount=len(body))

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
                "path": getattr(self, "path", ""),
            },
        )
        try:
            self._send_json(error.status, payload, headers, close=error.close)
        except OSError:
            self.close_connection = True
