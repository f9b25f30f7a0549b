"""A seeded mutator of the service's inputs, built from the protocol's own grammar, and the
clients that throw them at a real server (used by tests/test_service_fuzz.py for a bounded
subset and by benchmarks/fuzz_campaign.py for the long campaign).

Three kinds of input:

* **frame-level** (`frame_input`): a FRAME (raw or compact) whose prefix is intact but whose
  header or payload is wrong in one of the ways PROTOCOL.md 4.2 and 4.7 forbid (array specs,
  dtypes, shapes, counts, NaN, the payload length, unknown keys, the scene override, the compact
  encoding's keys and zstd frames). The server must answer each with
  exactly one non-fatal ERROR (or an IMAGE when the mutation happened to be valid), in order,
  on a connection that goes on;
* **connection-level** (`connection_input`): bytes that break the framing or the handshake
  (prefix fields, header JSON, ids, HELLO, garbage, truncation + half-close). The server must
  answer with a fatal ERROR or GOODBYE and close, promptly;
* **HTTP** (`http_input`): mutated .npz bodies, npy headers, scene JSON, request lines and
  headers. Every answer must be a JSON error below 500 (or 503 busy), or an image.

Everything is derived from a `random.Random(seed)`, so a failure is reproduced by its seed.
"""

from __future__ import annotations

import contextlib
import io
import json
import random
import socket
import struct
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from error_texts import text_faults

from sphrender.core.protocol import (
    PREFIX_SIZE,
    MessageType,
    encode_message,
    encode_npz_frame,
    parse_header,
    parse_prefix,
)

