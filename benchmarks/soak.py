"""Soak: many small frames of varied sessions through a real server, as a frontend fleet sends them.

    nice -n 10 .venv/bin/python benchmarks/soak.py --frames 10000 --out soak.json

Cycles through stream sessions (HELLO, pipelined frames, BYE, or a client that just hangs up)
and HTTP sessions (POST /v1/sessions, frames, DELETE, or left for the reaper: 20 s here),
with one-shot POST /v1/render frames, /v1/info and /metrics between them. Sessions vary image
size, particle count, radius and output encoding (png, jpeg, exr, raw); frames carry scene
overrides and some are bad input (NaN positions, unknown keys) answered as errors in between.
Checks every answer is the one expected, and reports the resident memory of the service
process and of the renderer process every 1,000 frames, and at frame 1,000 (after warm-up) and
at the end both live and settled (no session left: growth is judged on the settled pair), and
the service's threads and open files at the start and after the last session closed. Bounded by
--frames.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import numpy as np
from service_harness import ServerProcess

from sphrender.core.protocol import (
    MessageType,
    encode_frame,
    encode_message,
    encode_npz_frame,
)

SIZES = ((32, 24), (64, 48), (96, 72), (128, 96), (160, 120))
_PAGE = os.sysconf("SC_PAGE_SIZE")


def rss(pid: int) -> int:
    with open(f"/proc/{pid}/statm") as handle:
        return int(handle.read().split()[1]) * _PAGE


def children(pid: int) -> list[int]:
    found: list[int] = []
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/children") as handle:
                found += [int(c) for c in handle.read().split()]
        except OSError:
            pass
    return found


def counts(pid: int) -> dict[str, int]:
    return {
        "threads": len(os.listdir(f"/proc/{pid}/task")),
        "fds": len(os.listdir(f"/proc/{pid}/fd")),
    }


def memory(pid: int) -> dict[str, int]:
    child = sum(rss(c) for c in children(pid))
    parent = rss(pid)
    return {"service_rss": parent, "renderer_rss": child, "total_rss": parent + child}


FORMATS = ("png", "jpeg", "exr", "raw")
#: Sessions left behind (with their latest image) expire within the warm-up, so the samples after
#: it compare steady states, not a growing number of live sessions.
CONFIG = {"limits": {"session_idle_timeout_s": 20.0}}
#: Seconds to wait before a settled sample: abandoned sessions expire (idle timeout + a reaper
#: period) and both processes trim their heaps (every 5 s).
SETTLE_S = 20.0 + 5.0 + 6.0


def settled(pid: int) -> dict[str, int]:
    """Memory once no session is live: the same state at frame 1,000 and at the end."""
    time.sleep(SETTLE_S)
    return memory(pid)


def scene(rng: random.Random) -> dict[str, Any]:
    width, height = rng.choice(SIZES) if rng.random() < 0.95 else (1280, 720)
    return {
        "image": {"width": width, "height": height},
        "camera": {"eye": [0.6, 0.5, 0.9], "target": [0.0, 0.0, 0.0], "fov_y": 40.0},
        "particles": {"radius": rng.choice((0.015, 0.02, 0.03))},
        "output": {"format": rng.choice(FORMATS)},
    }


def override(rng: random.Random) -> dict[str, Any] | None:
    """A per-frame scene change (camera or radius), a bad key, or nothing."""
    draw = rng.random()
    if draw < 0.2:
        return {"camera": {"eye": [rng.uniform(0.4, 0.9), 0.5, 0.9]}}
    if draw < 0.3:
        return {"particles": {"radius": rng.choice((0.01, 0.025))}}
    if draw < 0.35:
        return {"camera": {"no_such_key": 1}}
    return None


def positions(rng: random.Random) -> np.ndarray:
    n = rng.choice((50, 200, 800, 2000)) if rng.random() < 0.98 else 100_000
    points = np.random.default_rng(rng.randrange(1 << 30)).normal(size=(n, 3)) * 0.15
    if rng.random() < 0.05:
        points[rng.randrange(n)] = np.nan
    return points


def _good(points: np.ndarray, changes: dict[str, Any] | None) -> bool:
    return bool(np.isfinite(points).all()) and "no_such_key" not in json.dumps(changes or {})


def stream_session(server: ServerProcess, rng: random.Random, burst: int) -> int:
    """One stream session; returns how many answers were not the expected kind."""
    wrong = 0
    with server.stream() as client:
        client.hello(scene(rng))
        for start in range(0, burst, 8):
            batch = range(start, min(burst, start + 8))
            frames = [(positions(rng), override(rng)) for _ in batch]
            client.send(
                b"".join(
                    encode_frame(i, points, scene=changes)
                    for i, (points, changes) in zip(batch, frames, strict=True)
                )
            )
            for points, changes in frames:
                kind, _header, _payload = client.receive()
                expected = MessageType.IMAGE if _good(points, changes) else MessageType.ERROR
                wrong += kind != expected
        if rng.random() < 0.8:
            client.send(encode_message(MessageType.BYE, {}))
            client.receive()
    return wrong


def http_session(server: ServerProcess, rng: random.Random, burst: int) -> int:
    """One HTTP session (or one-shot renders); returns how many answers were unexpected."""
    wrong = 0
    one_shot = rng.random() < 0.3
    chosen = scene(rng)
    if not one_shot:
        status, body = server.json("POST", "/v1/sessions", chosen)
        assert status == 201, body
    for _ in range(burst):
        points, changes = positions(rng), override(rng)
        expected = 200 if _good(points, changes) else 400
        if one_shot:
            frame_scene = {**chosen, **(changes or {})}
            payload = encode_npz_frame(points, scene=frame_scene)
            status = server.request("POST", "/v1/render", payload)[0]
        else:
            payload = encode_npz_frame(points, scene=changes)
            status = server.request("POST", f"/v1/sessions/{body['id']}/frames", payload)[0]
        wrong += status != expected
    if not one_shot and rng.random() < 0.8:
        server.request("DELETE", f"/v1/sessions/{body['id']}")
    server.request("GET", rng.choice(("/v1/info", "/metrics", "/healthz")))
    return wrong


def soak(frames: int, seed: int) -> dict[str, Any]:
    rng = random.Random(seed)
    done = 0
    samples: dict[str, Any] = {}
    trend: list[dict[str, int]] = []  # every 1,000 frames: growing or levelled off?
    errors = 0
    sessions = 0
    with tempfile.TemporaryDirectory() as tmp, ServerProcess(Path(tmp), CONFIG) as server:
        pid = server.proc.pid
        time.sleep(0.5)
        samples["start"] = {**counts(pid), **memory(pid)}
        started = time.monotonic()
        while done < frames:
            burst = min(frames - done, rng.randrange(5, 60))
            sessions += 1
            if rng.random() < 0.6:
                errors += stream_session(server, rng, burst)
            else:
                errors += http_session(server, rng, burst)
            before = done
            done += burst
            if before < 1000 <= done:
                samples["frame_1000"] = memory(pid)
                samples["frame_1000_settled"] = settled(pid)
            if before // 1000 < done // 1000:
                trend.append({"frames": done, **memory(pid)})
        elapsed = time.monotonic() - started - SETTLE_S
        samples["end"] = memory(pid)
        samples["end_settled"] = {**counts(pid), **settled(pid)}
    first, last = samples["frame_1000_settled"], samples["end_settled"]
    return {
        "frames": done,
        "sessions": sessions,
        "errors": errors,
        "seconds": round(elapsed, 1),
        "fps": round(done / elapsed, 1),
        "samples": samples,
        "trend_mib": [
            {k: v if k == "frames" else round(v / 2**20, 1) for k, v in row.items()}
            for row in trend
        ],
        "rss_growth_from_frame_1000_pct": {
            key: round(100.0 * (last[key] - first[key]) / first[key], 2)
            for key in ("service_rss", "renderer_rss", "total_rss")
        },
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    report = soak(max(args.frames, 1001), args.seed)
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 1 if report["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
