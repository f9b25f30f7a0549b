"""The wire codec shared by the render service and its clients (numpy + stdlib only).

Two encodings of one particle frame live here:

* **The streaming protocol** (``PROTOCOL.md`` is the normative description; this module is its
  reference implementation). Every message is a 16-byte prefix, a UTF-8 JSON header and a raw
  payload::

      offset size  field
      0      4     magic  b"SPHR"
      4      1     protocol version (1)
      5      1     message type (`MessageType`)
      6      2     flags, u16 little-endian, must be 0
      8      4     header length in bytes, u32 little-endian
      12     4     payload length in bytes, u32 little-endian

  A FRAME's header lists its arrays (``name``, ``dtype``, ``shape``); the payload is those arrays'
  little-endian bytes concatenated in the listed order, without padding.

* **The HTTP body** of ``POST /v1/render``: an ``.npz`` archive (``np.savez``) with the arrays of
  the ``.npz`` input format and an optional ``scene`` entry holding scene JSON as a 0-d string
  array. `decode_npz_frame` parses the archive itself, entry by entry, so nothing is ever
  unpickled and no declared size is trusted before it has been checked against the limits (a
  small compressed body cannot expand into gigabytes).

Errors: framing problems raise `ProtocolError` (the connection cannot continue); problems with a
frame's content raise `InputError` naming the field, and `LimitError` (an `InputError`) when a
configured size limit is exceeded, so transports can answer 413 rather than 400.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Literal, TypeAlias

import numpy as np

from sphrender.core.errors import InputError, LimitError, kind_of, show
from sphrender.core.npz_body import NpzFrame, decode_npz_frame, encode_npz_frame

__all__ = [
    "ARRAY_NAMES",
    "ID_DTYPES",
    "IMAGE_FORMATS",
    "MAGIC",
    "MAX_FRAME_ID",
    "PREFIX",
    "PREFIX_SIZE",
    "SOLID_DTYPES",
    "VECTOR_ARRAYS",
    "VERSION",
    "WIRE_DTYPES",
    "ArraySlot",
    "ErrorCode",
    "ImageFormat",
    "LimitError",
    "Message",
    "MessageType",
    "NpzFrame",
    "ProtocolError",
    "decode_frame_arrays",
    "decode_npz_frame",
    "encode_frame",
    "encode_message",
    "encode_npz_frame",
    "parse_header",
    "parse_prefix",
    "plan_frame_arrays",
    "read_message",
]

#: First four bytes of every message.
MAGIC = b"SPHR"
#: The protocol version this module speaks (byte 4 of every message).
VERSION = 1
#: magic, version, type, flags, header length, payload length; little-endian, no padding.
PREFIX = struct.Struct("<4sBBHII")
PREFIX_SIZE = PREFIX.size  # 16
#: Frame ids are JSON integers; 2**53 - 1 is the largest every JSON library represents exactly.
MAX_FRAME_ID = 2**53 - 1
#: The arrays a frame may carry, as in the .npz input format.
ARRAY_NAMES: tuple[str, ...] = (
    "positions",
    "densities",
    "radii",
    "temperatures",
    "velocities",
    "ids",
    "peak_temperatures",
    "solid",
)
#: Arrays of N rows of 3 values; the others are (N,).
VECTOR_ARRAYS: frozenset[str] = frozenset({"positions", "velocities"})
#: The image encodings an IMAGE (and an HTTP render) can carry (PROTOCOL.md §4.3).
ImageFormat: TypeAlias = Literal["png", "exr", "jpeg", "raw"]
IMAGE_FORMATS: tuple[ImageFormat, ...] = ("png", "exr", "jpeg", "raw")
#: Wire dtype names (numpy's array-protocol strings, always little-endian) -> numpy dtype.
WIRE_DTYPES: dict[str, np.dtype[Any]] = {"<f4": np.dtype("<f4"), "<f8": np.dtype("<f8")}
#: The dtypes of ``ids`` (integers; the other arrays are floats).
ID_DTYPES: dict[str, np.dtype[Any]] = {t: np.dtype(t) for t in ("<i4", "<u4", "<i8", "<u8")}
#: The dtypes of ``solid`` (one byte per particle, 0 or 1).
SOLID_DTYPES: dict[str, np.dtype[Any]] = {t: np.dtype(t) for t in ("|u1", "|b1")}
#: How deep a JSON header may nest (a scene is 3 levels deep; this leaves room and no more).
MAX_JSON_DEPTH = 16
#: Longest JSON integer accepted, in digits: every 64-bit integer fits (2**64 has 20 digits).
MAX_JSON_INT_DIGITS = 20


class MessageType(IntEnum):
    """Byte 5 of the prefix. Client -> server below 0x80, server -> client from 0x80."""

    HELLO = 0x01
    FRAME = 0x02
    BYE = 0x03
    WELCOME = 0x81
    IMAGE = 0x82
    ERROR = 0x83
    DROPPED = 0x84
    GOODBYE = 0x85


class ErrorCode:
    """The ``code`` of an ERROR message (and of HTTP error bodies), with its HTTP status."""

    BAD_INPUT = "bad_input"
    TOO_LARGE = "too_large"
    UNAUTHORIZED = "unauthorized"
    NOT_FOUND = "not_found"
    BUSY = "busy"
    SHUTTING_DOWN = "shutting_down"
    RENDER_FAILED = "render_failed"
    TIMEOUT = "timeout"
    PROTOCOL = "protocol"
    UNSUPPORTED_VERSION = "unsupported_version"

    HTTP_STATUS: Mapping[str, int] = {
        BAD_INPUT: 400,
        TOO_LARGE: 413,
        UNAUTHORIZED: 401,
        NOT_FOUND: 404,
        BUSY: 503,
        SHUTTING_DOWN: 503,
        RENDER_FAILED: 500,
        TIMEOUT: 408,
        PROTOCOL: 400,
        UNSUPPORTED_VERSION: 400,
    }


class ProtocolError(Exception):
    """A message that breaks the framing; the connection is answered once and then closed."""

    def __init__(self, code: str, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.field = field


@dataclass(frozen=True)
class Message:
    type: MessageType
    header: dict[str, Any]
    payload: memoryview


# --------------------------------------------------------------------------------------------
# Framing


def encode_message(
    kind: MessageType, header: Mapping[str, Any], payload: bytes | memoryview = b""
) -> bytes:
    """One complete message: prefix + compact JSON header + payload."""
    header_bytes = json.dumps(header, separators=(",", ":"), allow_nan=False).encode("utf-8")
    payload_view = memoryview(payload).cast("B")
    prefix = PREFIX.pack(MAGIC, VERSION, int(kind), 0, len(header_bytes), payload_view.nbytes)
    return b"".join((prefix, header_bytes, payload_view))


def parse_prefix(
    prefix: bytes | bytearray | memoryview, *, max_header_bytes: int, max_payload_bytes: int
) -> tuple[MessageType, int, int]:
    """Check a 16-byte prefix; returns (type, header length, payload length)."""
    if len(prefix) != PREFIX_SIZE:
        raise ProtocolError(ErrorCode.PROTOCOL, f"prefix must be {PREFIX_SIZE} bytes")
    magic, version, kind, flags, header_len, payload_len = PREFIX.unpack(prefix)
    if magic != MAGIC:
        raise ProtocolError(
            ErrorCode.PROTOCOL,
            f"bad magic (bytes {bytes(magic).hex(' ')}), expected 53 50 48 52 (ASCII SPHR)",
            "magic",
        )
    if version != VERSION:
        raise ProtocolError(
            ErrorCode.UNSUPPORTED_VERSION,
            f"protocol version {version} is not supported; this server speaks {VERSION}",
            "version",
        )
    try:
        message_type = MessageType(kind)
    except ValueError:
        raise ProtocolError(
            ErrorCode.PROTOCOL, f"unknown message type 0x{kind:02x}", "type"
        ) from None
    if flags != 0:
        raise ProtocolError(ErrorCode.PROTOCOL, f"flags must be 0, got {flags}", "flags")
    if header_len > max_header_bytes:
        raise ProtocolError(
            ErrorCode.TOO_LARGE,
            f"header of {header_len} bytes exceeds the limit of {max_header_bytes}",
            "header_length",
        )
    if payload_len > max_payload_bytes:
        raise ProtocolError(
            ErrorCode.TOO_LARGE,
            f"payload of {payload_len} bytes exceeds the limit of {max_payload_bytes}",
            "payload_length",
        )
    return message_type, header_len, payload_len


class _JsonRule(ValueError):
    """One of this protocol's own JSON rules broken (its text is shown to the client)."""


