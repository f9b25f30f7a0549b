"""Python client of `sphrender serve`: numpy + standard library only (no GL, no OpenCL).

    client = Client("http://127.0.0.1:8080", token=None)
    png = client.render(positions, scene={"image": {"width": 640, "height": 360}})

    with client.stream(scene) as session:           # pipelined over the streaming socket
        for result in session.render_all(frames):   # yields answers in order, one per frame
            ...

Retries happen only where repeating is safe: rendering a frame is a pure function of its input,
so a render request is retried after connection failures and ``503 busy`` answers (honouring
``Retry-After``), with exponential backoff. Errors the server reports about the input are raised
at once as `ServerError`, carrying the server's message, field and code.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import socket
import time
import urllib.parse
from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from sphrender.client.compact_stream import CompactSender, compact_body, offered
from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.core.frame_message import FRAME_CONTENT_TYPE
from sphrender.core.protocol import (
    IMAGE_FORMATS,
    ErrorCode,
    ImageFormat,
    MessageType,
    ProtocolError,
    encode_frame,
    encode_message,
    encode_npz_frame,
    read_message,
)

#: Errors of the transport itself: the server is down, restarting or went away mid-request.
CONNECTION_ERRORS: tuple[type[BaseException], ...] = (
    ConnectionError,
    http.client.RemoteDisconnected,
    http.client.BadStatusLine,
    http.client.IncompleteRead,
    TimeoutError,
    socket.timeout,
)


class ServerError(Exception):
    """The server refused a request: `code` (see PROTOCOL.md §4.4), `field`, HTTP `status`."""

    def __init__(self, message: str, code: str, field: str | None, status: int | None) -> None:
        where = f"{field}: " if field else ""
        super().__init__(f"{where}{message} ({code})")
        self.message = message
        self.code = code
        self.field = field
        self.status = status

    @property
    def retryable(self) -> bool:
        return self.code in (ErrorCode.BUSY, ErrorCode.SHUTTING_DOWN)


class ServerUnavailable(Exception):
    """Every attempt to reach the server failed (the last cause is chained)."""


@dataclass
class StreamResult:
    """One answer of a streaming session: ``kind`` is "image", "error" or "dropped"."""

    id: int
    kind: Literal["image", "error", "dropped"]
    header: dict[str, Any]
    data: bytes = b""

    @property
    def notes(self) -> list[dict[str, str]]:
        """What the server changed about the frame's input to render it (IMAGE ``notes``,
        PROTOCOL.md 4.3): ``{"field", "message"}`` objects; empty for most frames."""
        return list(self.header.get("notes", []))

    def raw_arrays(self) -> dict[str, np.ndarray]:
        """The arrays of a raw IMAGE (``format`` "raw"), by name."""
        if self.kind != "image" or self.header.get("format") != "raw":
            raise InputError("format", "only a raw IMAGE carries arrays")
        return decode_raw(self.header["arrays"], self.data)

    @property
    def error(self) -> ServerError | None:
        if self.kind != "error":
            return None
        return ServerError(
            str(self.header.get("error")),
            str(self.header.get("code")),
            self.header.get("field"),
            None,
        )


def _frame_arrays(frame: ParticleFrame) -> dict[str, Any]:
    """The arrays a frame read from a file sends: those the renderer uses. Velocities and ids
    (20 bytes a particle) travel only when a caller passes them explicitly."""
    return {
        "densities": frame.densities,
        "radii": frame.radii,
        "temperatures": frame.temperatures,
        "peak_temperatures": frame.peak_temperatures,
        "solid": frame.solid,
    }


@dataclass
class Client:
    """A client of one server. Thread-safe: every request uses its own connection."""

    url: str
    token: str | None = None
    timeout: float = 120.0
    retries: int = 4
    backoff_s: float = 0.5
    #: HTTP frames in the compact encoding (PROTOCOL.md §4.7) instead of .npz; the stream uses
    #: it whenever the server offers it (`stream(compact=...)`).
    compact: bool = False
    _host: str = field(init=False)
    _port: int = field(init=False)

    def __post_init__(self) -> None:
        parsed = urllib.parse.urlsplit(self.url if "//" in self.url else f"http://{self.url}")
        if parsed.scheme != "http" or not parsed.hostname:
            raise InputError("server", f"expected http://HOST:PORT, got {self.url!r}")
        self._host = parsed.hostname
        self._port = parsed.port or 80

    # -- HTTP ------------------------------------------------------------------------------

    def _headers(self, content_type: str | None = None) -> dict[str, str]:
        headers = {}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        if content_type:
            headers["Content-Type"] = content_type
        return headers

    def _request_once(
        self, method: str, path: str, body: bytes | None, content_type: str | None
    ) -> tuple[int, dict[str, str], bytes]:
        connection = http.client.HTTPConnection(self._host, self._port, timeout=self.timeout)
        try:
            connection.request(method, path, body=body, headers=self._headers(content_type))
            response = connection.getresponse()
            return (
                response.status,
                {k.lower(): v for k, v in response.getheaders()},
                response.read(),
            )
        finally:
            connection.close()

    def request(
        self,
        method: str,
        path: str,
        body: bytes | None = None,
        content_type: str | None = None,
        *,
        retry: bool = True,
    ) -> tuple[dict[str, str], bytes]:
        """One request, retried (when `retry`) on connection failures and 503; raises
        `ServerError` for every other non-2xx answer."""
        attempts = 1 + (self.retries if retry else 0)
        last: BaseException | None = None
        for attempt in range(attempts):
            delay = self.backoff_s * 2**attempt
            try:
                status, headers, data = self._request_once(method, path, body, content_type)
            except CONNECTION_ERRORS as exc:
                last = exc
            else:
                if 200 <= status < 300:
                    return headers, data
                error = _error_from_http(status, data)
                if not (retry and error.retryable):
                    raise error
                last = error
                delay = max(delay, float(headers.get("retry-after", "0") or 0))
            if attempt + 1 < attempts:
                time.sleep(delay)
        if isinstance(last, ServerError):
            raise last
        raise ServerUnavailable(
            f"{self.url} unreachable after {attempts} attempts: {last}"
        ) from last

    def info(self) -> dict[str, Any]:
        _headers, data = self.request("GET", "/v1/info")
        info: dict[str, Any] = json.loads(data)
        return info

    def render(
        self,
        positions: object,
        scene: Mapping[str, Any] | None = None,
        *,
        densities: object | None = None,
        radii: object | None = None,
        temperatures: object | None = None,
        velocities: object | None = None,
        ids: object | None = None,
        format: ImageFormat | None = None,
        peak_temperatures: object | None = None,
        solid: object | None = None,
    ) -> bytes:
        """Render one frame over HTTP; returns the image bytes (PNG, EXR, JPEG or raw arrays:
        `render_raw` decodes those). `velocities` (N, 3) and `ids` (N,) are validated and carried
        with the frame; `peak_temperatures` (N,) kelvin feed the heat tint; `solid` (N,) flags a
        workpiece's particles (0 / 1)."""
        arrays = {"densities": densities, "radii": radii, "temperatures": temperatures}
        arrays |= {"velocities": velocities, "ids": ids, "solid": solid}
        arrays["peak_temperatures"] = peak_temperatures
        return self._render(positions, scene, arrays, format)[1]

    def _render(
        self,
        positions: object,
        scene: Mapping[str, Any] | None,
        arrays: Mapping[str, Any],
        format: ImageFormat | None,
    ) -> tuple[dict[str, str], bytes]:
        if format is not None and format not in IMAGE_FORMATS:
            raise InputError("format", f"must be one of {', '.join(IMAGE_FORMATS)}")
        path = "/v1/render" + (f"?format={format}" if format else "")
        if self.compact:
            body = compact_body(positions, scene, arrays)
            return self.request("POST", path, body, FRAME_CONTENT_TYPE)
        body = encode_npz_frame(positions, scene=scene, **arrays)
        return self.request("POST", path, body, "application/x-npz")

    def render_raw(
        self,
        positions: object,
        scene: Mapping[str, Any] | None = None,
        *,
        densities: object | None = None,
        radii: object | None = None,
        temperatures: object | None = None,
        velocities: object | None = None,
        ids: object | None = None,
        solid: object | None = None,
    ) -> dict[str, np.ndarray]:
        """Render as raw arrays (the scene's ``output.raw_type``) and decode them: ``rgba``
        (H, W, 4), plus ``Z`` and ``N`` for the float types (PROTOCOL.md §4.3)."""
        arrays = dict(
            densities=densities,
            radii=radii,
            temperatures=temperatures,
            velocities=velocities,
            ids=ids,
            solid=solid,
        )
        headers, data = self._render(positions, scene, arrays, "raw")
        return decode_raw(json.loads(headers["x-sphrender-arrays"]), data)

    def render_arrays(
        self, positions: object, scene: Mapping[str, Any] | None = None, **arrays: Any
    ) -> dict[str, np.ndarray]:
        """Render as EXR and decode it: {"R", "G", "B", "A", "Z", "N.X", ...: (H, W) arrays}."""
        return decode_exr(self.render(positions, scene, format="exr", **arrays))

    def render_frame(
        self, frame: ParticleFrame, scene: Mapping[str, Any] | None = None, **kwargs: Any
    ) -> bytes:
        return self.render(frame.positions, scene, **_frame_arrays(frame), **kwargs)

    def render_frame_noted(
        self,
        frame: ParticleFrame,
        scene: Mapping[str, Any] | None = None,
        *,
        format: ImageFormat | None = None,
    ) -> tuple[bytes, list[dict[str, str]]]:
        """`render_frame`, and the answer's notes: what the server changed about the frame's
        input to render it, ``{"field", "message"}`` (``X-Sphrender-Notes``, PROTOCOL.md 4.3;
        usually none)."""
        headers, data = self._render(frame.positions, scene, _frame_arrays(frame), format)
        notes: list[dict[str, str]] = json.loads(headers.get("x-sphrender-notes", "[]"))
        return data, notes

    # -- streaming -------------------------------------------------------------------------

    def stream(
        self,
        scene: Mapping[str, Any] | None = None,
        *,
        mode: Literal["queue", "latest"] = "queue",
        max_in_flight: int | None = None,
        stream_port: int | None = None,
        compact: bool | Literal["ordered"] = True,
    ) -> StreamSession:
        """Open a streaming session (the port comes from /v1/info unless given). `compact`:
        send frames in the compact encoding when the server offers it (client/compact_stream.py:
        positions within 1/100 of the particle radius, maybe reordered: "ordered" keeps it)."""
        if stream_port is None:
            stream_port = self.info().get("stream_port")
            if not stream_port:
                raise ServerUnavailable(f"{self.url} has no streaming socket")
        return StreamSession(
            self._host, stream_port, scene, self.token, mode, max_in_flight, self.timeout, compact
        )


