"""Sessions (a validated scene kept between frames) and scene validation for the service.

A session is created once per client scene: ``POST /v1/sessions`` or a stream handshake. The
scene is parsed, checked against the server's limits and warmed on the render thread at creation,
so frames only carry particles (and optionally a partial scene override, merged section by
section onto the session's scene).

Only HTTP sessions count against ``limits.max_sessions`` (stream connections have their own cap,
``stream.max_connections``, so idle HTTP sessions cannot lock streams out). HTTP sessions unused
for ``limits.session_idle_timeout_s`` are deleted by the service's reaper; a stream session lives
as long as its connection.

Scene JSON is at most ``limits.max_scene_bytes``; validated scenes are cached by the SHA-256 of
their text (small texts only), so the cache never holds client text itself.

Environment maps (``[environment] file``) may only come from ``security.environment_dirs``: the
path is resolved (symlinks included) and must lie inside one of them; the scene handed to the
renderer carries the resolved absolute path. Error messages never reveal server paths.
"""

from __future__ import annotations

import hashlib
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from sphrender.core.frame import ParticleFrame
from sphrender.core.protocol import LimitError, parse_json_object
from sphrender.server.engine.lighting.detail_image import find_detail_image
from sphrender.server.engine.lighting.environment import EnvironmentLibrary
from sphrender.server.scene import Scene, scene_from_dict, scene_to_dict
from sphrender.server.service.thermal_history import PeakHistory

#: The answer when the renderer fails to prepare a session's scene (the details are logged).
WARM_FAILED = "preparing the scene failed in the renderer; the server logged the details"


class SessionLimitReached(Exception):
    """``limits.max_sessions`` sessions are open."""


#: Formats whose latest image a session keeps for viewers (what a browser can show), and the
#: largest image kept: a viewer's live view must not hold a server's memory hostage.
VIEWABLE_FORMATS = ("png", "jpeg")
MAX_KEPT_IMAGE_BYTES = 8 << 20


@dataclass(frozen=True)
class LatestImage:
    """The last image a session answered (any transport), for ``GET /v1/sessions/{id}/latest``;
    `data` is None when it was not kept (a format a browser cannot show, or too large)."""

    seq: int
    format: str
    width: int
    height: int
    data: bytes | None


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
    #: Particles the server holds for this session (demo sessions): its frames may then be
    #: JSON bodies with only a partial scene (a camera), rendered with these particles.
    particles: ParticleFrame | None = None
    latest: LatestImage | None = None
    images: int = 0
    peaks: PeakHistory = field(default_factory=PeakHistory)  # thermal history by particle id

    def keep_latest(self, fmt: str, data: bytes, width: int, height: int) -> None:
        """Record an answered image (called once per image, from the answering thread)."""
        self.images += 1
        kept = data if fmt in VIEWABLE_FORMATS and len(data) <= MAX_KEPT_IMAGE_BYTES else None
        self.latest = LatestImage(self.images, fmt, width, height, kept)

    def describe(self) -> dict[str, Any]:
        now = time.monotonic()
        return {
            "id": self.id,
            "transport": self.transport,
            "frames": self.frames,
            "age_s": round(now - self.created_at, 3),
            "idle_s": round(now - self.last_used, 3),
            "demo": self.particles is not None,
            "scene": scene_to_dict(self.scene),
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
            http = sum(1 for s in self._sessions.values() if s.transport == "http")
            if transport == "http" and http >= self.max_sessions:
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

    def listing(self, limit: int = 64) -> list[dict[str, Any]]:
        """The open sessions, newest first (at most `limit`), for the viewer."""
        with self._lock:
            sessions = sorted(self._sessions.values(), key=lambda s: s.created_at, reverse=True)
        return [
            {
                "id": s.id,
                "transport": s.transport,
                "demo": s.particles is not None,
                "images": s.images,
                "latest_format": None if s.latest is None else s.latest.format,
            }
            for s in sessions[:limit]
        ]

    def counts(self) -> dict[str, int]:
        with self._lock:
            result = {"http": 0, "stream": 0}
            for session in self._sessions.values():
                result[session.transport] += 1
            return result


class SceneValidator:
    """Scene JSON -> validated `Scene` under the server's limits (pixels, environment dirs)."""

    #: Scenes cached (by the SHA-256 of their text), and the longest text that is cached.
    CACHE_ENTRIES = 32
    CACHE_MAX_TEXT = 64 * 1024

    def __init__(
        self, max_pixels: int, environment_dirs: Sequence[str], max_scene_bytes: int = 1 << 20
    ) -> None:
        self.max_pixels = max_pixels
        self.max_scene_bytes = max_scene_bytes
        self._environments = EnvironmentLibrary(environment_dirs)
        self._cache: OrderedDict[bytes, tuple[Scene, dict[str, Any]]] = OrderedDict()
        self._cache_lock = threading.Lock()

    def check_size(self, size: int, field: str = "scene") -> None:
        if size > self.max_scene_bytes:
            raise LimitError(
                field,
                f"the scene text is {size} bytes; this server's limit is {self.max_scene_bytes} "
                "bytes (limits.max_scene_bytes)",
            )

    def from_json(self, text: str) -> tuple[Scene, dict[str, Any]]:
        data = text.encode("utf-8", errors="surrogatepass")
        self.check_size(len(data))
        key = hashlib.sha256(data).digest()
        with self._cache_lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        raw = parse_json_object(data, "scene")
        result = (self.from_dict(raw), raw)
        if len(data) <= self.CACHE_MAX_TEXT:
            with self._cache_lock:
                self._cache[key] = result
                while len(self._cache) > self.CACHE_ENTRIES:
                    self._cache.popitem(last=False)
        return result

    def from_dict(self, raw: Mapping[str, Any]) -> Scene:
        scene = scene_from_dict(raw, max_pixels=self.max_pixels)
        self._check_environment_file(scene)
        return scene

    def _check_environment_file(self, scene: Scene) -> None:
        """Fail at submission, not at render time, when `[environment] file` or `[finish]
        detail_image` names a file outside the configured directories (the render thread
        applies the same rule; what the file holds is checked there)."""
        if scene.environment.file is not None:
            self._environments.find_file(scene.environment.file)
        if scene.finish.detail_image is not None:
            find_detail_image(self._environments.directories, scene.finish.detail_image)
