"""A raw WebSocket client for the service's ``GET /v1/stream``: frames built byte by byte, so
tests can send what a library never would (unmasked frames, fragments with a ping between them,
bytes that are no frame). Standard library only; well-behaved traffic in the tests goes through
the independent `websockets` package instead. Server frames are never masked (RFC 6455 5.1).
"""

from __future__ import annotations

import base64
import os
import socket
import struct
from typing import Any

from sphrender.core.protocol import PREFIX_SIZE, MessageType, parse_header, parse_prefix

HOST = "127.0.0.1"
TEXT, BINARY, CLOSE, PING, PONG, CONTINUATION = 0x1, 0x2, 0x8, 0x9, 0xA, 0x0


def frame_bytes(
    opcode: int, payload: bytes, *, fin: bool = True, mask: bool = True, rsv: int = 0
) -> bytes:
    """One WebSocket frame as a client sends it (masked unless told otherwise)."""
    first = (0x80 if fin else 0) | (rsv << 4) | opcode
    n = len(payload)
    if n < 126:
        head = struct.pack("!BB", first, (0x80 if mask else 0) | n)
    elif n < 1 << 16:
        head = struct.pack("!BBH", first, (0x80 if mask else 0) | 126, n)
    else:
        head = struct.pack("!BBQ", first, (0x80 if mask else 0) | 127, n)
    if not mask:
        return head + payload
    key = os.urandom(4)
    stream = (key * (n // 4 + 1))[:n]
    masked = int.from_bytes(payload, "little") ^ int.from_bytes(stream, "little")
    return head + key + masked.to_bytes(n, "little")


def upgrade_request(
    port: int, path: str = "/v1/stream", headers: dict[str, str] | None = None
) -> bytes:
    fields = {
        "Host": f"{HOST}:{port}",
        "Upgrade": "websocket",
        "Connection": "Upgrade",
        "Sec-WebSocket-Key": base64.b64encode(os.urandom(16)).decode(),
        "Sec-WebSocket-Version": "13",
        **(headers or {}),
    }
    lines = [f"GET {path} HTTP/1.1"] + [f"{k}: {v}" for k, v in fields.items() if v is not None]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


class RawWebSocket:
    """One connection to `port`: `open` sends the upgrade and returns the HTTP answer."""

    def __init__(self, port: int, timeout: float = 30.0) -> None:
        self.port = port
        self.sock = socket.create_connection((HOST, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._buffer = b""

    def open(
        self, headers: dict[str, str] | None = None, before: bytes = b""
    ) -> tuple[int, dict[str, str], bytes]:
        """Upgrade (after `before`); (status, headers, body) where a refusal has a body."""
        self.sock.sendall(before + upgrade_request(self.port, headers=headers))
        return self.read_answer()

    def read_answer(self) -> tuple[int, dict[str, str], bytes]:
        """The HTTP answer to an upgrade request: (status, headers, body)."""
        while b"\r\n\r\n" not in self._buffer:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise EOFError(f"closed during the handshake: {self._buffer!r}")
            self._buffer += chunk
        head, self._buffer = self._buffer.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        fields = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:])}
        body = b""
        if status != 101:
            body = self._exact(int(fields.get("content-length", "0")))
        return status, fields, body

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def send_message(self, data: bytes, fragments: int = 1) -> None:
        """`data` as one binary message in `fragments` frames."""
        step = max(1, -(-len(data) // fragments))
        parts = [data[i : i + step] for i in range(0, len(data), step)] or [b""]
        frames = [
            frame_bytes(BINARY if i == 0 else CONTINUATION, part, fin=i == len(parts) - 1)
            for i, part in enumerate(parts)
        ]
        self.sock.sendall(b"".join(frames))

    def _exact(self, n: int) -> bytes:
        while len(self._buffer) < n:
            chunk = self.sock.recv(1 << 20)
            if not chunk:
                raise EOFError("the server closed the connection")
            self._buffer += chunk
        data, self._buffer = self._buffer[:n], self._buffer[n:]
        return data

    def read_frame(self) -> tuple[int, bool, bytes]:
        """(opcode, fin, payload) of the server's next frame."""
        first, second = self._exact(2)
        assert not second & 0x80, "server frames must not be masked"
        n = second & 0x7F
        if n == 126:
            (n,) = struct.unpack("!H", self._exact(2))
        elif n == 127:
            (n,) = struct.unpack("!Q", self._exact(8))
        return first & 0x0F, bool(first & 0x80), self._exact(n)

    def receive(self) -> tuple[MessageType, dict[str, Any], bytes] | tuple[str, int, str]:
        """The next stream message, or ``("close", code, reason)`` for the server's Close."""
        while True:
            opcode, fin, payload = self.read_frame()
            if opcode == CLOSE:
                code = struct.unpack("!H", payload[:2])[0] if len(payload) >= 2 else 1005
                return "close", code, payload[2:].decode("utf-8")
            if opcode == BINARY:
                assert fin, "the server sends each stream message as one frame"
                kind, hlen, plen = parse_prefix(
                    payload[:PREFIX_SIZE], max_header_bytes=1 << 20, max_payload_bytes=1 << 30
                )
                header = parse_header(payload[PREFIX_SIZE : PREFIX_SIZE + hlen]) if hlen else {}
                body = payload[PREFIX_SIZE + hlen :]
                assert len(body) == plen
                return kind, header, body
            assert opcode in (PING, PONG), opcode

    def until_close(self, limit: int = 100) -> tuple[list[Any], Any]:
        """The stream messages before the server's Close, and the Close."""
        seen: list[Any] = []
        for _ in range(limit):
            answer = self.receive()
            if answer[0] == "close":
                return seen, answer
            seen.append(answer)
        raise AssertionError(f"no Close after {limit} messages")

    def closed_after(self) -> bool:
        """True once the server has closed TCP (EOF or reset) after its Close."""
        try:
            return self.sock.recv(1) == b""
        except ConnectionResetError:
            return True

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> RawWebSocket:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
