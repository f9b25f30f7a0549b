"""Service benchmark: frames per second and latency over the stream for 1, 4 and 16 clients,
per encoding (png, jpeg, raw, exr).

Not a test. Run:  .venv/bin/python benchmarks/bench_service.py [--frames 24] [--sizes 640x360]
    [--encodings png,jpeg,raw] [--clients 1,16] [--summary]

Starts a real `sphrender serve` on loopback (ephemeral ports), sends a ~100k-particle jittered
lattice ball (float64 positions, 2.4 MB per frame) and reports, per image size:

* N clients in ``queue`` mode, each pipelining up to the server's ``max_in_flight`` frames
  (a writer and a reader thread per client): aggregate fps, and latency p50/p99 from a frame's
  send to its IMAGE (queueing included, so latency grows with the number of clients);
* one client sending one frame at a time (send, wait, send) against the same client pipelining,
  measured in the same run: the throughput gain of pipelining (render of frame k+1 overlapping
  the encode of frame k and the network/decoding of the next frame);
* one HTTP client, one request at a time, for comparison with the stream.

Every configuration renders the same frames; the total frame count per configuration is
``--frames`` (split evenly over the clients), so a whole run stays short.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.core.protocol import (
    PREFIX_SIZE,
    MessageType,
    encode_frame,
    encode_message,
    encode_npz_frame,
    parse_header,
    parse_prefix,
)
from sphrender.server.content.lattice import jittered_lattice_ball

SPHRENDER = str(Path(sys.executable).with_name("sphrender"))


def start_server(config_path: Path) -> tuple[subprocess.Popen[bytes], dict[str, Any]]:
    proc = subprocess.Popen(
        [SPHRENDER, "serve", "--config", str(config_path), "--port", "0", "--stream-port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    assert proc.stdout is not None
    selector = selectors.DefaultSelector()
    selector.register(proc.stdout, selectors.EVENT_READ)
    if not selector.select(120):
        proc.kill()
        raise SystemExit("server did not start")
    return proc, json.loads(proc.stdout.readline())


class Client:
    def __init__(self, port: int, scene: dict[str, Any]) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=300)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock.sendall(encode_message(MessageType.HELLO, {"scene": scene}))
        kind, header = self.receive()
        assert kind == MessageType.WELCOME, header
        self.max_in_flight = int(header["max_in_flight"])

    def _exact(self, n: int) -> bytes:
        chunks = []
        while n:
            chunk = self.sock.recv(min(n, 1 << 20))
            if not chunk:
                raise EOFError
            chunks.append(chunk)
            n -= len(chunk)
        return b"".join(chunks)

    def receive(self) -> tuple[MessageType, dict[str, Any]]:
        kind, header_len, payload_len = parse_prefix(
            self._exact(PREFIX_SIZE), max_header_bytes=1 << 20, max_payload_bytes=1 << 31
        )
        header = parse_header(self._exact(header_len)) if header_len else {}
        self._exact(payload_len)
        return kind, header

    def run(
        self,
        frames: list[bytes],
        pipelined: bool,
        latencies: list[float],
        stages: list[dict[str, float]] | None = None,
    ) -> None:
        """Send the FRAME messages, pipelined or one at a time; time each to its IMAGE."""
        count = len(frames)
        sent_at: dict[int, float] = {}
        window = threading.Semaphore(self.max_in_flight if pipelined else 1)

        def writer() -> None:
            for i in range(count):
                window.acquire()
                sent_at[i] = time.perf_counter()
                self.sock.sendall(frames[i])

        thread = threading.Thread(target=writer)
        thread.start()
        for i in range(count):
            kind, header = self.receive()
            assert kind == MessageType.IMAGE and header["id"] == i, header
            latencies.append(time.perf_counter() - sent_at[i])
            if stages is not None:
                stages.append(header["timings_ms"])
            window.release()
        thread.join()

    def close(self) -> None:
        self.sock.sendall(encode_message(MessageType.BYE, {}))
        self.sock.close()


def stream_run(
    port: int,
    scene: dict[str, Any],
    positions: np.ndarray,
    clients: int,
    total: int,
    pipelined: bool,
    stages: list[dict[str, float]] | None = None,
) -> tuple[float, list[float]]:
    per_client = max(1, total // clients)
    frames = [encode_frame(i, positions) for i in range(per_client)]
    connections = [Client(port, scene) for _ in range(clients)]
    latencies: list[float] = []
    lock = threading.Lock()

    def run(client: Client) -> None:
        local: list[float] = []
        client.run(frames, pipelined, local, stages)
        with lock:
            latencies.extend(local)

    threads = [threading.Thread(target=run, args=(c,)) for c in connections]
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    elapsed = time.perf_counter() - start
    for client in connections:
        client.close()
    return len(latencies) / elapsed, latencies


def http_run(port: int, body: bytes, total: int) -> tuple[float, list[float]]:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=300)
    latencies = []
    start = time.perf_counter()
    for _ in range(total):
        t0 = time.perf_counter()
        connection.request("POST", "/v1/render", body, {"Content-Type": "application/x-npz"})
        response = connection.getresponse()
        response.read()
        assert response.status == 200, response.status
        latencies.append(time.perf_counter() - t0)
    elapsed = time.perf_counter() - start
    connection.close()
    return total / elapsed, latencies


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values) * 1e3, q))


def row(name: str, fps: float, latencies: list[float], extra: str = "") -> None:
    print(
        f"  {name:<34} {fps:7.2f} fps   p50 {percentile(latencies, 50):8.1f} ms"
        f"   p99 {percentile(latencies, 99):8.1f} ms   {extra}",
        flush=True,
    )


def run_size(
    args: argparse.Namespace,
    ready: dict[str, Any],
    positions: np.ndarray,
    r: float,
    size: str,
    encoding: str,
    summary: list[tuple[str, str, float, float, float]],
) -> None:
    width, height = (int(v) for v in size.split("x"))
    scene = {
        "image": {"width": width, "height": height},
        "camera": {"eye": [1.3, 1.0, 1.7], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        "particles": {"radius": r},
        "output": {"format": encoding},
    }
    print(f"\n{width}x{height}, {encoding}, {args.frames} frames per configuration", flush=True)
    # Warm-up (scene preparation, first-frame costs).
    stream_run(ready["stream_port"], scene, positions, 1, 2, True)
    stages: list[dict[str, float]] = []
    one_fps, one_lat = stream_run(
        ready["stream_port"], scene, positions, 1, args.frames, False, stages
    )
    row("stream, 1 client, one at a time", one_fps, one_lat)
    means = {n: float(np.mean([s.get(n, 0.0) for s in stages])) for n in stages[0]}
    print("    server ms/frame: " + ", ".join(f"{n} {v:.1f}" for n, v in means.items()))
    fps_by_clients = {}
    for clients in (int(c) for c in args.clients.split(",")):
        fps, lat = stream_run(ready["stream_port"], scene, positions, clients, args.frames, True)
        fps_by_clients[clients] = fps
        extra = f"x{fps / one_fps:.2f} vs one-at-a-time" if clients == 1 else ""
        row(f"stream, {clients} client(s), pipelined", fps, lat, extra)
    summary.append(
        (size, encoding, percentile(one_lat, 50), one_fps, fps_by_clients.get(16, float("nan")))
    )
    if not args.skip_http:
        body = encode_npz_frame(positions, scene=scene)
        fps, lat = http_run(ready["http_port"], body, max(4, args.frames // 2))
        row("HTTP, 1 client, one at a time", fps, lat, f"x{fps / one_fps:.2f} vs stream")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=24, help="frames per configuration")
    parser.add_argument("--sizes", default="640x360,1280x720")
    parser.add_argument("--clients", default="1,4,16")
    parser.add_argument("--ball-radius", type=float, default=0.58, help="0.58 -> ~100k particles")
    parser.add_argument("--encoder-threads", type=int, default=2)
    parser.add_argument("--encodings", default="png,jpeg,raw,exr", help="output.format values")
    parser.add_argument("--skip-http", action="store_true")
    args = parser.parse_args()
    summary: list[tuple[str, str, float, float, float]] = []

    r = 0.01
    positions = jittered_lattice_ball(args.ball_radius, r)
    print(f"{positions.shape[0]} particles, {positions.nbytes / 1e6:.1f} MB of float64 positions")
    config = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench-server-{os.getpid()}.toml"
    config.write_text(
        "[limits]\nmax_sessions = 64\n[stream]\nmax_connections = 64\n"
        f"[scheduler]\nqueue_per_session = 8\nqueue_total = 256\n"
        f"encoder_threads = {args.encoder_threads}\n"
    )
    proc, ready = start_server(config)
    print(f"server: {ready['gl_renderer']}, {os.cpu_count()} CPUs")
    try:
        for size in args.sizes.split(","):
            for encoding in args.encodings.split(","):
                run_size(args, ready, positions, r, size, encoding, summary)
        print("\nend-to-end latency, 1 client one frame at a time (p50 ms), and fps:")
        for size, encoding, p50, fps1, fps16 in summary:
            print(
                f"  {size:>9} {encoding:<5} p50 {p50:7.1f} ms   1 client {fps1:5.2f} fps"
                f"   16 clients {fps16:5.2f} fps"
            )
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(60)
        config.unlink()
        print(f"\nserver exit status after SIGTERM: {code}")


if __name__ == "__main__":
    main()
