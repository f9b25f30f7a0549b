"""Two real `sphrender serve` replicas behind a real HAProxy (Debian's `haproxy`), configured
from `deploy/haproxy/haproxy.cfg.template` by `deploy/haproxy/render_config.py`, all on
loopback. HAProxy's listening sockets are made here (port 0) and inherited (``bind fd@N``), so
no port is guessed. HTTP and stream clients send frames through it while one replica gets
SIGTERM mid-run: HTTP requests still succeed (HAProxy's and the client's retries), the stream
client reconnects to the other replica and resends what was not answered, and every frame is
answered exactly once, with the image of that frame."""

from __future__ import annotations

import csv
import importlib.util
import io
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from service_harness import HOST, SMALL_SCENE, ServerProcess, StreamClient, ball, reference_png

from sphrender.client.api import Client
from sphrender.core.protocol import MessageType, encode_npz_frame
from sphrender.server.engine.renderer import SurfaceRenderer

REPO = Path(__file__).resolve().parents[1]
HAPROXY = shutil.which("haproxy")
#: A missing HAProxy fails the tests (never skips them): it is one of the README's test packages.
NO_HAPROXY = "haproxy not found: install the packages in deploy/apt/tests.txt (see the README)"

#: Health checks every 200 ms, one failure takes a replica out: the grace must be longer.
CHECK_INTERVAL_MS = 200
REPLICA_CONFIG: dict[str, dict[str, Any]] = {
    "lifecycle": {"drain_grace_s": 1.0, "drain_timeout_s": 20.0},
    "stream": {"max_in_flight": 8},
}
STREAM_FRAMES = 80
HTTP_CLIENTS = 2
HTTP_FRAMES = 25


