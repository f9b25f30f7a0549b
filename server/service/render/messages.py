"""The messages between the render worker (service process) and the render process.

Two directions, two encodings:

* worker -> process (`Request`): pickled by `Connection.send`; the process is our own code, so
  pickling is trusted here. A `FrameRequest` is followed by one raw ``send_bytes`` per entry of
  its ``arrays`` (no pickling copy of the particle buffers).
* process -> worker (`Answer`): *never pickled* (a process whose memory may be corrupt must not
  be able to make the service run code): one JSON object with a ``type`` tag per answer, and for
  an `ImageAnswer` the encoded image in the next ``send_bytes``. Every answer travels with the
  process's `Health` (resident bytes, whether the GL context was rebuilt).

`decode_answer` checks every field's type, so the worker never handles an untyped value; a
malformed answer raises `ValueError` (the worker treats the process as broken).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from typing import TypeAlias

from sphrender.core.protocol import ImageFormat
from sphrender.server.scene import Scene

# -- worker -> render process -------------------------------------------------------------------


@dataclass(frozen=True)
class ArraySpec:
    """One particle buffer that follows a `FrameRequest` as raw bytes."""

    name: str  # a frame array: positions, densities, radii, temperatures, peak_temperatures,
    # solid, or velocities (shutter open)
    dtype: str  # numpy dtype string, e.g. "<f8"
    shape: tuple[int, ...]


@dataclass(frozen=True)
class FrameRequest:
    id: int
    scene: Scene
    format: ImageFormat
    #: 1-based number of this frame over the life of the service (survives process restarts).
    seq: int
    arrays: tuple[ArraySpec, ...]


@dataclass(frozen=True)
class WarmRequest:
    """Render one particle with `scene` and throw the image away (programs, targets, LUTs)."""

    id: int
    scene: Scene


@dataclass(frozen=True)
class StopRequest:
    """Finish the frames in hand and exit."""


Request: TypeAlias = FrameRequest | WarmRequest | StopRequest

# -- render process -> worker -------------------------------------------------------------------


@dataclass(frozen=True)
class Health:
    rss: int  # resident bytes of the render process
    rebuilt: bool  # the GL context was rebuilt since the previous answer


@dataclass(frozen=True)
class Ready:
    pid: int
    gl_renderer: str
    gl_version: str
    max_image_side: int
    warm_ms: float
    # The OpenCL device of the SPH stages (None without one): platform, device, type.
    cl_platform: str | None = None
    cl_device: str | None = None
    cl_type: str | None = None


@dataclass(frozen=True)
class StartupFailed:
    error: str


@dataclass(frozen=True)
class ArrayLayout:
    """A raw image's array descriptor (PROTOCOL.md §4.3)."""

    name: str
    dtype: str
    shape: tuple[int, ...]


@dataclass(frozen=True)
class Note:
    """What the renderer changed about a frame's input."""

    field: str
    message: str


@dataclass(frozen=True)
class ImageAnswer:
    """The encoded image follows in the next ``send_bytes``."""

    id: int
    width: int
    height: int
    particles: int
    drawn: int
    timings_ms: dict[str, float]  # the renderer's stages and encode
    host_ms: float
    recv_ms: float  # reading the particle buffers from the pipe
    arrays: tuple[ArrayLayout, ...] | None  # raw only
    notes: tuple[Note, ...]


@dataclass(frozen=True)
class ErrorAnswer:
    id: int
    code: str  # bad_input or render_failed
    message: str
    field: str | None


@dataclass(frozen=True)
class Started:
    """The process began job `id` (its render clock starts: ``limits.render_timeout_s``)."""

    id: int


@dataclass(frozen=True)
class WarmError:
    input: bool  # an InputError (the scene), else a render failure
    field: str | None
    message: str


@dataclass(frozen=True)
class WarmAnswer:
    id: int
    error: WarmError | None


Answer: TypeAlias = Ready | StartupFailed | Started | ImageAnswer | ErrorAnswer | WarmAnswer

_TAGS: dict[type[Answer], str] = {
    Ready: "ready",
    StartupFailed: "startup_failed",
    Started: "started",
    ImageAnswer: "image",
    ErrorAnswer: "error",
    WarmAnswer: "warm",
}


def encode_answer(answer: Answer, health: Health) -> bytes:
    """The JSON bytes of one answer (`decode_answer` reads them back)."""
    body = {"type": _TAGS[type(answer)], **asdict(answer), **asdict(health)}
    return json.dumps(body, allow_nan=False).encode("utf-8")


