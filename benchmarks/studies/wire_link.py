"""End-to-end frames per second over a rate-limited link: a token-bucket relay on loopback
between the Python client and a real `sphrender serve` stream port, both directions limited to
the link's rate. Per link rate and frame encoding (float64 raw, as numpy's default reaches the
wire today; float32 raw; compact, order-free and in order), one stream session pipelines a
sequence of frames (the server's max_in_flight) and the frames per second are counted from the
first send to the last answer. Each answer's stage timings give the render process's
milliseconds a frame (the renderer's stages and the image encoding, one after the other in one
process): its inverse is a ceiling no encoding on the wire can lift.

Two scenes: the dam break rendered at 64x40 (what a trainee would see, small so that the render
is not the only limit on this CPU), and the same with the camera turned away from the particles
(the server still receives, decodes and culls every particle: the transport's own ceiling).
"""

from __future__ import annotations

import os
import signal
import socket
import statistics
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from benchmarks.bench_service import start_server
from sphrender.client.api import Client, StreamResult

#: The encodings compared, and what each asks of `Client.stream(compact=...)`.
_COMPACT: dict[str, bool | Literal["ordered"]] = {
    "float64 raw": False,
    "float32 raw": False,
    "compact": True,
    "compact, in order": "ordered",
}
ENCODINGS = tuple(_COMPACT)

#: Bytes one relay read moves at most; also the bucket's burst.
_CHUNK = 64 * 1024


class TokenBucket:
    """`rate` bytes a second, bursts of at most `burst` bytes."""

    def __init__(self, rate: float, burst: int = _CHUNK) -> None:
        self.rate, self.burst = rate, burst
        self.tokens, self.last = float(burst), time.monotonic()
        self.lock = threading.Lock()

    def take(self, amount: int) -> None:
        with self.lock:
            now = time.monotonic()
            self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate)
            self.last = now
            self.tokens -= amount
            wait = -self.tokens / self.rate if self.tokens < 0 else 0.0
        if wait > 0:
            time.sleep(wait)


class Relay:
    """Accepts connections on loopback and forwards each to `port`, each direction through its
    own token bucket at `bits_per_s`."""

    def __init__(self, port: int, bits_per_s: float) -> None:
        self.target, self.rate = port, bits_per_s / 8
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:
                return
            server = socket.create_connection(("127.0.0.1", self.target))
            for source, sink in ((client, server), (server, client)):
                bucket = TokenBucket(self.rate)
                threading.Thread(target=_pump, args=(source, sink, bucket), daemon=True).start()

    def close(self) -> None:
        self.listener.close()


def _pump(source: socket.socket, sink: socket.socket, bucket: TokenBucket) -> None:
    try:
        while data := source.recv(_CHUNK):
            bucket.take(len(data))
            sink.sendall(data)
        sink.shutdown(socket.SHUT_WR)
    except OSError:
        pass


@dataclass(frozen=True)
class LinkRow:
    scene: str
    link: str
    encoding: str
    fps: float
    bytes_per_frame: float
    server_ms: float  # median over the answers of the render process's stage timings, summed


def run_link(frames: list[dict[str, Any]], scenes: dict[str, dict[str, Any]],
             links: dict[str, float], rounds: int = 1) -> Iterator[LinkRow]:  # fmt: skip
    """Frames per second for each scene, link and encoding (see the module docstring)."""
    config = Path(tempfile.mkdtemp()) / "wire-link.toml"
    n = len(frames[0]["positions"])
    config.write_text(
        f"[limits]\nmax_particles = {max(n, 1000)}\n[stream]\nmax_payload_bytes = {64 << 20}\n"
        "max_in_flight = 4\n"
    )
    proc, ready = start_server(config)
    try:
        url = f"http://127.0.0.1:{ready['http_port']}"
        for scene_name, scene in scenes.items():
            for link_name, rate in links.items():
                relay = Relay(ready["stream_port"], rate)
                try:
                    for encoding in ENCODINGS:
                        fps, size, server_ms = _session_fps(
                            url, relay.port, scene, frames, encoding, rounds
                        )
                        yield LinkRow(scene_name, link_name, encoding, fps, size, server_ms)
                finally:
                    relay.close()
    finally:
        os.kill(proc.pid, signal.SIGTERM)
        proc.wait(60)


def _session_fps(url: str, port: int, scene: dict[str, Any], frames: list[dict[str, Any]],
                 encoding: str, rounds: int) -> tuple[float, float, float]:  # fmt: skip
    """(frames/s, bytes a frame, the render process's median ms a frame) of one session."""
    client = Client(url, timeout=300)
    compact: bool | Literal["ordered"] = _COMPACT[encoding]
    sent = 0
    server_ms: list[float] = []
    with client.stream(scene, stream_port=port, compact=compact) as session:
        assert (session.compact is not None) == bool(compact)
        start = time.perf_counter()
        outstanding = 0
        for _ in range(rounds):
            for frame in frames:
                positions = frame["positions"]
                if encoding == "float32 raw":
                    positions = positions.astype("float32")
                arrays = {k: v for k, v in frame.items() if k != "positions"}
                while outstanding >= session.max_in_flight:
                    server_ms.append(_server_ms(session.receive()))
                    outstanding -= 1
                session.send(positions, **arrays)
                outstanding += 1
                sent += 1
        while outstanding:
            server_ms.append(_server_ms(session.receive()))
            outstanding -= 1
        elapsed = time.perf_counter() - start
    size = _wire_bytes(frames, encoding, float(scene["particles"]["radius"]))
    return sent / elapsed, size, statistics.median(server_ms)


def _server_ms(answer: StreamResult) -> float:
    """The render process's stage timings of one IMAGE, summed: not the wait in the queue nor
    the hand-over (`ipc`), which overlap the previous frame's render."""
    assert answer.kind == "image", answer.header
    timings = answer.header.get("timings_ms", {})
    return float(sum(v for k, v in timings.items() if k not in ("queue", "ipc")))


def _wire_bytes(frames: list[dict[str, Any]], encoding: str, radius: float) -> float:
    """Mean FRAME payload bytes of the sequence in `encoding` (the compact one as a session)."""
    from sphrender.core.compact_encoder import POSITION_ERROR_FRACTION, CompactEncoder

    n = len(frames[0]["positions"])
    if encoding == "float64 raw":
        return n * (24 + 4 * (len(frames[0]) - 1))
    if encoding == "float32 raw":
        return n * (12 + 4 * (len(frames[0]) - 1))
    reorder = _COMPACT[encoding] is True
    encoder = CompactEncoder(position_error=POSITION_ERROR_FRACTION * radius, reorder=reorder)
    return sum(len(encoder.encode(i, f)[1]) for i, f in enumerate(frames)) / len(frames)
