"""First frames of a session: what frame 1 costs against frame 10, stream and HTTP.

Not a test. Run:  .venv/bin/python benchmarks/bench_first_frame.py [--frames 10] [--size 640x360]
    [--particles 20000] [--servers 1]

Starts a fresh `sphrender serve` on loopback (its renderer process warm with the default scene, as
always), then, one frame at a time (send, wait for the image): a new stream session of a scene the
server has not seen (its own image size, radius, output format), then a new HTTP session
(`POST /v1/sessions`) of another. The frames are a jittered lattice ball with densities and
temperatures, as a simulator sends them. Prints, per frame, the client's latency (send to image)
and the server's stage timings (`queue`, the passes, `encode`, `ipc`), and the ratio of frame 1's
latency to frame 10's (and to the median of frames 6..10, steadier on a shared machine).
"""

from __future__ import annotations

import argparse
import json
import selectors
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.client.api import Client
from sphrender.core.protocol import encode_npz_frame
from sphrender.server.content.lattice import jittered_lattice_ball

SPHRENDER = str(Path(sys.executable).with_name("sphrender"))
RADIUS = 0.02


def start_server() -> tuple[subprocess.Popen[bytes], dict[str, Any]]:
    proc = subprocess.Popen(
        [SPHRENDER, "serve", "--port", "0", "--stream-port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
    )
    assert proc.stdout is not None
    selector = selectors.DefaultSelector()
    selector.register(proc.stdout, selectors.EVENT_READ)
    if not selector.select(180):
        proc.kill()
        raise SystemExit("server did not start")
    return proc, json.loads(proc.stdout.readline())


def make_frames(count: int, particles: int) -> list[dict[str, np.ndarray]]:
    """`count` frames of a ball of about `particles` particles, each moved a little."""
    ball = RADIUS * 2 * (3 * particles / (4 * np.pi)) ** (1 / 3)
    frames = []
    for k in range(count):
        positions = jittered_lattice_ball(ball, RADIUS, seed=k) + np.array([0.0, 0.001 * k, 0.0])
        n = len(positions)
        frames.append(
            {
                "positions": positions,
                "densities": np.full(n, 1000.0, np.float32),
                "temperatures": np.linspace(1500.0, 2200.0, n, dtype=np.float32),
            }
        )
    return frames


def scene_for(width: int, height: int, fmt: str, radius: float) -> dict[str, Any]:
    return {
        "image": {"width": width, "height": height},
        "particles": {"radius": radius},
        "output": {"format": fmt},
        "camera": {"eye": [0.0, 0.3, 1.2], "target": [0.0, 0.0, 0.0]},
    }


def stream_session(client: Client, scene: dict[str, Any], frames: list[dict[str, Any]]) -> list:
    rows = []
    start = time.perf_counter()
    with client.stream(scene) as session:
        hello_ms = (time.perf_counter() - start) * 1e3
        print(f"stream HELLO to WELCOME (the scene warmed): {hello_ms:.0f} ms")
        for frame in frames:
            start = time.perf_counter()
            arrays = {k: v for k, v in frame.items() if k != "positions"}
            session.send(frame["positions"], **arrays)
            result = session.receive()
            latency = (time.perf_counter() - start) * 1e3
            if result.kind != "image":
                raise SystemExit(f"stream frame failed: {result.header}")
            rows.append((latency, dict(result.header.get("timings_ms", {}))))
    return rows


def http_session(client: Client, scene: dict[str, Any], frames: list[dict[str, Any]]) -> list:
    start = time.perf_counter()
    _headers, data = client.request(
        "POST", "/v1/sessions", json.dumps(scene).encode(), "application/json"
    )
    print(f"POST /v1/sessions (the scene warmed): {(time.perf_counter() - start) * 1e3:.0f} ms")
    session_id = json.loads(data)["id"]
    rows = []
    for frame in frames:
        start = time.perf_counter()
        body = encode_npz_frame(**frame)
        headers, _image = client.request(
            "POST", f"/v1/sessions/{session_id}/frames", body, "application/x-npz"
        )
        latency = (time.perf_counter() - start) * 1e3
        timings = {}
        for item in headers.get("server-timing", "").split(","):
            name, _, dur = item.strip().partition(";dur=")
            if dur:
                timings[name] = float(dur)
        rows.append((latency, timings))
    client.request("DELETE", f"/v1/sessions/{session_id}")
    return rows


def report(label: str, rows: list) -> float:
    stages = sorted({k for _lat, t in rows for k in t})
    print(f"\n{label}")
    print("frame  latency_ms  " + "  ".join(f"{s:>9}" for s in stages))
    for k, (latency, timings) in enumerate(rows, 1):
        cells = "  ".join(f"{timings.get(s, float('nan')):9.1f}" for s in stages)
        print(f"{k:5d}  {latency:10.1f}  {cells}")
    first, tenth = rows[0][0], rows[-1][0]
    steady = statistics.median(lat for lat, _t in rows[len(rows) // 2 :])
    print(
        f"{label}: frame 1 / frame {len(rows)} = {first / tenth:.2f}; "
        f"frame 1 / median of the later half = {first / steady:.2f}"
    )
    return first / steady


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--size", default="640x360")
    parser.add_argument("--particles", type=int, default=20000)
    parser.add_argument("--servers", type=int, default=1, help="fresh servers, one after another")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    frames = make_frames(args.frames, args.particles)
    print(f"{len(frames[0]['positions'])} particles, {width}x{height}, {args.frames} frames")
    ratios: dict[str, list[float]] = {"stream": [], "http": []}
    for k in range(args.servers):
        proc, ready = start_server()
        try:
            client = Client(f"http://127.0.0.1:{ready['http_port']}")
            stream_scene = scene_for(width, height, "png", RADIUS)
            http_scene = scene_for(width - 32, height - 32, "jpeg", RADIUS * 1.1)
            runs: list[tuple[str, Any, dict[str, Any]]] = [
                ("stream", stream_session, stream_scene),
                ("http", http_session, http_scene),
            ]
            order = runs if k % 2 == 0 else runs[::-1]  # each transport first on a fresh server
            for place, (name, run, scene) in enumerate(order):
                label = f"{name} session, server {k + 1}, {('first', 'second')[place]} session"
                ratios[name].append(report(label, run(client, scene, frames)))
        finally:
            proc.terminate()
            proc.wait(30)
    for name, values in ratios.items():
        print(f"{name}: first / steady per server: " + ", ".join(f"{v:.2f}" for v in values))


if __name__ == "__main__":
    main()