HOST = "127.0.0.1"
SCENE: dict[str, Any] = {
    "image": {"width": 32, "height": 24},
    "camera": {"eye": [0.6, 0.5, 0.9], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
    "particles": {"radius": 0.02},
}
_WEIRD: list[Any] = [
    None,
    True,
    False,
    0,
    -1,
    1.5,
    2**53,
    10**19,
    -(10**19),
    "",
    "x",
    "<f8",
    "<f4",
    ">f8",
    "<f2",
    "|u1",
    [],
    [1],
    [[]],
    {},
    {"a": 1},
    "\u00b2",
    "\ud7ff",
    1e308,
]


def prefix(kind: int, hlen: int, plen: int, **over: int) -> bytes:
    """A 16-byte prefix; `over` replaces fields (version, type, flags, header_len, ...)."""
    return struct.pack(
        "<4sBBHII",
        b"SPHR",
        over.get("version", 1),
        over.get("type", kind),
        over.get("flags", 0),
        over.get("header_len", hlen),
        over.get("payload_len", plen),
    )


def message(kind: int, header: bytes, payload: bytes = b"", **over: int) -> bytes:
    return prefix(kind, len(header), len(payload), **over) + header + payload


def _dump(value: Any) -> bytes:
    return json.dumps(value, separators=(",", ":")).encode()


def _weird(rng: random.Random, big: bool = False) -> Any:
    """A value of the wrong kind; `big`: also integers beyond 64 bits, which make the whole
    header invalid JSON for this protocol (a fatal error, so connection-level only)."""
    if big and rng.random() < 0.1:  # a big integer written out, as the campaign found
        return int("1" + "0" * rng.choice((19, 20, 25, 400)))
    return rng.choice(_WEIRD)


def _coincident(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.tile(rng.normal(size=3) * 0.1, (n, 1))


def _near_coincident(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.normal(size=3) * 0.1 + rng.normal(size=(n, 3)) * 1e-7


def _coplanar(rng: np.random.Generator, n: int) -> np.ndarray:
    """A random plane through the origin, the particles scattered on it."""
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    points = rng.normal(size=(n, 3)) * 0.1
    return np.asarray(points - np.outer(points @ normal, normal))


def _collinear(rng: np.random.Generator, n: int) -> np.ndarray:
    direction = rng.normal(size=3)
    return np.outer(rng.normal(size=n) * 0.1, direction / np.linalg.norm(direction))


def _one_cell(rng: np.random.Generator, n: int) -> np.ndarray:
    """Every particle within a cube of a tenth of the default support (4 r, r = 0.02)."""
    return np.asarray(rng.random((n, 3)) * 0.008)


#: Degenerate geometry, the shapes that once made a stage quadratic (coincident particles,
#: ones within float rounding of each other, a plane, a line, one grid cell): name -> (rng, n)
#: -> (n, 3) positions.
DEGENERATE_SHAPES: dict[str, Callable[[np.random.Generator, int], np.ndarray]] = {
    "coincident": _coincident,
    "near_coincident": _near_coincident,
    "coplanar": _coplanar,
    "collinear": _collinear,
    "one_cell": _one_cell,
}


def random_positions(rng: random.Random, n: int) -> np.ndarray:
    """A fuzz frame's positions: a normal cloud, or one of `DEGENERATE_SHAPES` (one in five)."""
    numbers = np.random.default_rng(rng.randrange(1 << 30))
    if rng.random() < 0.2:
        return DEGENERATE_SHAPES[rng.choice(sorted(DEGENERATE_SHAPES))](numbers, n)
    return np.asarray(numbers.normal(size=(n, 3)) * 0.1)


def _valid_arrays(rng: random.Random, n: int) -> tuple[list[dict[str, Any]], bytes]:
    specs: list[dict[str, Any]] = [{"name": "positions", "dtype": "<f8", "shape": [n, 3]}]
    positions = random_positions(rng, n)
    payload = positions.astype("<f8").tobytes()
    for name in rng.sample(("radii", "densities", "temperatures"), rng.randrange(3)):
        specs.append({"name": name, "dtype": rng.choice(("<f4", "<f8")), "shape": [n]})
        dtype = specs[-1]["dtype"]
        payload += np.full(n, 0.02 if name == "radii" else 1000.0, dtype=dtype).tobytes()
    return specs, payload


def _mutate_json(rng: random.Random, value: Any, depth: int = 0, big: bool = False) -> Any:
    """One random change somewhere in a JSON value."""
    out: Any
    if isinstance(value, dict) and value and rng.random() < 0.7:
        key = rng.choice(list(value))
        out = dict(value)
        roll = rng.random()
        if roll < 0.15:
            del out[key]
        elif roll < 0.3:
            out[rng.choice(("zz", "name", "dtype", "shape", "extra", key + "_"))] = _weird(rng, big)
        else:
            out[key] = _mutate_json(rng, value[key], depth + 1, big)
        return out
    if isinstance(value, list) and value and rng.random() < 0.7:
        out = list(value)
        index = rng.randrange(len(out))
        roll = rng.random()
        if roll < 0.2:
            del out[index]
        elif roll < 0.35:
            out.append(_weird(rng, big))
        else:
            out[index] = _mutate_json(rng, out[index], depth + 1, big)
        return out
    if rng.random() < 0.1 and depth < 6:
        return {"nest": _mutate_json(rng, value, depth + 1, big)}
    return _weird(rng, big)


def frame_input(rng: random.Random, frame_id: int) -> bytes:
    """A frame-level input (module docstring): valid prefix and id, something else wrong; a
    quarter of them compact frames (tests/fuzz_compact.py)."""
    if rng.random() < 0.25:
        from fuzz_compact import compact_frame_input

        return compact_frame_input(rng, frame_id, _weird)
    n = rng.choice((0, 1, 2, 3, 5, 8))
    specs, payload = _valid_arrays(rng, n)
    header: dict[str, Any] = {"id": frame_id, "arrays": specs}
    roll = rng.random()
    if roll < 0.45:
        header["arrays"] = _mutate_json(rng, specs)
    elif roll < 0.55:
        header[rng.choice(("ids", "scene", "frame", "Arrays"))] = _weird(rng)
    elif roll < 0.7:
        header["scene"] = _mutate_json(rng, {"camera": dict(SCENE["camera"]), "image": {}})
    elif roll < 0.8 and n:
        spoiled = bytearray(payload)
        for _ in range(rng.randrange(1, 4)):
            at = rng.randrange(len(spoiled) - 7)
            spoiled[at : at + 8] = struct.pack("<d", rng.choice((np.nan, np.inf, -np.inf, 0.0)))
        payload = bytes(spoiled)
    elif roll < 0.9:
        cut = rng.randrange(len(payload) + 1) if payload else 0
        payload = payload[:cut] + bytes(rng.randrange(0, 17))
    else:
        header["arrays"][0]["shape"] = [rng.choice((10**6, 10**9, 2**40)), 3]
    return message(MessageType.FRAME, _dump(header), payload)


def _bad_header(rng: random.Random) -> bytes:
    return rng.choice(
        (
            b"",
            b"[]",
            b"nul",
            b'{"a":NaN}',
            b'{"a":Infinity}',
            b"\xff\xfe{}",
            b"{" * 40 + b"}" * 40,
            b'{"id":' + b"9" * 500 + b"}",
            b'{"id":1e400}',
            bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))),
            _dump([[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]),
        )
    )


def connection_input(rng: random.Random) -> tuple[bytes, bool]:
    """(bytes, needs a valid HELLO first). The server must answer and close, promptly."""
    roll = rng.random()
    hello = message(MessageType.HELLO, _dump({"scene": SCENE}))
    if roll < 0.2:  # prefix fields
        over = rng.choice(
            (
                {"version": rng.randrange(256)},
                {"type": rng.randrange(256)},
                {"flags": rng.randrange(1, 1 << 16)},
                {"header_len": rng.choice((1 << 20, 1 << 31, 2**32 - 1))},
                {"payload_len": rng.choice((1 << 30, 2**32 - 1))},
            )
        )
        data = message(MessageType.FRAME, b"{}", b"", **over)
        return (b"XXXX" + data[4:] if rng.random() < 0.2 else data), rng.random() < 0.5
    if roll < 0.4:  # header that is not a JSON object
        return message(rng.choice((MessageType.HELLO, MessageType.FRAME)), _bad_header(rng)), False
    if roll < 0.55:  # HELLO mutations
        header = _mutate_json(rng, {"scene": SCENE, "mode": "queue", "max_in_flight": 4}, big=True)
        payload = bytes(rng.randrange(3)) if rng.random() < 0.1 else b""
        return message(MessageType.HELLO, _dump(header), payload) + message(
            MessageType.BYE, b"{}"
        ), False
    if roll < 0.7:  # FRAME ids
        header = {"id": rng.choice((None, "1", -1, 2**53, 1.0, True, [1], {})), "arrays": []}
        if rng.random() < 0.2:
            del header["id"]
        return message(MessageType.FRAME, _dump(header)), True
    if roll < 0.8:  # order: FRAME before HELLO, HELLO twice, server-side types
        kind = rng.choice((MessageType.FRAME, MessageType.HELLO, 0x81, 0x82, 0x85))
        return message(kind, _dump({"scene": SCENE, "id": 1, "arrays": []})), kind != 0x02
    if roll < 0.9:  # garbage
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64))), rng.random() < 0.5
    frame = frame_input(rng, 1)
    return hello + frame[: rng.randrange(1, len(frame))], False  # truncated, then half-closed


