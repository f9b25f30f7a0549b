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

import io
import json
import math
import struct
import zipfile
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from sphrender.client.errors import InputError

__all__ = [
    "ARRAY_NAMES",
    "MAGIC",
    "MAX_FRAME_ID",
    "PREFIX",
    "PREFIX_SIZE",
    "VERSION",
    "WIRE_DTYPES",
    "ErrorCode",
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
ARRAY_NAMES: tuple[str, ...] = ("positions", "densities", "radii", "temperatures")
#: Wire dtype names (numpy's array-protocol strings, always little-endian) -> numpy dtype.
WIRE_DTYPES: dict[str, np.dtype[Any]] = {"<f4": np.dtype("<f4"), "<f8": np.dtype("<f8")}
#: How deep a JSON header may nest (a scene is 3 levels deep; this leaves room and no more).
MAX_JSON_DEPTH = 16


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


class LimitError(InputError):
    """Input over a configured size limit (HTTP 413, stream code ``too_large``)."""


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
            ErrorCode.PROTOCOL, f"bad magic {bytes(magic)!r}, expected {MAGIC!r}", "magic"
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


def _reject_constant(name: str) -> Any:
    raise ValueError(f"{name} is not valid JSON")


def _depth(value: Any, limit: int) -> int:
    """Nesting depth of parsed JSON (iterative; raises ValueError past `limit`)."""
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 1)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, dict | list):
            if level > limit:
                raise ValueError(f"JSON nests deeper than {limit} levels")
            deepest = max(deepest, level)
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, level + 1) for child in children)
    return deepest


def parse_json_object(data: bytes | bytearray | memoryview, what: str) -> dict[str, Any]:
    """Strict JSON: UTF-8, an object at the top, no NaN/Infinity, bounded nesting."""
    try:
        text = bytes(data).decode("utf-8")
        value = json.loads(text, parse_constant=_reject_constant)
        _depth(value, MAX_JSON_DEPTH)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(what, f"is not valid JSON: {str(exc).splitlines()[0]}") from None
    if not isinstance(value, dict):
        raise InputError(what, f"must be a JSON object, got {type(value).__name__}")
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
    if array.dtype.kind not in "fiu":
        raise InputError(name, f"must be a numeric array, got dtype {array.dtype}")
    wide = allow_f8 and array.dtype == np.float64
    return np.ascontiguousarray(array, dtype="<f8" if wide else "<f4")


def encode_frame(
    frame_id: int,
    positions: object,
    *,
    densities: object | None = None,
    radii: object | None = None,
    temperatures: object | None = None,
    scene: Mapping[str, Any] | None = None,
) -> bytes:
    """A FRAME message. Positions keep float64 when given as float64 (large coordinates)."""
    arrays = {"positions": _wire_array("positions", positions, allow_f8=True)}
    for name, value in (("densities", densities), ("radii", radii), ("temperatures", temperatures)):
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
    expected = (None, 3) if name == "positions" else (None,)
    text = "[N, 3]" if name == "positions" else "[N]"
    if (
        not isinstance(value, list)
        or len(value) != len(expected)
        or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value)
        or (len(value) == 2 and value[1] != 3)
    ):
        raise InputError(field, f"must be {text} with N >= 0 for {name}, got {value!r}")
    return tuple(value)


def decode_frame_arrays(
    specs: Any, payload: bytes | bytearray | memoryview, *, max_particles: int
) -> dict[str, np.ndarray]:
    """The arrays of a FRAME from its header's ``arrays`` list and its payload.

    Every declared size is checked against `max_particles` and against the payload length before
    anything is allocated; the sum of the arrays' byte sizes must equal the payload length
    exactly. The arrays returned are read-only views into the payload (native float dtypes).
    """
    if not isinstance(specs, list) or not specs:
        raise InputError("arrays", "must be a non-empty list of {name, dtype, shape}")
    view = memoryview(payload).cast("B")
    arrays: dict[str, np.ndarray] = {}
    offset = 0
    count: int | None = None
    for index, spec in enumerate(specs):
        where = f"arrays[{index}]"
        if not isinstance(spec, dict):
            raise InputError(where, "must be an object with name, dtype and shape")
        unknown = set(spec) - {"name", "dtype", "shape"}
        if unknown:
            raise InputError(f"{where}.{sorted(unknown)[0]}", "unknown key")
        name = spec.get("name")
        if name not in ARRAY_NAMES:
            raise InputError(f"{where}.name", f"must be one of {', '.join(ARRAY_NAMES)}")
        if name in arrays:
            raise InputError(f"{where}.name", f"{name!r} appears twice")
        dtype = WIRE_DTYPES.get(spec.get("dtype"))  # type: ignore[arg-type]
        if dtype is None:
            raise InputError(f"{where}.dtype", f"must be one of {', '.join(WIRE_DTYPES)}")
        shape = _shape(f"{where}.shape", spec.get("shape"), name)
        n = shape[0]
        if n > max_particles:
            raise LimitError(f"{where}.shape", f"{n} particles exceed the limit of {max_particles}")
        if count is not None and n != count:
            raise InputError(f"{where}.shape", f"has {n} entries but the first array has {count}")
        count = n
        nbytes = math.prod(shape) * dtype.itemsize
        if offset + nbytes > view.nbytes:
            raise InputError(
                f"{where}.shape",
                f"needs {nbytes} bytes at offset {offset} but the payload has {view.nbytes}",
            )
        array = np.frombuffer(view[offset : offset + nbytes], dtype=dtype).reshape(shape)
        arrays[name] = array.astype(dtype.newbyteorder("="), copy=False)
        offset += nbytes
    if offset != view.nbytes:
        raise InputError(
            "payload_length", f"is {view.nbytes} bytes but the arrays declare {offset} bytes"
        )
    if "positions" not in arrays:
        raise InputError("arrays", "must include 'positions'")
    return arrays