def load_render_config() -> ModuleType:
    path = REPO / "deploy" / "haproxy" / "render_config.py"
    spec = importlib.util.spec_from_file_location("render_config", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["render_config"] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


class HaproxyProcess:
    """HAProxy in the foreground with inherited listening sockets and a stats socket."""

    def __init__(self, tmp_dir: Path, replicas: list[ServerProcess]) -> None:
        render_config = load_render_config()
        self.listeners = []
        for _ in range(2):
            listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            listener.bind((HOST, 0))
            listener.listen(128)
            self.listeners.append(listener)
        self.http_port, self.stream_port = (s.getsockname()[1] for s in self.listeners)
        self.stats_path = tmp_dir / "haproxy.sock"
        config = render_config.render(
            [
                render_config.Replica(f"r{i}", HOST, r.http_port, r.stream_port)
                for i, r in enumerate(replicas)
            ],
            http_bind=f"fd@{self.listeners[0].fileno()}",
            stream_bind=f"fd@{self.listeners[1].fileno()}",
            check_interval_ms=CHECK_INTERVAL_MS,
            fall=1,
            rise=1,
            global_extra=[f"stats socket {self.stats_path} mode 600 level admin"],
        )
        self.config_path = tmp_dir / "haproxy.cfg"
        self.config_path.write_text(config)
        self.log_path = tmp_dir / "haproxy.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        assert HAPROXY is not None, NO_HAPROXY
        self.proc = subprocess.Popen(
            [HAPROXY, "-db", "-f", str(self.config_path)],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            pass_fds=[s.fileno() for s in self.listeners],
        )

    def server_states(self) -> dict[tuple[str, str], str]:
        """(backend, server) -> status ("UP", "DOWN", ...), from `show stat`."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(5)
            sock.connect(str(self.stats_path))
            sock.sendall(b"show stat\n")
            data = b""
            while chunk := sock.recv(65536):
                data += chunk
        rows = csv.DictReader(io.StringIO(data.decode().lstrip("# ")))
        return {
            (row["pxname"], row["svname"]): row["status"]
            for row in rows
            if row.get("svname") not in ("FRONTEND", "BACKEND", None)
        }

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        for listener in self.listeners:
            listener.close()
        self._log.close()


def wait_for(condition: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[tuple[list[ServerProcess], HaproxyProcess]]:
    assert HAPROXY is not None, NO_HAPROXY
    replicas: list[ServerProcess] = []
    proxy: HaproxyProcess | None = None
    try:
        for name in ("a", "b"):
            replicas.append(ServerProcess(tmp_path / name, REPLICA_CONFIG))
        proxy = HaproxyProcess(tmp_path, replicas)

        def all_up() -> bool:
            try:
                states = proxy.server_states()
            except OSError:
                return False
            return len(states) == 4 and set(states.values()) == {"UP"}

        wait_for(all_up, 30, "HAProxy to see both replicas up")
        yield replicas, proxy
    finally:
        if proxy is not None:
            proxy.stop()
        for replica in replicas:
            replica.stop(signal.SIGKILL)


class ReconnectingStream:
    """A frontend's stream client: frames paced every `interval`, at most 4 in flight; on
    GOODBYE or a closed connection it reconnects through the balancer and resends every frame
    not yet answered. Fails on any answer that is not an image, or a frame answered twice."""

    def __init__(self, port: int, frames: dict[int, np.ndarray], interval: float) -> None:
        self.port = port
        self.frames = frames
        self.interval = interval
        self.answers: dict[int, bytes] = {}
        self.sessions: list[str] = []
        self.goodbyes: list[str] = []
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            pending = deque(sorted(self.frames))
            while pending:
                in_flight = self._connection(pending)
                pending = deque(sorted({*in_flight, *pending}))
        except BaseException as exc:
            self.error = exc

    def _connection(self, pending: deque[int]) -> list[int]:
        in_flight: deque[int] = deque()
        with StreamClient(self.port, timeout=30) as client:
            self.sessions.append(client.hello(SMALL_SCENE, max_in_flight=4)["session"])
            try:
                while pending or in_flight:
                    while pending and len(in_flight) < 4:
                        frame_id = pending.popleft()
                        in_flight.append(frame_id)  # before sending: a send may fail
                        client.frame(frame_id, self.frames[frame_id])
                        time.sleep(self.interval)
                    kind, header, payload = client.receive()
                    if kind == MessageType.GOODBYE:
                        self.goodbyes.append(str(header.get("reason")))
                        break
                    assert kind == MessageType.IMAGE, (kind, header)
                    frame_id = int(header["id"])
                    assert frame_id == in_flight.popleft(), "answers out of order"
                    assert frame_id not in self.answers, f"frame {frame_id} answered twice"
                    self.answers[frame_id] = payload
            except (EOFError, ConnectionError):
                self.goodbyes.append("closed")
        return list(in_flight)


def http_client(
    url: str, frames: dict[int, np.ndarray], answers: dict[int, bytes], errors: list[str]
) -> None:
    client = Client(url, retries=10, backoff_s=0.1, timeout=30)
    for frame_id, positions in frames.items():
        try:
            answers[frame_id] = client.render(positions, SMALL_SCENE)
        except Exception as exc:
            errors.append(f"frame {frame_id}: {exc!r}")
        time.sleep(0.08)


def test_sigterm_one_replica_mid_run_no_frame_fails_or_repeats(
    cluster: tuple[list[ServerProcess], HaproxyProcess], renderer: SurfaceRenderer
) -> None:
    replicas, proxy = cluster
    stream_frames = {i: ball(2000, seed=i) for i in range(STREAM_FRAMES)}
    http_frames = [
        {1000 * (c + 1) + i: ball(2000, seed=1000 * (c + 1) + i) for i in range(HTTP_FRAMES)}
        for c in range(HTTP_CLIENTS)
    ]
    stream = ReconnectingStream(proxy.stream_port, stream_frames, interval=0.05)
    http_answers: dict[int, bytes] = {}
    http_errors: list[str] = []
    threads = [threading.Thread(target=stream.run)] + [
        threading.Thread(
            target=http_client,
            args=(f"http://{HOST}:{proxy.http_port}", frames, http_answers, http_errors),
        )
        for frames in http_frames
    ]
    for thread in threads:
        thread.start()
    try:
        wait_for(lambda: len(stream.answers) >= 8 and len(http_answers) >= 4, 60, "traffic")
        # stop the replica the stream session is on, so the stream client must move
        session = stream.sessions[0]
        (victim,) = [
            r
            for r in replicas
            if any(
                e.get("event") == "session_open" and e.get("id") == session for e in r.log_events()
            )
        ]
        survivor = next(r for r in replicas if r is not victim)
        victim.proc.send_signal(signal.SIGTERM)
        stopped_at = (len(stream.answers), len(http_answers))
    finally:
        for thread in threads:
            thread.join(120)
    assert victim.proc.wait(30) == 0, victim.logs()
    assert stream.error is None, repr(stream.error)
    assert not http_errors, http_errors
    assert stopped_at[0] < STREAM_FRAMES and stopped_at[1] < HTTP_CLIENTS * HTTP_FRAMES

    # every frame answered exactly once (checked as they came), with its own image
    assert sorted(stream.answers) == sorted(stream_frames)
    assert sorted(http_answers) == sorted(k for frames in http_frames for k in frames)
    for frame_id, positions in [
        *stream_frames.items(),
        *(i for f in http_frames for i in f.items()),
    ]:
        answer = stream.answers.get(frame_id) or http_answers[frame_id]
        assert answer == reference_png(renderer, positions, SMALL_SCENE), frame_id

    # the stream moved: GOODBYE shutdown from the victim, the last session on the survivor
    assert "shutdown" in stream.goodbyes, stream.goodbyes
    assert len(stream.sessions) >= 2
    assert any(
        e.get("event") == "session_open" and e.get("id") == stream.sessions[-1]
        for e in survivor.log_events()
    )
    events = [e.get("event") for e in victim.log_events()]
    assert events.index("drain_grace") < events.index("drain_start") < events.index("stopped")
    # HAProxy took the victim out of both backends
    wait_for(
        lambda: sorted(proxy.server_states().values()) == ["DOWN", "DOWN", "UP", "UP"],
        10,
        "HAProxy to mark the stopped replica down",
    )


def test_drain_grace_not_ready_but_still_serving(tmp_path: Path) -> None:
    """With drain_grace_s, SIGTERM first turns /readyz 503 "draining" while frames are still
    rendered (what lets a balancer take the replica out before its listeners close)."""
    with ServerProcess(tmp_path, {"lifecycle": {"drain_grace_s": 3.0}}) as server:
        assert server.json("GET", "/readyz") == (200, {"status": "ready"})
        server.proc.send_signal(signal.SIGTERM)
        wait_for(lambda: server.json("GET", "/readyz")[0] == 503, 2, "/readyz 503")
        assert server.json("GET", "/readyz") == (503, {"status": "draining"})
        body = encode_npz_frame(ball(2000), scene=SMALL_SCENE)
        status, _headers, _png = server.request("POST", "/v1/render", body)
        assert status == 200
        assert server.proc.wait(30) == 0
