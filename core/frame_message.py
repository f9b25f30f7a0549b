"""A FRAME's arrays in either encoding (raw or compact), judged from its header first.

The stream reader and the HTTP ``application/x-sphrender-frame`` body (a whole FRAME message)
both go through here: `plan_frame` checks the header against the payload length and the limits
before the payload is read; `FrameDecoder.decode` turns the payload into arrays.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sphrender.core.compact import ENCODING, CompactDecoder, plan_compact_arrays
from sphrender.core.errors import InputError, LimitError, show
from sphrender.core.protocol import (
    PREFIX_SIZE,
    MessageType,
    ProtocolError,
    decode_frame_arrays,
    parse_header,
    parse_prefix,
    plan_frame_arrays,
)

__all__ = [
    "ENCODINGS",
    "FRAME_CONTENT_TYPE",
    "FrameDecoder",
    "FramePlan",
    "decode_frame_body",
    "plan_frame",
]

#: The frame encodings a FRAME header's ``encoding`` may name (absent = raw).
ENCODINGS: tuple[str, ...] = ("raw", ENCODING)
#: HTTP content type of a body holding one whole FRAME message (either encoding).
FRAME_CONTENT_TYPE = "application/x-sphrender-frame"


@dataclass(frozen=True)
class FramePlan:
    encoding: str
    count: int
    names: tuple[str, ...]


def frame_encoding(header: Mapping[str, Any]) -> str:
    encoding = header.get("encoding", "raw")
    if encoding not in ENCODINGS:
        raise InputError(
            "header.encoding", f"must be one of {', '.join(ENCODINGS)}, got {show(encoding)}"
        )
    return str(encoding)


def plan_frame(header: Mapping[str, Any], payload_length: int, *, max_particles: int) -> FramePlan:
    """Everything the header declares, checked before the payload is read."""
    encoding = frame_encoding(header)
    if encoding == "raw":
        if "base" in header:
            raise InputError("header.base", "is only for compact frames")
        slots, count = plan_frame_arrays(
            header.get("arrays"), payload_length, max_particles=max_particles
        )
        return FramePlan(encoding, count, tuple(slot.name for slot in slots))
    compact, count = plan_compact_arrays(header, payload_length, max_particles=max_particles)
    return FramePlan(encoding, count, tuple(slot.name for slot in compact))


@dataclass
class FrameDecoder:
    """Decodes one session's FRAMEs (holds the compact encoding's previous frame)."""

    compact: CompactDecoder = field(default_factory=CompactDecoder)

    def forget(self) -> None:
        """Hold no previous frame (after a raw frame, or a frame refused from its header)."""
        self.compact.forget()

    def decode(
        self,
        header: Mapping[str, Any],
        payload: bytes | bytearray | memoryview,
        *,
        max_particles: int,
    ) -> dict[str, np.ndarray]:
        if frame_encoding(header) == "raw":
            self.forget()
            return decode_frame_arrays(header["arrays"], payload, max_particles=max_particles)
        return self.compact.decode(header, payload, max_particles=max_particles)


def decode_frame_body(
    body: bytes | bytearray | memoryview,
    *,
    max_header_bytes: int,
    max_particles: int,
    max_scene_bytes: int,
    admit: Callable[[str | None, int, tuple[str, ...]], None],
) -> dict[str, np.ndarray]:
    """An HTTP body holding one FRAME message: prefix, header, payload. `admit(scene JSON,
    particles, array names)` is called after the header is checked and before anything is
    decoded (it reserves memory). A delta frame (``base``) is refused: HTTP frames stand alone."""
    view = memoryview(body).cast("B")
    if view.nbytes < PREFIX_SIZE:
        raise InputError("body", f"is {view.nbytes} bytes, shorter than a message prefix (16)")
    try:
        kind, header_len, payload_len = parse_prefix(
            view[:PREFIX_SIZE],
            max_header_bytes=max_header_bytes,
            max_payload_bytes=view.nbytes,
        )
        if kind != MessageType.FRAME:
            raise InputError("type", f"must be FRAME (0x02), got 0x{int(kind):02x}")
        if PREFIX_SIZE + header_len + payload_len != view.nbytes:
            raise InputError(
                "payload_length",
                f"the prefix declares {PREFIX_SIZE + header_len + payload_len} bytes in all, "
                f"the body has {view.nbytes}",
            )
        header = parse_header(view[PREFIX_SIZE : PREFIX_SIZE + header_len])
    except ProtocolError as exc:
        raise InputError(exc.field or "body", exc.message) from None
    for key in header:
        if key not in ("id", "arrays", "scene", "encoding", "base"):
            raise InputError(f"header.{key}", "unknown key; allowed: id, arrays, scene, encoding")
    if "base" in header:
        raise InputError(
            "header.base", "an HTTP frame cannot be predicted from another frame; send it in full"
        )
    plan = plan_frame(header, payload_len, max_particles=max_particles)
    scene = header.get("scene")
    if scene is not None and not isinstance(scene, dict):
        raise InputError("scene", "must be a JSON object")
    scene_json = None if scene is None else json.dumps(scene)
    if scene_json is not None and len(scene_json) > max_scene_bytes:
        raise LimitError(
            "scene", f"of {len(scene_json)} bytes exceeds the limit of {max_scene_bytes}"
        )
    admit(scene_json, plan.count, plan.names)
    payload = view[PREFIX_SIZE + header_len :]
    one_frame = FrameDecoder(CompactDecoder(hold=False))
    return one_frame.decode(header, payload, max_particles=max_particles)