# --------------------------------------------------------------------------------------------
# .npz bodies


@dataclass(frozen=True)
class NpzFrame:
    """The particle arrays of an .npz body and its scene JSON text (None when absent)."""

    arrays: dict[str, np.ndarray]
    scene_json: str | None


def encode_npz_frame(
    positions: object,
    *,
    densities: object | None = None,
    radii: object | None = None,
    temperatures: object | None = None,
    scene: Mapping[str, Any] | str | None = None,
    compress: bool = False,
) -> bytes:
    """An .npz body for ``POST /v1/render`` (what ``np.savez`` writes; the scene as 0-d str)."""
    entries: dict[str, np.ndarray] = {"positions": np.asarray(positions)}
    for name, value in (("densities", densities), ("radii", radii), ("temperatures", temperatures)):
        if value is not None:
            entries[name] = np.asarray(value)
    if scene is not None:
        text = scene if isinstance(scene, str) else json.dumps(scene, allow_nan=False)
        entries["scene"] = np.array(text)
    buffer = io.BytesIO()
    save: Callable[..., None] = np.savez_compressed if compress else np.savez
    save(buffer, **entries)
    return buffer.getvalue()


_ZIP_ERRORS: tuple[type[BaseException], ...] = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    EOFError,
    OSError,
    ValueError,
    struct.error,
    NotImplementedError,  # unsupported compression method
    RuntimeError,  # encrypted entry
    KeyError,
)


def _read_exact(handle: io.BufferedIOBase | Any, n: int, field: str) -> bytes:
    data = handle.read(n)
    if len(data) != n:
        raise InputError(field, f"entry is truncated: {len(data)} of {n} bytes")
    return bytes(data)


def _read_npy_entry(
    archive: zipfile.ZipFile, member: str, field: str, budget: int
) -> tuple[np.ndarray, int]:
    """One .npy member, its header parsed by numpy (literal_eval, never pickle); returns the
    array and the bytes it used. Sizes are checked before the data is read."""
    info = archive.getinfo(member)
    if info.file_size > budget:
        raise LimitError(
            field, f"entry of {info.file_size} bytes exceeds the remaining limit of {budget}"
        )
    with archive.open(info) as handle:
        try:
            version = np.lib.format.read_magic(handle)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(handle)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(handle)
            else:
                raise ValueError(f"unsupported .npy version {version}")
        except (ValueError, SyntaxError, TypeError, EOFError) as exc:
            raise InputError(field, f"not a valid .npy entry: {exc}") from None
        if dtype.hasobject or dtype.fields is not None or dtype.kind not in "fiuUS":
            raise InputError(field, f"dtype {dtype} is not allowed (numbers or text only)")
        header_size = handle.tell()
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes + header_size != info.file_size:
            raise InputError(
                field,
                f"declares shape {shape} ({nbytes} bytes) but the entry holds "
                f"{info.file_size - header_size} bytes",
            )
        data = _read_exact(handle, nbytes, field)
    order: Literal["C", "F"] = "F" if fortran else "C"
    array = np.frombuffer(data, dtype=dtype).reshape(tuple(shape), order=order)
    return array, info.file_size


def decode_npz_frame(
    data: bytes | bytearray | memoryview, *, max_particles: int, max_uncompressed_bytes: int
) -> NpzFrame:
    """Parse an .npz body: arrays named as in `ARRAY_NAMES` plus an optional ``scene``.

    Other entries are ignored unread. Raises `InputError` (field ``body``, or the entry's name)
    for anything malformed and `LimitError` when the arrays would exceed the limits.
    """
    raw = bytes(data)
    if not raw.startswith(b"PK\x03\x04"):
        raise InputError("body", "must be an .npz (zip) archive (application/x-npz)")
    budget = max_uncompressed_bytes
    arrays: dict[str, np.ndarray] = {}
    scene_json: str | None = None
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            members = {name.removesuffix(".npy"): name for name in archive.namelist()}
            if "positions" not in members:
                listing = ", ".join(sorted(members)) or "none"
                raise InputError("positions", f"missing entry 'positions'; the body has {listing}")
            for name in (*ARRAY_NAMES, "scene"):
                if name not in members:
                    continue
                array, used = _read_npy_entry(archive, members[name], name, budget)
                budget -= used
                if name == "scene":
                    scene_json = _scene_text(array)
                    continue
                if array.dtype.kind not in "fiu":
                    raise InputError(name, f"must be a numeric array, got dtype {array.dtype}")
                if array.ndim >= 1 and array.shape[0] > max_particles:
                    raise LimitError(
                        name, f"{array.shape[0]} particles exceed the limit of {max_particles}"
                    )
                arrays[name] = array
    except InputError:
        raise
    except _ZIP_ERRORS as exc:
        detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError("body", f"cannot read the .npz archive: {detail}") from None
    return NpzFrame(arrays, scene_json)


def _scene_text(value: npt.NDArray[Any]) -> str:
    if value.dtype.kind not in "US" or value.size != 1:
        raise InputError("scene", f"must be a single string, got {value.dtype} {value.shape}")
    item = value.reshape(()).item()
    if isinstance(item, bytes):
        try:
            return item.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError("scene", "bytes are not valid UTF-8") from None
    return str(item)