def _reject_constant(name: str) -> Any:
    raise _JsonRule(f"{name} is not valid JSON")


def _depth(value: Any, limit: int) -> int:
    """Nesting depth of parsed JSON (iterative; raises ValueError past `limit`)."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, dict | list):
            if level > limit:
                raise _JsonRule(f"JSON nests deeper than {limit} levels")
            deepest = max(deepest, level)
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, level + 1) for child in children)
    return deepest


def _bounded_int(text: str) -> int:
    digits = len(text.lstrip("-"))
    if digits > MAX_JSON_INT_DIGITS:
        raise _JsonRule(
            f"an integer of {digits} digits is out of range (at most {MAX_JSON_INT_DIGITS} digits)"
        )
    return int(text)


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        shown = text if len(text) <= 24 else text[:24] + "..."
        raise _JsonRule(f"the number {shown} is out of range for a 64-bit float")
    return value


def parse_json_object(data: bytes | bytearray | memoryview, what: str) -> dict[str, Any]:
    """Strict JSON: UTF-8, an object at the top, no NaN/Infinity, numbers within 64-bit range
    (integers of at most 20 digits, floats finite: ``1e400`` and a 400-digit integer are
    refused here, so no later ``float()`` can overflow), bounded nesting."""
    try:
        text = bytes(data).decode("utf-8")
        value = json.loads(
            text,
            parse_constant=_reject_constant,
            parse_int=_bounded_int,
            parse_float=_finite_float,
        )
        _depth(value, MAX_JSON_DEPTH)
    except UnicodeDecodeError as exc:
        raise InputError(what, f"is not valid UTF-8 (byte {exc.start})") from None
    except _JsonRule as exc:
        raise InputError(what, f"is not valid JSON: {exc}") from None
    except json.JSONDecodeError as exc:  # the library's text is not shown, only the place
        raise InputError(
            what, f"is not valid JSON (line {exc.lineno}, column {exc.colno})"
        ) from None
    except RecursionError:
        depth = f"is not valid JSON: nests deeper than {MAX_JSON_DEPTH} levels"
        raise InputError(what, depth) from None
    except ValueError:
        raise InputError(what, "is not valid JSON") from None
    if not isinstance(value, dict):
        raise InputError(what, f"must be a JSON object, got {kind_of(value)}")
    return value


def parse_header(data: bytes | bytearray | memoryview) -> dict[str, Any]:
    """A message header; anything but a JSON object is a `ProtocolError`."""
    try:
        return parse_json_object(data, "header")
    except InputError as exc:
        raise ProtocolError(ErrorCode.PROTOCOL, exc.message, "header") from None


def read_message(
    recv_exact: Callable[[int], bytes | bytearray],
    *,
    max_header_bytes: int = 1 << 16,
    max_payload_bytes: int = 1 << 30,
) -> Message:
    """Read one message with ``recv_exact(n)`` (which returns exactly n bytes or raises)."""
    kind, header_len, payload_len = parse_prefix(
        recv_exact(PREFIX_SIZE),
        max_header_bytes=max_header_bytes,
        max_payload_bytes=max_payload_bytes,
    )
    header = parse_header(recv_exact(header_len)) if header_len else {}
    payload = recv_exact(payload_len) if payload_len else b""
    return Message(kind, header, memoryview(payload))


# --------------------------------------------------------------------------------------------
# FRAME arrays


def _wire_array(name: str, value: object, allow_f8: bool) -> np.ndarray:
    array = np.asarray(value)
    if name == "solid" and array.dtype.kind in "biu":
        return np.ascontiguousarray(array, dtype="|u1")  # 0 / 1 checked by the receiver
    if array.dtype.kind not in "fiu":
        raise InputError(name, f"must be a numeric array, got dtype {show(array.dtype.str)}")
    if name == "ids":
        if array.dtype.kind not in "iu":
            raise InputError(name, f"must be an integer array, got dtype {show(array.dtype.str)}")
        wire = array.dtype.newbyteorder("<") if array.dtype.itemsize in (4, 8) else "<i8"
        return np.ascontiguousarray(array, dtype=wire)
    wide = allow_f8 and array.dtype == np.float64
    return np.ascontiguousarray(array, dtype="<f8" if wide else "<f4")


def encode_frame(
    frame_id: int,
    positions: object,
    *,
    densities: object | None = None,
    radii: object | None = None,
    temperatures: object | None = None,
    velocities: object | None = None,
    ids: object | None = None,
    peak_temperatures: object | None = None,
    solid: object | None = None,
    scene: Mapping[str, Any] | None = None,
) -> bytes:
    """A FRAME message. Positions keep float64 when given as float64 (large coordinates); ids
    keep a 4- or 8-byte integer dtype (others become int64); solid flags go as one byte each;
    the rest are sent as float32."""
    arrays = {"positions": _wire_array("positions", positions, allow_f8=True)}
    named = (
        ("densities", densities),
        ("radii", radii),
        ("temperatures", temperatures),
        ("velocities", velocities),
        ("ids", ids),
        ("peak_temperatures", peak_temperatures),
        ("solid", solid),
    )
    for name, value in named:
        if value is not None:
            arrays[name] = _wire_array(name, value, allow_f8=False)
    header: dict[str, Any] = {
        "id": int(frame_id),
        "arrays": [
            {"name": name, "dtype": array.dtype.str, "shape": list(array.shape)}
            for name, array in arrays.items()
        ],
    }
    if scene is not None:
        header["scene"] = dict(scene)
    payload = b"".join(array.tobytes() for array in arrays.values())
    return encode_message(MessageType.FRAME, header, payload)


def _shape(field: str, value: Any, name: str) -> tuple[int, ...]:
    expected = (None, 3) if name in VECTOR_ARRAYS else (None,)
    text = "[N, 3]" if name in VECTOR_ARRAYS else "[N]"
    if (
        not isinstance(value, list)
        or len(value) != len(expected)
        or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value)
        or (len(value) == 2 and value[1] != 3)
    ):
        raise InputError(field, f"must be {text} with N >= 0 for {name}, got {show(value)}")
    return tuple(value)


@dataclass(frozen=True)
class ArraySlot:
    """Where one declared array lies in a FRAME's payload."""

    name: str
    dtype: np.dtype[Any]
    shape: tuple[int, ...]
    offset: int
    nbytes: int


