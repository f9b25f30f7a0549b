"""The client side of the compact frame encoding on a stream (PROTOCOL.md §4.7).

`CompactSender` turns a frame's arrays into a compact FRAME message when the server's WELCOME
offers ``compact``: positions within an absolute error of `POSITION_ERROR_FRACTION` x the
particle radius unless told otherwise, the other arrays at `DEFAULT_ERRORS`, each frame
predicted from the one before when that is smaller; positions may be sent order-free (the
frame's particles reordered, every array with them) unless `reorder` is False. It keeps the
arrays of every frame sent predicted from another until it is answered, so that a frame the
server answers with an error on ``base`` (it does not hold the frame predicted from) is sent
again in full.

A frame the encoder cannot quantise (NaN, a bound finer than float64 resolves) goes out raw, so
the server's error names the problem exactly as it does for every other client.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from sphrender.core.compact_encoder import POSITION_ERROR_FRACTION, CompactEncoder
from sphrender.core.errors import InputError
from sphrender.core.protocol import MessageType, encode_frame, encode_message

__all__ = ["CompactSender", "compact_body", "offered"]

#: The scene's particle radius when WELCOME does not say it (the schema's default).
_DEFAULT_RADIUS = 0.015


def offered(welcome: Mapping[str, Any]) -> bool:
    """Does this WELCOME offer the compact encoding?"""
    encodings = welcome.get("frame_encodings")
    return isinstance(encodings, list) and "compact" in encodings


def _scene_radius(welcome: Mapping[str, Any]) -> float:
    scene = welcome.get("scene")
    particles = scene.get("particles") if isinstance(scene, dict) else None
    radius = particles.get("radius") if isinstance(particles, dict) else None
    return float(radius) if isinstance(radius, int | float) and radius > 0 else _DEFAULT_RADIUS


def _plain(wire: Mapping[str, np.ndarray]) -> bool:
    """Numeric arrays of the shapes FRAME declares: (N, 3) positions, (N,) or (N, 3) others."""
    n = wire["positions"].shape[0] if wire["positions"].ndim == 2 else -1
    return wire["positions"].shape == (n, 3) and all(
        a.dtype.kind in "fiu" and a.shape in ((n,), (n, 3)) for a in wire.values()
    )


class CompactSender:
    """Compact FRAME messages for one stream session (see the module docstring)."""

    def __init__(
        self,
        welcome: Mapping[str, Any],
        *,
        position_error: float | None = None,
        errors: Mapping[str, float | None] | None = None,
        reorder: bool = True,
    ) -> None:
        self.fixed_error = position_error
        radius = _scene_radius(welcome)
        error = position_error if position_error is not None else POSITION_ERROR_FRACTION * radius
        self.encoder = CompactEncoder(
            position_error=error, errors=dict(errors or {}), reorder=reorder
        )
        self._pending: dict[int, tuple[object, dict[str, Any]]] = {}

    def message(self, frame_id: int, positions: object, arrays: Mapping[str, Any]) -> bytes:
        """The FRAME for `positions` and `arrays` (densities, ..., and ``scene``)."""
        wire, scene = self._wire_arrays(positions, arrays)
        if not _plain(wire):  # let the server name what is wrong with it
            self.encoder.reset()
            return encode_frame(frame_id, positions, **arrays)
        if self.fixed_error is None and "radii" in wire and wire["radii"].size:
            self.encoder.position_error = POSITION_ERROR_FRACTION * float(wire["radii"].min())
        try:
            header, payload = self.encoder.encode(frame_id, wire)
        except InputError:
            self.encoder.reset()
            return encode_frame(frame_id, positions, **arrays)
        if scene is not None:
            header["scene"] = dict(scene)
        if "base" in header:
            self._pending[frame_id] = (positions, dict(arrays))
        return encode_message(MessageType.FRAME, header, payload)

    def answered(self, frame_id: int) -> None:
        self._pending.pop(frame_id, None)

    def resend(self, frame_id: int, field: object) -> bytes | None:
        """The frame in full when the server refused it for its ``base``; else None."""
        kept = self._pending.pop(frame_id, None)
        if field != "base" or kept is None:
            return None
        self.encoder.reset()
        positions, arrays = kept
        return self.message(frame_id, positions, arrays)

    @staticmethod
    def _wire_arrays(
        positions: object, arrays: Mapping[str, Any]
    ) -> tuple[dict[str, np.ndarray], Mapping[str, Any] | None]:
        try:
            wire = {"positions": np.asarray(positions, dtype="<f8")}
        except (TypeError, ValueError):
            wire = {"positions": np.zeros((0, 0))}
        scene = None
        for name, value in arrays.items():
            if name == "scene":
                scene = value
            elif value is not None:
                array = np.asarray(value)
                if array.dtype.kind == "f":
                    array = array.astype("<f4")
                elif array.dtype.kind in "iu" and array.dtype.itemsize not in (4, 8):
                    array = array.astype("<i8")
                wire[name] = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<"))
        return wire, scene


def compact_body(
    positions: object, scene: Mapping[str, Any] | None, arrays: Mapping[str, Any]
) -> bytes:
    """An HTTP body of one compact FRAME (``application/x-sphrender-frame``), positions within
    `POSITION_ERROR_FRACTION` x the scene's particle radius (its default when not given)."""
    sender = CompactSender({"scene": dict(scene or {})})
    named = {k: v for k, v in arrays.items() if v is not None}
    return sender.message(0, positions, {**named, "scene": scene} if scene else named)
