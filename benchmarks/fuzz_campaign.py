"""The hostile-network campaign against a real `sphrender serve` on loopback.

    nice -n 10 .venv/bin/python benchmarks/fuzz_campaign.py --seconds 300 --seed 1 --out run1.json

Starts a server with the default settings (ephemeral ports), then runs side by side:

* a **well-behaved client** streaming one fixed frame and, every 10th frame, rendering it over
  HTTP: every answer must be an IMAGE (200) whose bytes equal the first one's;
* stream **frame-level** fuzzers (pipelined batches on long-lived connections) and a
  **connection-level** fuzzer (one connection per input), from `tests/fuzz_inputs.py`;
* an **HTTP** fuzzer on keep-alive connections.

With ``--websocket`` the same campaign runs on the WebSocket transport instead (``GET
/v1/stream``, PROTOCOL.md §10; a server with a token, ``stream.max_payload_bytes`` of 1 MiB and
``stream.message_timeout_s`` of 3 s):
the well-behaved client streams over a WebSocket, 2 frame-level fuzzers send fragmented
FRAMEs with pings between fragments, and 2 connection-level fuzzers send
`tests/fuzz_ws_inputs.py`'s inputs (bad origin and token, bad upgrades, garbage, unmasked,
reserved bits, bad opcodes and control frames, text, oversized, random bytes, stream garbage in
binary messages), each of which must end in a JSON error or a documented Close code with a
clear reason.

At the end: the server must still be alive and answer /healthz, the renderer must never have
been restarted (``sphrender_worker_restarts_total``), and the server's threads and open files
must be back near their start. Every error text of every answer is checked
(`fuzz_inputs.text_faults`: no Python repr, module path or library message; PROTOCOL.md 1), and
every line the server (``--log-json``) wrote to stderr must be a JSON object. Prints and writes
a JSON report: inputs (stream, HTTP), rate, crashes, hangs, 5xx for client errors, bad error
texts, non-JSON stderr lines, the good client's frames and mismatches. Bounded: it stops by
itself after ``--seconds``. Run the million in chunks with different seeds.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import numpy as np
from fuzz_inputs import (
    SCENE,
    HttpConn,
    Tally,
    run_connection_input,
    run_frame_batch,
    run_http_input,
    stream_hello,
)
from fuzz_ws_inputs import run_ws_connection_input, run_ws_frame_batch, ws_hello
from service_harness import ServerProcess

from sphrender.core.protocol import encode_frame, encode_npz_frame


def proc_counts(pid: int) -> tuple[int, int]:
    return len(os.listdir(f"/proc/{pid}/task")), len(os.listdir(f"/proc/{pid}/fd"))


def good_client(port: int, http_port: int, stop: threading.Event, result: dict[str, Any]) -> None:
    positions = np.random.default_rng(7).normal(size=(400, 3)) * 0.15
    frame = encode_frame(0, positions)
    body = encode_npz_frame(positions, scene=SCENE)
    http = HttpConn(http_port, timeout=30)
    request = (
        f"POST /v1/render HTTP/1.1\r\nHost: x\r\nContent-Length: {len(body)}\r\n\r\n".encode()
        + body
    )
    reference: bytes | None = None
    conn = stream_hello(port)
    conn.sock.settimeout(30)
    while not stop.is_set():
        conn.sock.sendall(frame)
        kind, header, payload = conn.receive()
        result["frames"] += 1
        if kind != 0x82:
            result["errors"] += 1
            result.setdefault("notes", []).append(header)
            continue
        reference = reference or payload
        if payload != reference:
            result["mismatches"] += 1
        if result["frames"] % 10 == 0:
            status, _keep = http.request(request)
            result["http_frames"] += 1
            if status != 200:
                result["http_errors"] += 1
    conn.close()


def fuzz_frames(port: int, seed: int, stop: threading.Event, tally: Tally) -> None:
    rng = random.Random(seed)
    conn = stream_hello(port)
    next_id = 1
    while not stop.is_set():
        try:
            run_frame_batch(conn, rng, next_id, 8, tally)
            next_id += 8
        except (EOFError, TimeoutError, ConnectionError, OSError):
            conn.close()
            conn = stream_hello(port)
    conn.close()


def fuzz_connections(port: int, seed: int, stop: threading.Event, tally: Tally) -> None:
    rng = random.Random(seed)
    while not stop.is_set():
        try:
            run_connection_input(port, rng, tally)
        except (ConnectionError, OSError, AssertionError) as exc:
            tally.note(f"connection fuzzer: {exc!r}")


def fuzz_http(port: int, seed: int, stop: threading.Event, tally: Tally) -> None:
    rng = random.Random(seed)
    http = HttpConn(port)
    while not stop.is_set():
        run_http_input(http, rng, tally)
    http.close()


WS_TOKEN = "fuzz-campaign-token-0123456789"
#: A message that has begun must end within 3 s here (30 s by default), below the fuzzers' 8 s
#: wait for a Close: random bytes often form a frame header announcing more than follows.
WS_CONFIG = {
    "security": {"token": WS_TOKEN},
    "stream": {"max_payload_bytes": 1 << 20, "message_timeout_s": 3.0},
}
WS_MAX_MESSAGE = 16 + 65536 + (1 << 20)


def good_ws_client(http_port: int, stop: threading.Event, result: dict[str, Any]) -> None:
    frame = encode_frame(0, np.random.default_rng(7).normal(size=(400, 3)) * 0.15)
    reference: bytes | None = None
    ws = ws_hello(http_port, WS_TOKEN, random.Random(3), timeout=30)
    while not stop.is_set():
        ws.send_message(frame)
        answer = ws.receive()
        result["frames"] += 1
        if answer[0] != 0x82:
            result["errors"] += 1
            result.setdefault("notes", []).append(str(answer)[:200])
            continue
        reference = reference or answer[2]
        result["mismatches"] += answer[2] != reference
    ws.close()


def fuzz_ws_frames(port: int, seed: int, stop: threading.Event, tally: Tally) -> None:
    rng = random.Random(seed)
    ws = ws_hello(port, WS_TOKEN, rng)
    next_id = 1
    while not stop.is_set():
        try:
            run_ws_frame_batch(ws, rng, next_id, 8, tally)
            next_id += 8
        except (EOFError, TimeoutError, ConnectionError, OSError):
            ws.close()
            ws = ws_hello(port, WS_TOKEN, rng)
    ws.close()


def fuzz_ws_connections(port: int, seed: int, stop: threading.Event, tally: Tally) -> None:
    rng = random.Random(seed)
    while not stop.is_set():
        try:
            run_ws_connection_input(port, WS_TOKEN, rng, tally, WS_MAX_MESSAGE)
        except (ConnectionError, OSError, AssertionError) as exc:
            tally.note(f"ws connection fuzzer: {exc!r}")


def worker_threads(
    server: ServerProcess,
    seed: int,
    stop: threading.Event,
    tally: Tally,
    good: dict[str, Any],
    websocket: bool,
    frame_workers: int,
    http_workers: int,
) -> list[threading.Thread]:
    """The campaign's clients (module docstring), on the stream port or the WebSocket."""
    calls: list[tuple[Any, tuple[Any, ...]]] = []
    if websocket:
        calls.append((good_ws_client, (server.http_port, stop, good)))
        for i in range(frame_workers):
            calls.append((fuzz_ws_frames, (server.http_port, seed * 100 + i, stop, tally)))
        for i in range(2):
            calls.append(
                (fuzz_ws_connections, (server.http_port, seed * 100 + 50 + i, stop, tally))
            )
    else:
        calls.append((good_client, (server.stream_port, server.http_port, stop, good)))
        for i in range(frame_workers):
            calls.append((fuzz_frames, (server.stream_port, seed * 100 + i, stop, tally)))
        calls.append((fuzz_connections, (server.stream_port, seed * 100 + 50, stop, tally)))
        for i in range(http_workers):
            calls.append((fuzz_http, (server.http_port, seed * 100 + 70 + i, stop, tally)))
    return [threading.Thread(target=target, args=args, daemon=True) for target, args in calls]