# -- decoding: every field checked, so nothing untyped reaches the worker ---------------------


class _Fields:
    """Typed reads of one decoded JSON object; a missing or mistyped field is a ValueError."""

    def __init__(self, value: object, what: str = "answer") -> None:
        if not isinstance(value, dict):
            raise ValueError(f"{what} is not a JSON object")
        self._body: dict[str, object] = value
        self._what = what

    def _get(self, key: str) -> object:
        if key not in self._body:
            raise ValueError(f"{self._what} has no {key!r}")
        return self._body[key]

    def integer(self, key: str) -> int:
        value = self._get(key)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{self._what}.{key} is not an integer")
        return value

    def number(self, key: str) -> float:
        value = self._get(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{self._what}.{key} is not a number")
        return float(value)

    def flag(self, key: str) -> bool:
        value = self._get(key)
        if not isinstance(value, bool):
            raise ValueError(f"{self._what}.{key} is not a boolean")
        return value

    def text(self, key: str) -> str:
        value = self._get(key)
        if not isinstance(value, str):
            raise ValueError(f"{self._what}.{key} is not a string")
        return value

    def optional_text(self, key: str) -> str | None:
        return None if self._get(key) is None else self.text(key)

    def items(self, key: str) -> list[object]:
        value = self._get(key)
        if not isinstance(value, list):
            raise ValueError(f"{self._what}.{key} is not a list")
        return value

    def child(self, key: str) -> _Fields:
        return _Fields(self._get(key), f"{self._what}.{key}")

    def is_null(self, key: str) -> bool:
        return self._get(key) is None

    def float_map(self, key: str) -> dict[str, float]:
        inner = self.child(key)
        return {name: inner.number(name) for name in inner._body}

    def shape(self, key: str) -> tuple[int, ...]:
        shape = self.items(key)
        if not all(isinstance(n, int) and not isinstance(n, bool) for n in shape):
            raise ValueError(f"{self._what}.{key} is not a list of integers")
        return tuple(n for n in shape if isinstance(n, int))


def _layouts(fields: _Fields) -> tuple[ArrayLayout, ...] | None:
    if fields.is_null("arrays"):
        return None
    layouts = (_Fields(item, "answer.arrays[]") for item in fields.items("arrays"))
    return tuple(ArrayLayout(a.text("name"), a.text("dtype"), a.shape("shape")) for a in layouts)


def _decode(tag: str, fields: _Fields) -> Answer:
    match tag:
        case "ready":
            return Ready(
                pid=fields.integer("pid"),
                gl_renderer=fields.text("gl_renderer"),
                gl_version=fields.text("gl_version"),
                max_image_side=fields.integer("max_image_side"),
                warm_ms=fields.number("warm_ms"),
                cl_platform=fields.optional_text("cl_platform"),
                cl_device=fields.optional_text("cl_device"),
                cl_type=fields.optional_text("cl_type"),
            )
        case "startup_failed":
            return StartupFailed(fields.text("error"))
        case "started":
            return Started(fields.integer("id"))
        case "image":
            notes = (_Fields(item, "answer.notes[]") for item in fields.items("notes"))
            return ImageAnswer(
                id=fields.integer("id"),
                width=fields.integer("width"),
                height=fields.integer("height"),
                particles=fields.integer("particles"),
                drawn=fields.integer("drawn"),
                timings_ms=fields.float_map("timings_ms"),
                host_ms=fields.number("host_ms"),
                recv_ms=fields.number("recv_ms"),
                arrays=_layouts(fields),
                notes=tuple(Note(n.text("field"), n.text("message")) for n in notes),
            )
        case "error":
            return ErrorAnswer(
                id=fields.integer("id"),
                code=fields.text("code"),
                message=fields.text("message"),
                field=fields.optional_text("field"),
            )
        case "warm":
            error = None
            if not fields.is_null("error"):
                e = fields.child("error")
                error = WarmError(e.flag("input"), e.optional_text("field"), e.text("message"))
            return WarmAnswer(fields.integer("id"), error)
    raise ValueError(f"unknown answer type {tag!r}")


def decode_answer(message: bytes) -> tuple[Answer, Health]:
    """One answer and the health it carries, from `encode_answer`'s bytes (ValueError if
    malformed)."""
    fields = _Fields(json.loads(message))
    health = Health(rss=fields.integer("rss"), rebuilt=fields.flag("rebuilt"))
    return _decode(fields.text("type"), fields), health