# -- HTTP -----------------------------------------------------------------------------------


def _npy(header: str, data: bytes) -> bytes:
    header = header + " " * (63 - (len(header) + 10) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + data


def http_body(rng: random.Random) -> bytes:
    """A mutated .npz body."""
    n = rng.choice((0, 1, 3, 7))
    positions = random_positions(rng, n)
    roll = rng.random()
    if roll < 0.25:
        scene = _dump(_mutate_json(rng, SCENE)).decode()
        return encode_npz_frame(positions, scene=scene, compress=rng.random() < 0.5)
    if roll < 0.5:
        body = bytearray(encode_npz_frame(positions, scene=SCENE, compress=rng.random() < 0.5))
        for _ in range(rng.randrange(1, 6)):
            body[rng.randrange(len(body))] = rng.randrange(256)
        return bytes(body[: rng.randrange(len(body) // 2, len(body) + 1)])
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        descr = rng.choice(("'<f8'", "'<f4'", "'|O'", "'<U3'", "[('a','<f8')]", "'<c16'", "42"))
        shape = rng.choice(("(1, 3)", "(0, 3)", "(2,)", "(-1, 3)", "(10**9, 3)", "()", "(1, 3"))
        order = rng.choice(("False", "True", "1", "None"))
        header = f"{{'descr': {descr}, 'fortran_order': {order}, 'shape': {shape}, }}"
        if rng.random() < 0.2:
            header = header[: rng.randrange(len(header))]
        archive.writestr("positions.npy", _npy(header, bytes(24 * rng.randrange(3))))
        if rng.random() < 0.3:
            archive.writestr(
                "scene.npy",
                _npy("{'descr': '<U5', 'fortran_order': False, 'shape': ()}", b"x" * 20),
            )
    return buffer.getvalue()


def http_input(rng: random.Random) -> bytes:
    """A whole HTTP/1.1 request (keep-alive), possibly malformed; garbage may be incomplete
    (the client then half-closes: see `run_http_input`)."""
    if rng.random() < 0.15:
        from fuzz_compact import compact_http_request

        return compact_http_request(rng, rng.randrange(1 << 20), _weird, SCENE)
    roll = rng.random()
    if roll < 0.55:
        body = http_body(rng)
        path = rng.choice(("/v1/render", "/v1/render?format=exr", "/v1/render?format=gif"))
        length = str(len(body))
        if rng.random() < 0.1:
            length = rng.choice(("\u00b2", "-1", "1e3", " 12", "0x10", "9" * 30, "1, 2"))
        head = f"POST {path} HTTP/1.1\r\nHost: x\r\nContent-Length: {length}\r\n"
        if rng.random() < 0.1:
            head += "Expect: 100-continue\r\n"
        if rng.random() < 0.05:
            head += "Transfer-Encoding: chunked\r\n"
        return (head + "\r\n").encode("utf-8") + body
    if roll < 0.7:
        scene = _dump(_mutate_json(rng, SCENE))
        head = f"POST /v1/sessions HTTP/1.1\r\nHost: x\r\nContent-Length: {len(scene)}\r\n\r\n"
        return head.encode() + scene
    if roll < 0.85:
        method = rng.choice(("GET", "DELETE", "PUT", "HEAD", "BREW", "get", "POST"))
        path = rng.choice(
            (
                "/healthz",
                "/readyz",
                "/v1/info",
                "/v1/sessions/" + "0" * 32,
                "/v1/sessions/" + "g" * 32 + "/frames",
                "/%00",
                "/" + "a" * rng.choice((10, 9000, 70000)),
                "*",
            )
        )
        version = rng.choice(
            ("HTTP/1.1", "HTTP/1.0", "HTTP/2.0", "HTTP/1.1x", "HTTP/0.9", "HTTP/1.2", "")
        )
        extra = "Content-Length: 0\r\n" if method in ("POST", "PUT") else ""
        return f"{method} {path} {version}\r\nHost: x\r\n{extra}\r\n".encode("utf-8", "replace")
    garbage = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80)))
    return garbage + (b"\r\n\r\n" if rng.random() < 0.7 else b"")


# -- clients --------------------------------------------------------------------------------


@dataclass
class Tally:
    inputs: int = 0
    stream_inputs: int = 0
    http_inputs: int = 0
    hangs: int = 0
    server_errors: int = 0  # HTTP >= 500 other than 503, stream render_failed
    busy: int = 0
    images: int = 0
    texts: int = 0  # error texts checked
    bad_texts: int = 0  # ... with a Python repr, a module path or a library message
    notes: list[str] = field(default_factory=list)

    def note(self, text: str) -> None:
        if len(self.notes) < 50:
            self.notes.append(text)

    def check_text(self, answer: object, where: str) -> None:
        """Count the error text of an ERROR header or an HTTP error body (`text_faults`)."""
        text = answer.get("error") if isinstance(answer, dict) else None
        self.texts += 1
        faults = text_faults(text)
        if faults:
            self.bad_texts += 1
            self.note(f"bad error text ({where}): {faults} in {text!r}")


class Conn:
    """A raw socket with exact reads under a timeout."""

    def __init__(self, port: int, timeout: float = 5.0) -> None:
        self.sock = socket.create_connection((HOST, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buffer = b""

    def read_exact(self, n: int) -> bytes:
        while len(self.buffer) < n:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                raise EOFError
            self.buffer += chunk
        out, self.buffer = self.buffer[:n], self.buffer[n:]
        return out

    def receive(self) -> tuple[int, dict[str, Any], bytes]:
        kind, header_len, payload_len = parse_prefix(
            self.read_exact(PREFIX_SIZE), max_header_bytes=1 << 20, max_payload_bytes=1 << 30
        )
        header = parse_header(self.read_exact(header_len)) if header_len else {}
        return int(kind), header, self.read_exact(payload_len)

    def close(self) -> None:
        self.sock.close()


def stream_hello(port: int, max_in_flight: int = 8) -> Conn:
    conn = Conn(port)
    conn.sock.sendall(
        encode_message(MessageType.HELLO, {"scene": SCENE, "max_in_flight": max_in_flight})
    )
    kind, header, _payload = conn.receive()
    assert kind == MessageType.WELCOME, header
    return conn


def run_frame_batch(
    conn: Conn, rng: random.Random, first_id: int, count: int, tally: Tally
) -> None:
    """`count` frame-level inputs pipelined on one connection; checks one answer each, in
    order, none fatal."""
    conn.sock.sendall(b"".join(frame_input(rng, first_id + i) for i in range(count)))
    for i in range(count):
        try:
            kind, header, _payload = conn.receive()
        except TimeoutError:
            tally.hangs += 1
            tally.note(f"frame batch hang at id {first_id + i}")
            raise
        if header.get("id") != first_id + i or kind not in (0x82, 0x83):
            tally.note(f"frame {first_id + i}: unexpected answer {kind:#x} {header}")
            raise EOFError
        if kind == 0x83 and header.get("fatal"):
            tally.note(f"frame {first_id + i}: fatal {header}")
            raise EOFError
        if kind == 0x83:
            tally.check_text(header, f"frame {first_id + i}")
        if kind == 0x82:
            tally.images += 1
        elif header.get("code") == "render_failed":
            tally.server_errors += 1
            tally.note(f"frame {first_id + i}: render_failed {header}")
        elif header.get("code") == "busy":
            tally.busy += 1
    tally.inputs += count
    tally.stream_inputs += count


def run_connection_input(port: int, rng: random.Random, tally: Tally, timeout: float = 5.0) -> None:
    data, needs_hello = connection_input(rng)
    conn = stream_hello(port) if needs_hello else Conn(port, timeout)
    try:
        conn.sock.settimeout(timeout)
        with contextlib.suppress(OSError):  # the server may close before taking it all
            conn.sock.sendall(data)
            conn.sock.shutdown(socket.SHUT_WR)  # no more: the server must finish and close
        start = time.monotonic()
        while True:
            try:
                kind, header, _payload = conn.receive()
            except (EOFError, ConnectionError):
                break
            except TimeoutError:
                tally.hangs += 1
                tally.note(f"connection input hang: {data[:60]!r}")
                break
            except Exception:  # not a valid message from the server
                tally.note(f"connection input: bad server bytes after {data[:40]!r}")
                break
            if kind == 0x83:
                tally.check_text(header, f"connection input {data[:40]!r}")
            if kind == 0x83 and header.get("code") == "render_failed":
                tally.server_errors += 1
                tally.note(f"render_failed for {data[:60]!r}: {header}")
            if time.monotonic() - start > timeout:
                tally.hangs += 1
                break
    finally:
        conn.close()
    tally.inputs += 1
    tally.stream_inputs += 1


class HttpConn:
    def __init__(self, port: int, timeout: float = 5.0) -> None:
        self.port = port
        self.timeout = timeout
        self.conn: Conn | None = None
        #: The last answer's JSON body (an error's), or None (an image, or no answer).
        self.answer: Any = None

    def request(self, data: bytes, *, last: bool = False) -> tuple[int, bool]:
        """(status or 0 for a close without answer, connection kept). `last`: half-close
        after sending (the request may be incomplete: the server must answer or close)."""
        if self.conn is None:
            self.conn = Conn(self.port, self.timeout)
        conn = self.conn
        try:
            conn.sock.sendall(data)
            if last:
                conn.sock.shutdown(socket.SHUT_WR)
            status = 100
            while status == 100:  # an interim 100 Continue, then the answer
                while b"\r\n\r\n" not in conn.buffer:
                    chunk = conn.sock.recv(65536)
                    if not chunk:
                        raise EOFError
                    conn.buffer += chunk
                head, _, conn.buffer = conn.buffer.partition(b"\r\n\r\n")
                lines = head.decode("latin-1").split("\r\n")
                status = int(lines[0].split()[1])
            headers = {
                k.strip().lower(): v.strip() for k, _, v in (x.partition(":") for x in lines[1:])
            }
            self.answer = None
            if not data.startswith(b"HEAD "):
                body = conn.read_exact(int(headers.get("content-length", "0")))
                if headers.get("content-type", "").startswith("application/json"):
                    self.answer = json.loads(body)
            keep = headers.get("connection", "").lower() != "close"
        except (EOFError, ConnectionError, OSError, ValueError, IndexError):
            self.close()
            return 0, False
        if not keep:
            self.close()
        return status, keep

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None


def run_http_input(http: HttpConn, rng: random.Random, tally: Tally) -> None:
    data = http_input(rng)
    start = time.monotonic()
    known = data.split(b" ", 1)[0] in (b"GET", b"POST", b"DELETE", b"PUT", b"HEAD")
    last = not known or not data.split(b"\r\n", 1)[0].endswith(b"HTTP/1.1")
    status, _keep = http.request(data, last=last)
    if last:
        http.close()
    if status == 0 and time.monotonic() - start >= http.timeout:
        tally.hangs += 1
        tally.note(f"HTTP hang: {data[:80]!r}")
    elif status >= 500 and status != 503:
        tally.server_errors += 1
        tally.note(f"HTTP {status} for {data[:120]!r}")
    elif status == 503:
        tally.busy += 1
    elif status == 200:
        tally.images += 1
    if status >= 400 and not data.startswith(b"HEAD "):
        tally.check_text(http.answer, f"HTTP {status} for {data[:60]!r}")
    if data.startswith(b"POST") and status != 200:
        http.close()  # the body may not have been read: start clean
    tally.inputs += 1
    tally.http_inputs += 1
