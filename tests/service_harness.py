"""A real `sphrender serve` process on loopback, and minimal HTTP and stream clients for tests.

The server is started with ``--port 0 --stream-port 0`` and reports the ports the OS chose on its
first stdout line, so tests never race for a "free" port. Every wait here is bounded.
"""

from __future__ import annotations

import http.client
import json
import os
import selectors
import signal
import socket
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import OpenImageIO as oiio
from cli_harness import SPHRENDER

from sphrender.core.protocol import (
    PREFIX_SIZE,
    MessageType,
    encode_frame,
    encode_message,
    parse_header,
    parse_prefix,
)
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import encode_for_scene
from sphrender.server.scene import Scene, scene_from_dict

HOST = "127.0.0.1"
START_TIMEOUT_S = 90.0

#: The small scene most service tests render: 64x48, a ball of particles seen from the side.
SMALL_SCENE: dict[str, Any] = {
    "image": {"width": 64, "height": 48},
    "camera": {"eye": [0.6, 0.5, 0.9], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
    "particles": {"radius": 0.02},
}


#: Settings of the shared test server: small limits and short timeouts so the limit and timeout
#: tests are quick, generous enough that the concurrency tests are never refused.
MAIN_CONFIG: dict[str, dict[str, Any]] = {
    "http": {"max_body_bytes": 4 << 20, "read_timeout_s": 2.0, "body_timeout_s": 3.0},
    "stream": {
        "max_in_flight": 8,
        "max_payload_bytes": 4 << 20,
        "max_header_bytes": 16384,
        "handshake_timeout_s": 3.0,
        "message_timeout_s": 1.5,
        "idle_timeout_s": 60.0,
    },
    "limits": {"max_particles": 50_000, "max_pixels": 320 * 240, "max_sessions": 48},
    "scheduler": {"queue_per_session": 8, "queue_total": 64, "encoder_threads": 2},
}


def ball(count: int = 2000, seed: int = 0, shift: float = 0.0) -> npt.NDArray[np.float64]:
    rng = np.random.default_rng(seed)
    positions = rng.normal(size=(count, 3)) * 0.15
    positions[:, 0] += shift
    return positions


def toml_text(config: Mapping[str, Mapping[str, Any]]) -> str:
    """Flat two-level TOML; JSON scalars and string lists are valid TOML values."""
    lines: list[str] = []
    for section, values in config.items():
        lines.append(f"[{section}]")
        lines.extend(f"{key} = {json.dumps(value)}" for key, value in values.items())
    return "\n".join(lines) + "\n"


def png_pixels(data: bytes, tmp_dir: Path) -> npt.NDArray[np.uint8]:
    """Decode PNG bytes with OpenImageIO (through a file; its Python API reads files)."""
    path = tmp_dir / f"decode-{time.monotonic_ns()}.png"
    path.write_bytes(data)
    try:
        buf = oiio.ImageBuf(str(path))
        pixels = buf.get_pixels(oiio.UINT8)
        if pixels is None:
            raise AssertionError(f"OpenImageIO cannot read the PNG: {buf.geterror()}")
        return np.asarray(pixels)
    finally:
        path.unlink()


def reference_png(
    renderer: SurfaceRenderer, positions: np.ndarray, scene_dict: Mapping[str, Any]
) -> bytes:
    """What the service should answer, rendered in the test process with the same engine."""
    from sphrender.core.frame import make_frame

    scene = scene_from_dict(scene_dict) if scene_dict else Scene()
    frame, _stats = renderer.render(make_frame(positions), scene)
    return encode_for_scene(frame, scene, "png")


class ServerProcess:
    """`sphrender serve` as a subprocess; use as a context manager (always stopped)."""

    def __init__(
        self,
        tmp_dir: Path,
        config: Mapping[str, Mapping[str, Any]] | None = None,
        env: Mapping[str, str] | None = None,
        args: tuple[str, ...] = (),
    ) -> None:
        self.tmp_dir = tmp_dir
        tmp_dir.mkdir(parents=True, exist_ok=True)
        self.config_path = tmp_dir / "server.toml"
        self.config_path.write_text(toml_text(config or {}))
        self.stderr_path = tmp_dir / "server.log"
        self._stderr = open(self.stderr_path, "wb")  # noqa: SIM115 - closed in stop()
        # The token and fault injection come only from the test, never from the outer environment.
        inherited = {"SPHRENDER_TOKEN", "SPHRENDER_FAULT_INJECTION", "SPHRENDER_TEST_FAULTS"}
        environment = {k: v for k, v in os.environ.items() if k not in inherited}
        environment.update(env or {})
        self.proc = subprocess.Popen(
            [
                SPHRENDER,
                "serve",
                "--config",
                str(self.config_path),
                "--port",
                "0",
                "--stream-port",
                "0",
                "--log-json",
                *args,
            ],
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            env=environment,
        )
        self.ready = self._read_ready_line()
        self.http_port: int = self.ready["http_port"]
        self.stream_port: int = self.ready["stream_port"]

    def _read_ready_line(self) -> dict[str, Any]:
        assert self.proc.stdout is not None
        selector = selectors.DefaultSelector()
        selector.register(self.proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + START_TIMEOUT_S
        line = b""
        while not line.endswith(b"\n"):
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not selector.select(remaining):
                self.stop(signal.SIGKILL)
                raise AssertionError(f"server did not start in time:\n{self.logs()}")
            chunk = os.read(self.proc.stdout.fileno(), 4096)
            if not chunk:
                code = self.proc.wait(10)
                raise AssertionError(f"server exited with {code} before listening:\n{self.logs()}")
            line += chunk
        selector.close()
        return dict(json.loads(line.decode()))

    def logs(self) -> str:
        if not self._stderr.closed:
            self._stderr.flush()
        return self.stderr_path.read_text(errors="replace")

    def log_events(self) -> list[dict[str, Any]]:
        events = []
        for line in self.logs().splitlines():
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return events

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self._stderr.close()
        return int(self.proc.returncode)

    def __enter__(self) -> ServerProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- clients ---------------------------------------------------------------------------------

    def request(
        self,
        method: str,
        path: str,
        body: bytes | None = None,
        headers: Mapping[str, str] | None = None,
        timeout: float = 60.0,
    ) -> tuple[int, dict[str, str], bytes]:
        connection = http.client.HTTPConnection(HOST, self.http_port, timeout=timeout)
        try:
            connection.request(method, path, body=body, headers=dict(headers or {}))
            response = connection.getresponse()
            return response.status, dict(response.getheaders()), response.read()
        finally:
            connection.close()

    def json(self, method: str, path: str, body: Any = None, **kw: Any) -> tuple[int, Any]:
        data = None if body is None else json.dumps(body).encode()
        status, _headers, payload = self.request(method, path, data, **kw)
        return status, json.loads(payload) if payload else None

    def stream(self, timeout: float = 60.0) -> StreamClient:
        return StreamClient(self.stream_port, timeout)

    def metrics_text(self, headers: Mapping[str, str] | None = None) -> str:
        status, _headers, body = self.request("GET", "/metrics", headers=headers)
        assert status == 200
        return body.decode()


class StreamClient:
    """A blocking client of the streaming protocol (what a frontend would implement)."""

    def __init__(self, port: int, timeout: float = 60.0) -> None:
        self.sock = socket.create_connection((HOST, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def hello(self, scene: Mapping[str, Any] | None = None, **fields: Any) -> dict[str, Any]:
        header = {"scene": dict(scene if scene is not None else SMALL_SCENE), **fields}
        self.send(encode_message(MessageType.HELLO, header))
        kind, answer, _payload = self.receive()
        assert kind == MessageType.WELCOME, (kind, answer)
        return answer

    def frame(self, frame_id: int, positions: np.ndarray, **kw: Any) -> None:
        self.send(encode_frame(frame_id, positions, **kw))

    def _recv_exact(self, n: int) -> bytes:
        chunks = []
        while n:
            chunk = self.sock.recv(min(n, 1 << 20))
            if not chunk:
                raise EOFError("server closed the connection")
            chunks.append(chunk)
            n -= len(chunk)
        return b"".join(chunks)

    def receive(self) -> tuple[MessageType, dict[str, Any], bytes]:
        kind, header_len, payload_len = parse_prefix(
            self._recv_exact(PREFIX_SIZE), max_header_bytes=1 << 20, max_payload_bytes=1 << 30
        )
        header = parse_header(self._recv_exact(header_len)) if header_len else {}
        payload = self._recv_exact(payload_len) if payload_len else b""
        return kind, header, payload

    def closed_by_server(self) -> bool:
        """True when the server has closed the connection (EOF or reset)."""
        try:
            return self.sock.recv(1) == b""
        except ConnectionResetError:
            return True

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> StreamClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
