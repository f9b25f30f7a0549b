"""Sessions (a validated scene kept between frames) and scene validation for the service.

A session is created once per client scene: ``POST /v1/sessions`` or a stream handshake. The
scene is parsed, checked against the server's limits and warmed on the render thread at creation,
so frames only carry particles (and optionally a partial scene override, merged section by
section onto the session's scene).

Both transports count against ``limits.max_sessions``. HTTP sessions unused for
``limits.session_idle_timeout_s`` are deleted by the service's reaper; a stream session lives as
long as its connection.

Environment maps (``[environment] file``) may only come from ``security.environment_dirs``: the
path is resolved (symlinks included) and must lie inside one of them; the scene handed to the
renderer carries the resolved absolute path. Error messages never reveal server paths.
"""

from __future__ import annotations

import functools
import secrets
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from sphrender.client.protocol import LimitError, parse_json_object
from sphrender.server.engine.lighting.environment import EnvironmentLibrary
from sphrender.server.scene import Scene, scene_from_dict


class SessionLimitReached(Exception):
    """``limits.max_sessions`` sessions are open."""


@dataclass(eq=False)
class Session:
    id: str
    scene: Scene
    raw_scene: dict[str, Any]
    transport: Literal["http", "stream"]
    created_at: float = field(default_factory=time.monotonic)
    last_used: float = field(default_factory=time.monotonic)
    frames: int = 0
    active: int = 0  # HTTP frames in progress; a busy session is never reaped

    def describe(self) -> dict[str, Any]:
        now = time.monotonic()
        return {
            "id": self.id,
            "transport": self.transport,
            "frames": self.frames,
            "age_s": round(now - self.created_at, 3),
            "idle_s": round(now - self.last_used, 3),
            "scene": self.raw_scene,
        }


class SessionRegistry:
    """Thread-safe table of open sessions with a hard cap."""

    def __init__(self, max_sessions: int, idle_timeout_s: float) -> None:
        self.max_sessions = max_sessions
        self.idle_timeout_s = idle_timeout_s
        self._lock = threading.Lock()
        self._sessions: dict[str, Session] = {}

    def add(
        self, scene: Scene, raw_scene: dict[str, Any], transport: Literal["http", "stream"]
    ) -> Session:
        with self._lock:
            if len(self._sessions) >= self.max_sessions:
                raise SessionLimitReached
            session = Session(secrets.token_hex(16), scene, raw_scene, transport)
            self._sessions[session.id] = session
            return session

    def get(self, session_id: str, *, touch: bool = True) -> Session | None:
        """The session, marked as used unless `touch` is False (looking is not using)."""
        with self._lock:
            session = self._sessions.get(session_id)
            if session is not None and touch:
                session.last_used = time.monotonic()
            return session

    def begin_frame(self, session: Session) -> None:
        """A frame of `session` is in progress (it is not reaped meanwhile)."""
        with self._lock:
            session.active += 1
            session.frames += 1
            session.last_used = time.monotonic()

    def end_frame(self, session: Session) -> None:
        with self._lock:
            session.active -= 1
            session.last_used = time.monotonic()

    def remove(self, session_id: str) -> Session | None:
        with self._lock:
            return self._sessions.pop(session_id, None)

    def reap_idle(self) -> list[Session]:
        """Remove HTTP sessions idle past the timeout (never one with a frame in progress)."""
        now = time.monotonic()
        with self._lock:
            idle = [
                s
                for s in self._sessions.values()
                if s.transport == "http"
                and s.active == 0
                and now - s.last_used > self.idle_timeout_s
            ]
            for session in idle:
                del self._sessions[session.id]
        return idle

    def counts(self) -> dict[str, int]:
        with self._lock:
            result = {"http": 0, "stream": 0}
            for session in self._sessions.values():
                result[session.transport] += 1
            return result


class SceneValidator:
    """Scene JSON -> validated `Scene` under the server's limits (pixels, environment dirs)."""

    def __init__(self, max_pixels: int, environment_dirs: Sequence[str]) -> None:
        self.max_pixels = max_pixels
        self._environments = EnvironmentLibrary(environment_dirs)
        self.from_json = functools.lru_cache(maxsize=128)(self._from_json_uncached)

    def _from_json_uncached(self, text: str) -> tuple[Scene, dict[str, Any]]:
        raw = parse_json_object(text.encode("utf-8"), "scene")
        return self.from_dict(raw), raw

    def from_dict(self, raw: Mapping[str, Any]) -> Scene:
        scene = scene_from_dict(raw)
        self._check_environment_file(scene)
        pixels = scene.image.width * scene.image.height
        if pixels > self.max_pixels:
            raise LimitError(
                "image",
                f"{scene.image.width}x{scene.image.height} = {pixels} pixels exceeds this "
                f"server's limit of {self.max_pixels}",
            )
        return scene

    def _check_environment_file(self, scene: Scene) -> None:
        """Fail at submission, not at render time, when `[environment] file` names a file
        outside the configured directories (the render thread applies the same rule)."""
        if scene.environment.file is not None:
            self._environments.find_file(scene.environment.file)