def non_json_lines(text: str) -> int:
    """Lines of a log that are not one JSON object each."""
    count = 0
    for line in text.splitlines():
        try:
            count += not isinstance(json.loads(line), dict)
        except ValueError:
            count += 1
    return count


def campaign(
    seconds: float,
    seed: int,
    frame_workers: int = 2,
    http_workers: int = 2,
    websocket: bool = False,
) -> dict[str, Any]:
    tally = Tally()
    good: dict[str, Any] = {"frames": 0, "errors": 0, "mismatches": 0, "http_frames": 0}
    good["http_errors"] = 0
    with tempfile.TemporaryDirectory() as tmp:
        env = {"PYTHONFAULTHANDLER": "1"}
        config = WS_CONFIG if websocket else {}
        with ServerProcess(Path(tmp), config, env=env) as server:
            pid = server.proc.pid
            time.sleep(0.5)
            start_counts = proc_counts(pid)
            stop = threading.Event()
            threads = worker_threads(
                server, seed, stop, tally, good, websocket, frame_workers, http_workers
            )
            started = time.monotonic()
            for thread in threads:
                thread.start()
            stop.wait(seconds)
            stop.set()
            for thread in threads:
                thread.join(60)
            elapsed = time.monotonic() - started
            alive = server.proc.poll() is None
            health = server.json("GET", "/healthz", timeout=10)[0] if alive else 0
            auth = {"Authorization": f"Bearer {WS_TOKEN}"} if websocket else None
            metrics = server.metrics_text(auth) if alive else ""
            restarts = sum(
                float(line.rsplit(" ", 1)[1])
                for line in metrics.splitlines()
                if line.startswith("sphrender_worker_restarts_total{")
            )
            time.sleep(2.0)  # connections wind down
            end_counts = proc_counts(pid) if alive else (0, 0)
            log_text = server.logs()
    return {
        "transport": "websocket" if websocket else "stream+http",
        "seed": seed,
        "seconds": round(elapsed, 1),
        "inputs": tally.inputs,
        "stream_inputs": tally.stream_inputs,
        "http_inputs": tally.http_inputs,
        "rate_per_s": round(tally.inputs / elapsed, 1),
        "crashes": (0 if alive else 1) + int(restarts),
        "segfault_in_log": "Segmentation fault" in log_text,
        "decode_bugs_logged": log_text.count('"decode_bug"'),
        "internal_errors_logged": log_text.count('"stream_bug"') + log_text.count('"worker_bug"'),
        "hangs": tally.hangs,
        "server_errors_5xx": tally.server_errors,
        "busy_503": tally.busy,
        "error_texts": tally.texts,
        "bad_texts": tally.bad_texts,
        "stderr_non_json_lines": non_json_lines(log_text),
        "fuzz_images": tally.images,
        "healthz_after": health,
        "threads_start_end": [start_counts[0], end_counts[0]],
        "fds_start_end": [start_counts[1], end_counts[1]],
        "good_client": good,
        "notes": tally.notes[:20],
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--websocket", action="store_true", help="fuzz GET /v1/stream instead")
    args = parser.parse_args()
    report = campaign(args.seconds, args.seed, websocket=args.websocket)
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    bad = report["crashes"] or report["hangs"] or report["server_errors_5xx"]
    bad = bad or report["bad_texts"] or report["stderr_non_json_lines"]
    good = report["good_client"]
    return 1 if bad or good["errors"] or good["mismatches"] or good["http_errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