def _error_from_http(status: int, data: bytes) -> ServerError:
    try:
        body = json.loads(data)
        return ServerError(
            str(body.get("error", "")), str(body.get("code", "")), body.get("field"), status
        )
    except (ValueError, AttributeError):
        return ServerError(data[:200].decode("utf-8", "replace"), "http", None, status)


class StreamSession:
    """One streaming connection (PROTOCOL.md): HELLO, pipelined FRAMEs, answers in order.

    Use as a context manager; `render_all` keeps up to ``max_in_flight`` frames outstanding.
    Not thread-safe: one thread sends and receives. A producer that hands frames over from its own
    callbacks or threads uses `sphrender.client.live.LiveSession`, built on this."""

    def __init__(
        self,
        host: str,
        port: int,
        scene: Mapping[str, Any] | None,
        token: str | None,
        mode: str,
        max_in_flight: int | None,
        timeout: float,
        compact: bool | Literal["ordered"] = True,
    ) -> None:
        self._socket = socket.create_connection((host, port), timeout=timeout)
        self._reader = self._socket.makefile("rb")
        hello: dict[str, Any] = {"mode": mode, "client": "sphrender.client"}
        if scene is not None:
            hello["scene"] = dict(scene)
        if token:
            hello["token"] = token
        if max_in_flight is not None:
            hello["max_in_flight"] = max_in_flight
        self._socket.sendall(encode_message(MessageType.HELLO, hello))
        welcome = self._read()
        if welcome.type == MessageType.ERROR:
            self.close()
            raise _stream_error(welcome.header)
        if welcome.type != MessageType.WELCOME:
            self.close()
            raise ProtocolError(ErrorCode.PROTOCOL, f"expected WELCOME, got {welcome.type!r}")
        self.welcome = welcome.header
        self.max_in_flight = int(welcome.header["max_in_flight"])
        self._next_id = 0
        self._outstanding: deque[int] = deque()
        self.closed_reason: str | None = None
        wanted = compact and offered(self.welcome)
        self.compact = CompactSender(self.welcome, reorder=compact != "ordered") if wanted else None
        self._held: dict[int, StreamResult] = {}  # answers that overtook a frame sent again
        self._resent: set[int] = set()

    @property
    def in_flight(self) -> int:
        """Frames sent and not yet answered."""
        return len(self._outstanding)

    def set_timeout(self, seconds: float | None) -> None:
        """How long a read or write may wait (None: for ever, until `abort`)."""
        self._socket.settimeout(seconds)

    def bye(self) -> None:
        """Send BYE: no more frames; the server answers those it owes, then GOODBYE."""
        self._socket.sendall(encode_message(MessageType.BYE, {}))

    def abort(self) -> None:
        """Close the connection now, without BYE (a blocked reader wakes): reason "aborted"."""
        self.closed_reason = self.closed_reason or "aborted"
        with contextlib.suppress(OSError):
            self._socket.shutdown(socket.SHUT_RDWR)
        self._socket.close()

    def _read_exact(self, n: int) -> bytes:
        data = self._reader.read(n)
        if data is None or len(data) != n:
            raise ConnectionError("the server closed the stream")
        return bytes(data)

    def _read(self) -> Any:
        return read_message(self._read_exact, max_payload_bytes=1 << 31)

    def send(self, positions: object, *, frame_id: int | None = None, **arrays: Any) -> int:
        """Send one FRAME (does not wait); returns its id. `arrays`: densities, radii,
        temperatures, velocities, ids, peak_temperatures, solid (PROTOCOL.md §4.2) and ``scene``,
        a per-frame override."""
        if frame_id is None:
            frame_id = self._next_id
        self._next_id = frame_id + 1
        if self.compact is not None:
            self._socket.sendall(self.compact.message(frame_id, positions, arrays))
        else:
            self._socket.sendall(encode_frame(frame_id, positions, **arrays))
        self._outstanding.append(frame_id)
        return frame_id

    def receive(self) -> StreamResult:
        """The next answer (in the order frames were sent). A compact frame refused for its
        ``base`` is sent again in full, and its answer still comes in order."""
        while True:
            head = self._outstanding[0] if self._outstanding else None
            if head in self._held and head not in self._resent:
                return self._held.pop(self._outstanding.popleft())
            result = self._receive_one()
            if self.compact is not None and result.kind == "error":
                again = self.compact.resend(result.id, result.header.get("field"))
                if again is not None:
                    self._socket.sendall(again)
                    self._resent.add(result.id)
                    continue
            if self.compact is not None:
                self.compact.answered(result.id)
            if head in self._resent and result.id != head:
                self._held[result.id] = result
                continue
            self._resent.discard(result.id)
            if head == result.id:
                self._outstanding.popleft()
            return result

    def _receive_one(self) -> StreamResult:
        message = self._read()
        header = dict(message.header)
        if message.type == MessageType.IMAGE:
            result = StreamResult(int(header["id"]), "image", header, bytes(message.payload))
        elif message.type == MessageType.DROPPED:
            result = StreamResult(int(header["id"]), "dropped", header)
        elif message.type == MessageType.ERROR and header.get("id") is not None:
            result = StreamResult(int(header["id"]), "error", header)
        elif message.type == MessageType.ERROR:
            raise _stream_error(header)
        elif message.type == MessageType.GOODBYE:
            self.closed_reason = str(header.get("reason"))
            raise ConnectionError(f"the server ended the session: {self.closed_reason}")
        else:
            raise ProtocolError(ErrorCode.PROTOCOL, f"unexpected message {message.type!r}")
        return result

    def render_all(self, frames: Iterable[ParticleFrame]) -> Iterator[StreamResult]:
        """Pipeline `frames`; yields one result per frame, in order."""
        for frame in frames:
            while len(self._outstanding) >= self.max_in_flight:
                yield self.receive()
            self.send(frame.positions, **_frame_arrays(frame))
        while self._outstanding:
            yield self.receive()

    def close(self) -> None:
        """Say BYE (after draining answers still owed) and close the socket."""
        try:
            if self.closed_reason is None:
                while self._outstanding:
                    self.receive()
                self.bye()
                while True:
                    message = self._read()
                    if message.type == MessageType.GOODBYE:
                        self.closed_reason = str(message.header.get("reason"))
                        break
        except (OSError, ProtocolError, ServerError):
            pass
        finally:
            self._reader.close()
            self._socket.close()

    def __enter__(self) -> StreamSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _stream_error(header: Mapping[str, Any]) -> ServerError:
    code = str(header.get("code"))
    return ServerError(
        str(header.get("error")), code, header.get("field"), ErrorCode.HTTP_STATUS.get(code)
    )


