"""WebSocket (``GET /v1/stream``) against the raw stream port: round-trip latency of a small
frame on loopback, measured in the same run on the same server.

Not a test. Run:  nice -n 10 .venv/bin/python benchmarks/bench_websocket.py [--rounds 12]
    [--per-round 20] [--particles 500] [--size 64x48]

One `sphrender serve` (ephemeral ports); one connection per transport, opened once, each with
its HELLO done: the raw stream (a plain socket), the WebSocket through a minimal client
(`tests/ws_client.py`: masking in Python, one frame per message) and through the `websockets`
library. Each frame is sent and its IMAGE awaited before the next (send, wait, send), so the
number is the transport's latency plus the render, not throughput. The transports take turns in
rounds of ``--per-round`` frames, so drift on the shared machine falls on all of them alike.
Prints per transport the median and p90 in ms and the ratio of its median to the raw stream's.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from service_harness import ServerProcess, ball
from websockets.sync.client import ClientConnection, connect
from ws_client import RawWebSocket

from sphrender.core.protocol import MessageType, encode_frame, encode_message


def measure(round_trip: Callable[[], None], count: int) -> list[float]:
    times = []
    for _ in range(count):
        start = time.perf_counter()
        round_trip()
        times.append((time.perf_counter() - start) * 1000.0)
    return times


def run(
    server: ServerProcess,
    library: ClientConnection,
    hello: bytes,
    frame: bytes,
    scene: dict[str, object],
    rounds: int,
    per_round: int,
) -> dict[str, list[float]]:
    """Latencies in ms per transport (module docstring)."""
    stream = server.stream()
    stream.hello(scene)
    raw_ws = RawWebSocket(server.http_port)
    assert raw_ws.open()[0] == 101
    raw_ws.send_message(hello)
    assert raw_ws.receive()[0] == MessageType.WELCOME
    library.send(hello)
    library.recv()

    def over_stream() -> None:
        stream.send(frame)
        assert stream.receive()[0] == MessageType.IMAGE

    def over_raw_ws() -> None:
        raw_ws.send_message(frame)
        assert raw_ws.receive()[0] == MessageType.IMAGE

    def over_library() -> None:
        library.send(frame)
        assert library.recv()[5] == MessageType.IMAGE

    transports = {
        "stream port (raw TCP)": over_stream,
        "WebSocket, minimal client": over_raw_ws,
        "WebSocket, websockets library": over_library,
    }
    for trip in transports.values():  # warm: the first frames of a session cost more
        measure(trip, 5)
    times: dict[str, list[float]] = {name: [] for name in transports}
    for _round in range(rounds):
        for name, trip in transports.items():
            times[name] += measure(trip, per_round)
    stream.close()
    raw_ws.close()
    return times


def report(
    times: dict[str, list[float]], args: argparse.Namespace, size: int, width: int, height: int
) -> None:
    base = statistics.median(times["stream port (raw TCP)"])
    print(
        f"{args.particles} particles ({size} B FRAME), {width}x{height} png, "
        f"{args.rounds} x {args.per_round} frames per transport, send-wait on loopback"
    )
    print(f"{'transport':32s} {'median ms':>10s} {'p90 ms':>8s} {'ratio':>6s}")
    for name, values in times.items():
        p90 = statistics.quantiles(values, n=10)[-1]
        median = statistics.median(values)
        print(f"{name:32s} {median:10.2f} {p90:8.2f} {median / base:6.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=12)
    parser.add_argument("--per-round", type=int, default=20)
    parser.add_argument("--particles", type=int, default=500)
    parser.add_argument("--size", default="64x48")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    scene: dict[str, object] = {
        "image": {"width": width, "height": height},
        "camera": {"eye": [0.6, 0.5, 0.9], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        "particles": {"radius": 0.02},
    }
    frame = encode_frame(0, ball(args.particles))
    hello = encode_message(MessageType.HELLO, {"scene": scene})
    with tempfile.TemporaryDirectory() as tmp, ServerProcess(Path(tmp)) as server:
        url = f"ws://127.0.0.1:{server.http_port}/v1/stream"
        with connect(url, max_size=None) as library:
            times = run(server, library, hello, frame, scene, args.rounds, args.per_round)
    report(times, args, len(frame), width, height)


if __name__ == "__main__":
    main()
