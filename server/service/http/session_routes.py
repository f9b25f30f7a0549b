"""Session routes of the HTTP API: create (``POST /v1/sessions``, ``POST /v1/demo/sessions``),
describe (``GET /v1/sessions/{id}``) and delete (``DELETE /v1/sessions/{id}``).

Creating a session warms its scene on the render process, so the first frame does not pay for
compiling programs; the answer carries the resolved scene (every default filled in).
"""

from __future__ import annotations

import logging
from typing import Any

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.core.protocol import ErrorCode, parse_json_object
from sphrender.server.content.demo import demo_scene_dict
from sphrender.server.scene import merge_scene_dicts, scene_to_dict
from sphrender.server.service.admission import decoding
from sphrender.server.service.facade import ServiceFacade
from sphrender.server.service.http.errors import HttpError
from sphrender.server.service.http.handler import HandlerBase
from sphrender.server.service.render.scheduler import SchedulerClosed
from sphrender.server.service.sessions import WARM_FAILED, Session, SessionLimitReached

log = logging.getLogger("sphrender.service.http")


def find_session(
    service: ServiceFacade, session_id: str, method: str, *, touch: bool = True
) -> Session:
    """An HTTP session by id, or 404 (a POST's connection closes: its body is unread)."""
    session = service.sessions.get(session_id, touch=touch)
    if session is None or session.transport != "http":
        raise HttpError(
            404,
            ErrorCode.NOT_FOUND,
            "no such session (deleted or expired)",
            "session",
            close=method == "POST",
        )
    return session


class SessionRoutes:
    """The session routes of one request on `http` (see the module docstring)."""

    def __init__(self, http: HandlerBase, service: ServiceFacade) -> None:
        self.http = http
        self.service = service

    def create_session(self) -> None:
        raw = self._scene_body()
        session = self._open_session(raw)
        self._answer_session(session)

    def create_demo_session(self) -> None:
        """A session of the built-in demo (the weld bead of `sphrender demo`), whose particles
        the server holds; the body, if any, is a partial scene laid over the demo's."""
        raw = merge_scene_dicts(demo_scene_dict(), self._scene_body())
        session = self._open_session(raw, self.service.demo_particles())
        self._answer_session(session)

    def _scene_body(self) -> dict[str, Any]:
        body = self.http._read_body(
            self.http._content_length(limit=self.service.config.limits.max_scene_bytes)
        )
        try:
            with decoding("scene", "http"):
                return parse_json_object(body, "scene") if body.strip() else {}
        except InputError as exc:
            raise HttpError.from_input(exc) from None

    def _answer_session(self, session: Session) -> None:
        self.http._send_json(
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
            log.warning("warm failed", extra={"event": "warm_failed", "detail": str(exc)})
            raise HttpError(500, ErrorCode.RENDER_FAILED, WARM_FAILED) from None
        session.particles = particles  # before anyone knows the id
        return session

    def get_session(self, session_id: str) -> None:
        session = find_session(self.service, session_id, self.http.command, touch=False)
        self.http._send_json(200, session.describe())

    def delete_session(self, session_id: str) -> None:
        if not self.service.close_session(session_id):
            raise HttpError(404, ErrorCode.NOT_FOUND, "no such session", "session")
        self.http._count_request(204)
        self.http.send_response(204)
        self.http.send_header("Content-Length", "0")
        self.http.end_headers()