#: dtype strings of raw IMAGE arrays (PROTOCOL.md §4.3).
RAW_DTYPES: dict[str, np.dtype[Any]] = {
    "u1": np.dtype("u1"),
    "<f2": np.dtype("<f2"),
    "<f4": np.dtype("<f4"),
}


def decode_raw(arrays: Any, data: bytes) -> dict[str, np.ndarray]:
    """A raw payload split into its arrays by the descriptors (name, dtype, shape), in order;
    the sizes must add up to the payload exactly."""
    out: dict[str, np.ndarray] = {}
    offset = 0
    for spec in arrays:
        dtype = RAW_DTYPES[spec["dtype"]]
        shape = tuple(int(n) for n in spec["shape"])
        size = int(np.prod(shape)) * dtype.itemsize
        if offset + size > len(data):
            raise ProtocolError(ErrorCode.PROTOCOL, "raw payload shorter than its arrays")
        out[spec["name"]] = np.frombuffer(data, dtype, int(np.prod(shape)), offset).reshape(shape)
        offset += size
    if offset != len(data):
        raise ProtocolError(ErrorCode.PROTOCOL, "raw payload longer than its arrays")
    return out


def decode_exr(data: bytes) -> dict[str, np.ndarray]:
    """Decode the EXR files the server writes (single-part scanline; NONE, ZIPS or ZIP
    compression; HALF and FLOAT channels) into {channel name: (H, W) array}, with numpy and
    zlib only. Rows top first, as the server writes them."""
    if data[:4] != bytes.fromhex("76 2f 31 01"):
        raise ValueError("not an OpenEXR file")
    version = int.from_bytes(data[4:8], "little")
    if version & 0x1200:
        raise ValueError("tiled and multi-part EXR are not supported by this decoder")
    pos = 8
    attributes: dict[str, bytes] = {}
    while data[pos] != 0:
        end = data.index(b"\0", pos)
        name = data[pos:end].decode()
        end_type = data.index(b"\0", end + 1)
        size = int.from_bytes(data[end_type + 1 : end_type + 5], "little")
        attributes[name] = data[end_type + 5 : end_type + 5 + size]
        pos = end_type + 5 + size
    pos += 1
    channels: list[tuple[str, np.dtype[Any]]] = []
    raw = attributes["channels"]
    cursor = 0
    while raw[cursor] != 0:
        end = raw.index(b"\0", cursor)
        pixel_type = int.from_bytes(raw[end + 1 : end + 5], "little")
        dtypes: dict[int, np.dtype[Any]] = {
            0: np.dtype("<u4"),
            1: np.dtype("<f2"),
            2: np.dtype("<f4"),
        }
        dtype = dtypes[pixel_type]
        channels.append((raw[cursor:end].decode(), dtype))
        cursor = end + 1 + 16
    xmin, ymin, xmax, ymax = np.frombuffer(attributes["dataWindow"], "<i4")
    width, height = int(xmax - xmin + 1), int(ymax - ymin + 1)
    compression = attributes["compression"][0]
    lines = {0: 1, 2: 1, 3: 16}.get(compression)
    if lines is None:
        raise ValueError(f"EXR compression {compression} is not supported by this decoder")
    chunks = -(-height // lines)
    offsets = np.frombuffer(data, "<u8", chunks, pos)
    out = {name: np.empty((height, width), dtype.newbyteorder("=")) for name, dtype in channels}
    for offset in offsets:
        y = int.from_bytes(data[offset : offset + 4], "little", signed=True) - int(ymin)
        size = int.from_bytes(data[offset + 4 : offset + 8], "little")
        block = data[offset + 8 : offset + 8 + size]
        rows = min(lines, height - y)
        expected = rows * width * sum(dtype.itemsize for _, dtype in channels)
        if compression != 0 and size < expected:
            block = _unzip_exr_block(block)
        cursor = 0
        for row in range(rows):
            for name, dtype in channels:
                nbytes = width * dtype.itemsize
                out[name][y + row] = np.frombuffer(block, dtype, width, cursor)
                cursor += nbytes
    return out


def _unzip_exr_block(block: bytes) -> bytes:
    """OpenEXR's ZIP: zlib, then undo the byte predictor and the even/odd interleave."""
    import zlib

    raw = np.frombuffer(zlib.decompress(block), np.uint8)
    deltas = raw.copy()
    deltas[1:] -= np.uint8(128)  # each byte holds (value - previous + 128) mod 256
    decoded = np.cumsum(deltas, dtype=np.uint8)  # wraps mod 256, as the encoder did
    half = (decoded.size + 1) // 2
    out = np.empty_like(decoded)
    out[0::2] = decoded[:half]
    out[1::2] = decoded[half:]
    return out.tobytes()
