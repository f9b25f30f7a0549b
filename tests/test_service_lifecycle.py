"""Service lifecycle and policy, each on its own real server process: SIGTERM/SIGINT drain, GL
error recovery, token auth, limits on sessions/connections/queue, idle timeouts, bind policy."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from render_faults import fault_env
from service_harness import (
    SMALL_SCENE,
    SPHRENDER,
    ServerProcess,
    StreamClient,
    ball,
    png_pixels,
)
from test_service_http import metric_values

from sphrender.core.protocol import MessageType, encode_frame, encode_message, encode_npz_frame

TOKEN = "s3cret-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def wait_for(condition: Any, timeout: float = 20.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_drains_in_flight_frames_and_exits_0(tmp_path: Path, sig: int) -> None:
    server = ServerProcess(tmp_path / "server")
    scene = {**SMALL_SCENE, "image": {"width": 320, "height": 240}}
    frames = [encode_frame(i, ball(30_000, seed=i)) for i in range(6)]
    body = encode_npz_frame(ball(30_000, seed=99), scene=scene)
    http_result: list[tuple[int, dict[str, str], bytes]] = []
    try:
        client = server.stream()
        client.hello(scene)
        client.send(b"".join(frames))
        http = threading.Thread(
            target=lambda: http_result.append(server.request("POST", "/v1/render", body))
        )
        http.start()

        def everything_received() -> bool:
            values = metric_values(server.metrics_text())
            stream_in = values.get(("sphrender_received_bytes_total", (("transport", "stream"),)))
            http_in = values.get(("sphrender_received_bytes_total", (("transport", "http"),)))
            return (stream_in or 0) >= sum(map(len, frames)) and (http_in or 0) >= len(body)

        wait_for(everything_received, what="the server to read every frame")
        signalled = time.monotonic()
        server.proc.send_signal(sig)
        answers = [client.receive() for _ in frames]
        assert [(k, h["id"]) for k, h, _p in answers] == [(MessageType.IMAGE, i) for i in range(6)]
        kind, header, _payload = client.receive()
        assert (kind, header) == (MessageType.GOODBYE, {"reason": "shutdown"})
        http.join(60)
        assert http_result and http_result[0][0] == 200
        code = server.proc.wait(30)
        assert code == 0, server.logs()
        assert time.monotonic() - signalled < 20
    finally:
        server.stop(signal.SIGKILL)
    events = [e.get("event") for e in server.log_events()]
    assert "drain_start" in events and "stopped" in events


def test_gl_error_answers_that_frame_and_rebuilds_the_context(tmp_path: Path) -> None:
    env = fault_env("gl_error_at_frames=3")
    positions = ball(1500, seed=4)
    with ServerProcess(tmp_path / "server", env=env) as server, server.stream() as client:
        client.hello()
        client.send(b"".join(encode_frame(i, positions) for i in range(1, 6)))
        answers = [client.receive() for _ in range(5)]
        kinds = [k for k, _h, _p in answers]
        assert kinds == [MessageType.IMAGE] * 2 + [MessageType.ERROR] + [MessageType.IMAGE] * 2
        error = answers[2][1]
        assert (error["id"], error["code"], error["fatal"]) == (3, "render_failed", False)
        first = png_pixels(answers[0][2], tmp_path)
        for _kind, _header, payload in answers[3:]:  # after the rebuild: the same pixels
            np.testing.assert_array_equal(png_pixels(payload, tmp_path), first)
        values = metric_values(server.metrics_text())
        assert values[("sphrender_gl_context_rebuilds_total", ())] == 1
        assert server.json("GET", "/readyz") == (200, {"status": "ready"})
        assert "gl_rebuilt" in [e.get("event") for e in server.log_events()]


STRICT_CONFIG: dict[str, dict[str, Any]] = {
    "stream": {"idle_timeout_s": 1.5, "max_connections": 3},
    "limits": {"max_sessions": 3, "session_idle_timeout_s": 1.0},
    "scheduler": {"queue_per_session": 1, "queue_total": 1, "encoder_threads": 1},
}


@pytest.fixture(scope="module")
def strict(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """A server with a token, tiny queues and short idle timeouts."""
    with ServerProcess(
        tmp_path_factory.mktemp("strict"), STRICT_CONFIG, env={"SPHRENDER_TOKEN": TOKEN}
    ) as server:
        yield server


def test_http_token_auth(strict: ServerProcess) -> None:
    assert strict.json("GET", "/healthz")[0] == 200  # probes need no token
    assert strict.json("GET", "/readyz")[0] == 200
    status, headers, body = strict.request("GET", "/v1/info")
    assert status == 401 and headers["WWW-Authenticate"].startswith("Bearer")
    assert json.loads(body)["field"] == "Authorization"
    assert strict.request("GET", "/metrics", headers={"Authorization": "Bearer wrong"})[0] == 401
    assert strict.request("GET", "/metrics", headers={"Authorization": TOKEN})[0] == 401
    assert strict.request("GET", "/v1/info", headers=AUTH)[0] == 200
    frame = encode_npz_frame(ball(100), scene=SMALL_SCENE)
    assert strict.request("POST", "/v1/render", frame)[0] == 401
    assert strict.request("POST", "/v1/render", frame, headers=AUTH)[0] == 200


def test_stream_token_auth(strict: ServerProcess) -> None:
    for token in (None, "wrong", TOKEN[:-1]):
        with strict.stream() as client:
            fields = {} if token is None else {"token": token}
            client.send(encode_message(MessageType.HELLO, {"scene": SMALL_SCENE, **fields}))
            kind, header, _payload = client.receive()
            assert kind == MessageType.ERROR
            assert (header["code"], header["field"], header["fatal"]) == (
                "unauthorized",
                "token",
                True,
            )
            assert client.closed_by_server()
    with strict.stream() as client:
        assert client.hello(token=TOKEN)["session"]


def test_full_queue_answers_503_with_retry_after(strict: ServerProcess) -> None:
    # Frames heavy enough (render, then a 640x480 PNG encode on the single encoder thread) that
    # ten simultaneous requests cannot all fit through a queue of one.
    scene = {**SMALL_SCENE, "image": {"width": 640, "height": 480}}
    body = encode_npz_frame(ball(50_000), scene=scene)
    results: list[tuple[int, dict[str, str], bytes]] = []
    barrier = threading.Barrier(10)

    def post() -> None:
        barrier.wait(30)
        results.append(strict.request("POST", "/v1/render", body, headers=AUTH))

    threads = [threading.Thread(target=post) for _ in range(10)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(120)
    statuses = sorted(status for status, _h, _b in results)
    assert len(statuses) == 10 and set(statuses) <= {200, 503}, statuses
    assert 200 in statuses and 503 in statuses, statuses
    for status, headers, data in results:
        if status == 503:
            assert int(headers["Retry-After"]) >= 1
            assert json.loads(data)["code"] == "busy"


def test_session_limit_and_idle_expiry(strict: ServerProcess) -> None:
    ids = []
    for _ in range(3):
        status, created = strict.json("POST", "/v1/sessions", SMALL_SCENE, headers=AUTH)
        assert status == 201
        ids.append(created["id"])
    status, _headers, body = strict.request(
        "POST", "/v1/sessions", json.dumps(SMALL_SCENE).encode(), headers=AUTH
    )
    assert status == 503 and json.loads(body)["field"] == "session"
    # Unused for session_idle_timeout_s (1 s), they are reaped and the slots come back.
    wait_for(
        lambda: strict.json("GET", f"/v1/sessions/{ids[0]}", headers=AUTH)[0] == 404,
        what="session expiry",
    )
    status, created = strict.json("POST", "/v1/sessions", SMALL_SCENE, headers=AUTH)
    assert status == 201
    assert strict.request("DELETE", f"/v1/sessions/{created['id']}", headers=AUTH)[0] == 204


def test_idle_stream_connection_gets_goodbye(strict: ServerProcess) -> None:
    with strict.stream() as client:
        client.hello(token=TOKEN)
        client.frame(1, ball(100))
        assert client.receive()[0] == MessageType.IMAGE
        start = time.monotonic()
        kind, header, _payload = client.receive()
        assert (kind, header) == (MessageType.GOODBYE, {"reason": "idle_timeout"})
        assert 1.0 < time.monotonic() - start < 10
        assert client.closed_by_server()


def test_stream_connection_limit(strict: ServerProcess) -> None:
    # Connections of earlier tests are released by the server asynchronously: start from none.
    wait_for(
        lambda: "sphrender_stream_connections_open 0" in strict.metrics_text(AUTH),
        what="earlier stream connections to close",
    )
    clients = [StreamClient(strict.stream_port) for _ in range(3)]
    try:
        for client in clients:
            client.hello(token=TOKEN)
        with strict.stream() as extra:
            kind, header, _payload = extra.receive()
            assert (kind, header["code"], header["fatal"]) == (MessageType.ERROR, "busy", True)
    finally:
        for client in clients:
            client.close()


def test_non_loopback_bind_without_token_is_refused(tmp_path: Path) -> None:
    # Refused before any socket is bound.
    result = subprocess.run(
        [SPHRENDER, "serve", "--host", "0.0.0.0", "--port", "0", "--stream-port", "0"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env={"PATH": "/usr/bin:/bin"},
    )
    assert result.returncode == 2, result.stderr
    assert "http.host" in result.stderr and "token" in result.stderr


def test_bad_server_config_is_refused_naming_the_key(tmp_path: Path) -> None:
    config = tmp_path / "server.toml"
    config.write_text("[stream]\nmax_in_flight = 0\n")
    result = subprocess.run(
        [SPHRENDER, "serve", "--config", str(config)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 2
    assert "stream.max_in_flight" in result.stderr


def test_port_in_use_is_a_one_line_error(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = subprocess.run(
            [SPHRENDER, "serve", "--port", str(port), "--stream-port", "0"],
            capture_output=True,
            text=True,
            timeout=120,
            check=False,
        )
    assert result.returncode == 2, result.stderr
    assert "http.port" in result.stderr and "Traceback" not in result.stderr