def plan_frame_arrays(
    specs: Any, payload_length: int, *, max_particles: int
) -> tuple[list[ArraySlot], int]:
    """Check a FRAME header's ``arrays`` list against `payload_length` and `max_particles`
    before any of the payload is read; returns the arrays' places and the particle count.

    The sum of the arrays' byte sizes must equal `payload_length` exactly."""
    if not isinstance(specs, list) or not specs:
        raise InputError("arrays", "must be a non-empty array of {name, dtype, shape} objects")
    slots: list[ArraySlot] = []
    offset = 0
    count: int | None = None
    for index, spec in enumerate(specs):
        where = f"arrays[{index}]"
        if not isinstance(spec, dict):
            raise InputError(
                where, f"must be an object with name, dtype and shape, got {kind_of(spec)}"
            )
        unknown = set(spec) - {"name", "dtype", "shape"}
        if unknown:
            raise InputError(f"{where}.{sorted(unknown)[0]}", "unknown key")
        name = spec.get("name")
        if not isinstance(name, str) or name not in ARRAY_NAMES:
            raise InputError(f"{where}.name", f"must be one of {', '.join(ARRAY_NAMES)}")
        if any(slot.name == name for slot in slots):
            raise InputError(f"{where}.name", f"{name} appears twice")
        wire = spec.get("dtype")
        allowed = {"ids": ID_DTYPES, "solid": SOLID_DTYPES}.get(name, WIRE_DTYPES)
        dtype = allowed.get(wire) if isinstance(wire, str) else None
        if dtype is None:
            raise InputError(
                f"{where}.dtype", f"must be one of the strings {', '.join(allowed)} for {name}"
            )
        shape = _shape(f"{where}.shape", spec.get("shape"), name)
        n = shape[0]
        if n > max_particles:
            raise LimitError(f"{where}.shape", f"{n} particles exceed the limit of {max_particles}")
        if count is not None and n != count:
            raise InputError(f"{where}.shape", f"has {n} entries but the first array has {count}")
        count = n
        nbytes = math.prod(shape) * dtype.itemsize
        if offset + nbytes > payload_length:
            raise InputError(
                f"{where}.shape",
                f"needs {nbytes} bytes at offset {offset} but the payload has {payload_length}",
            )
        slots.append(ArraySlot(name, dtype, shape, offset, nbytes))
        offset += nbytes
    if offset != payload_length:
        raise InputError(
            "payload_length", f"is {payload_length} bytes but the arrays declare {offset} bytes"
        )
    if not any(slot.name == "positions" for slot in slots):
        raise InputError("arrays", "must include an array named positions")
    return slots, count or 0


def decode_frame_arrays(
    specs: Any, payload: bytes | bytearray | memoryview, *, max_particles: int
) -> dict[str, np.ndarray]:
    """The arrays of a FRAME from its header's ``arrays`` list and its payload.

    Every declared size is checked (`plan_frame_arrays`) before anything is allocated. The arrays
    returned are read-only views into the payload (native float dtypes).
    """
    view = memoryview(payload).cast("B")
    slots, _count = plan_frame_arrays(specs, view.nbytes, max_particles=max_particles)
    arrays: dict[str, np.ndarray] = {}
    for slot in slots:
        chunk = view[slot.offset : slot.offset + slot.nbytes]
        array = np.frombuffer(chunk, dtype=slot.dtype).reshape(slot.shape)
        arrays[slot.name] = array.astype(slot.dtype.newbyteorder("="), copy=False)
    return arrays
