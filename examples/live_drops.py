"""Live frames from a simulator's step callback: hot drops falling into a box, streamed to
`sphrender serve` with `LiveSession` while the simulation runs, the camera orbiting by per-frame
scene overrides.

    .venv/bin/python examples/live_drops.py                        # starts a local server
    .venv/bin/python examples/live_drops.py --server http://HOST:8080 --steps 300 --out frames/

The simulator (numpy only, position-based: gravity, particles pushed apart where they overlap,
walls that absorb some of the impact, drops cooling from 1900 K) knows nothing about rendering: it
calls ``on_step`` after each step, as a real solver's callback would. The callback hands the
step's arrays to `LiveSession.submit`, which copies them and returns at once; when the simulator
is faster than the server, frames waiting to be sent are replaced by newer ones (``latest``
mode) and reported dropped. Images arrive on the session's delivery thread.
"""

from __future__ import annotations

import argparse
import json
import math
import selectors
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.client.api import Client, StreamResult
from sphrender.client.live import LiveSession

RADIUS = 0.01  # particle radius, m
BOX = np.array([0.15, 0.3, 0.15])  # half-width, height, half-depth of the box, m


@dataclass
class Step:
    index: int
    positions: np.ndarray  # (N, 3) float32, m
    velocities: np.ndarray  # (N, 3) float32, m/s
    temperatures: np.ndarray  # (N,) float32, K


def neighbour_pairs(positions: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) of particles closer than `h`: a uniform grid of cell `h`, sorted."""
    cells = np.floor(positions / h).astype(np.int64)
    keys = (cells[:, 0] * 73856093) ^ (cells[:, 1] * 19349663) ^ (cells[:, 2] * 83492791)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    firsts, seconds = [], []
    for offset in np.stack(np.meshgrid(*[(-1, 0, 1)] * 3, indexing="ij"), -1).reshape(-1, 3):
        c = cells + offset
        wanted = (c[:, 0] * 73856093) ^ (c[:, 1] * 19349663) ^ (c[:, 2] * 83492791)
        start = np.searchsorted(sorted_keys, wanted, "left")
        counts = np.searchsorted(sorted_keys, wanted, "right") - start
        i = np.repeat(np.arange(len(positions)), counts)
        within = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        j = order[np.repeat(start, counts) + within]
        keep = i < j
        firsts.append(i[keep])
        seconds.append(j[keep])
    i, j = np.concatenate(firsts), np.concatenate(seconds)
    close = np.linalg.norm(positions[i] - positions[j], axis=1) < h
    pairs = np.unique(np.stack([i[close], j[close]], 1), axis=0)  # hash collisions: once each
    return pairs[:, 0], pairs[:, 1]


class DropSimulator:
    """Drops of ~120 particles fall into an open box every `every` steps."""

    def __init__(self, dt: float = 1 / 120, every: int = 12, seed: int = 0) -> None:
        self.dt = dt
        self.every = every
        self.rng = np.random.default_rng(seed)
        self.x = np.zeros((0, 3))
        self.v = np.zeros((0, 3))
        self.kelvin = np.zeros(0)

    def _spawn(self) -> None:
        axis = np.arange(-3, 4) * 2 * RADIUS
        ball = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        ball = ball[np.linalg.norm(ball, axis=1) <= 3 * 2 * RADIUS]
        centre = [*self.rng.uniform(-0.08, 0.08, 1), 0.45, *self.rng.uniform(-0.08, 0.08, 1)]
        self.x = np.vstack([self.x, ball + centre])
        self.v = np.vstack([self.v, np.tile([0.0, -1.0, 0.0], (len(ball), 1))])
        self.kelvin = np.concatenate([self.kelvin, np.full(len(ball), 1900.0)])

    def step(self, index: int) -> None:
        if index % self.every == 0:
            self._spawn()
        previous = self.x.copy()
        self.v[:, 1] -= 9.81 * self.dt
        self.x += self.v * self.dt
        for _ in range(3):  # push overlapping pairs apart, half the overlap each
            i, j = neighbour_pairs(self.x, 2 * RADIUS)
            d = self.x[i] - self.x[j]
            dist = np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-9)
            push = 0.5 * (2 * RADIUS - dist) * d / dist
            np.add.at(self.x, i, push)
            np.add.at(self.x, j, -push)
        low = np.array([-BOX[0], 0.0, -BOX[2]]) + RADIUS
        high = np.array([BOX[0], 10.0, BOX[2]]) - RADIUS
        self.x = np.clip(self.x, low, high)
        self.v = 0.98 * (self.x - previous) / self.dt  # position-based: velocity from motion
        self.kelvin = 500.0 + (self.kelvin - 500.0) * math.exp(-self.dt / 0.3)

    def run(self, steps: int, on_step: Callable[[Step], None]) -> None:
        for index in range(steps):
            self.step(index)
            on_step(
                Step(
                    index,
                    self.x.astype(np.float32),
                    self.v.astype(np.float32),
                    self.kelvin.astype(np.float32),
                )
            )


def start_local_server() -> tuple[subprocess.Popen[bytes], str]:
    """`sphrender serve` on loopback with ports the OS picks (read from its first line)."""
    sphrender = str(Path(sys.executable).with_name("sphrender"))
    proc = subprocess.Popen(
        [sphrender, "serve", "--port", "0", "--stream-port", "0"], stdout=subprocess.PIPE
    )
    assert proc.stdout is not None
    selector = selectors.DefaultSelector()
    selector.register(proc.stdout, selectors.EVENT_READ)
    if not selector.select(180):
        proc.kill()
        raise SystemExit("the server did not start")
    ready = json.loads(proc.stdout.readline())
    return proc, f"http://127.0.0.1:{ready['http_port']}"


class Viewer:
    """What a frontend does with the answers (on the session's delivery thread)."""

    def __init__(self, out: Path | None) -> None:
        self.out = out
        self.counts = {"image": 0, "error": 0, "dropped": 0}
        self.latency_ms: list[float] = []
        self.sent_at: dict[int, float] = {}
        self.lock = threading.Lock()

    def on_result(self, result: StreamResult) -> None:
        with self.lock:
            self.counts[result.kind] += 1
            sent = self.sent_at.pop(result.id, None)
        if result.kind == "image":
            if sent is not None:
                self.latency_ms.append((time.perf_counter() - sent) * 1e3)
            if self.out is not None:
                (self.out / "latest.png").write_bytes(result.data)
        elif result.kind == "error":
            print(f"frame {result.id}: {result.error}", file=sys.stderr)

    def on_error(self, error: BaseException) -> None:
        print(f"the session ended: {error}", file=sys.stderr)


def orbit(index: int) -> dict[str, Any]:
    """A per-frame scene override: the camera circles the box."""
    angle = 0.6 + index * 0.01
    return {"camera": {"eye": [0.7 * math.sin(angle), 0.45, 0.7 * math.cos(angle)]}}


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--server", help="URL of a running server (default: start one here)")
    parser.add_argument("--steps", type=int, default=240)
    parser.add_argument("--size", default="480x360", help="image WIDTHxHEIGHT")
    parser.add_argument("--out", type=Path, help="write the latest image here as latest.png")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    proc, url = (None, args.server) if args.server else start_local_server()
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    scene = {
        "image": {"width": width, "height": height},
        "camera": {"eye": [0.0, 0.45, 0.7], "target": [0.0, 0.08, 0.0], "fov_y": 40.0},
        "particles": {"radius": RADIUS},
        "material": {"preset": "iron"},
    }
    viewer = Viewer(args.out)
    try:
        with LiveSession(
            Client(url), scene, on_result=viewer.on_result, on_error=viewer.on_error
        ) as live:

            def on_step(step: Step) -> None:  # the simulator's callback
                with viewer.lock:
                    viewer.sent_at[
                        live.submit(
                            step.positions,
                            temperatures=step.temperatures,
                            velocities=step.velocities,
                            scene=orbit(step.index),
                        )
                    ] = time.perf_counter()

            start = time.perf_counter()
            DropSimulator().run(args.steps, on_step)
            simulated = time.perf_counter() - start
        elapsed = time.perf_counter() - start
    finally:
        if proc is not None:
            proc.terminate()
            proc.wait(30)
    latency = sorted(viewer.latency_ms) or [float("nan")]
    print(
        f"{args.steps} steps in {simulated:.1f} s; answers: {viewer.counts}; "
        f"{viewer.counts['image'] / elapsed:.1f} images/s; "
        f"latency p50 {latency[len(latency) // 2]:.0f} ms"
    )


if __name__ == "__main__":
    main()
