"""A frame past the render limit (PROTOCOL.md §4.4 ``render_failed``, §5 timeouts, §9 HTTP
errors) is answered ``render_failed`` naming ``limits.render_timeout_s`` on both transports, and
costs no other frame: the frames the killed renderer held are rendered again by the new one, and
the next request is served as usual. The hang is injected through the test seam
(render_faults.py: ``hang_with_particles``), against a real server with a 2 s render limit."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from render_faults import fault_env
from service_harness import SMALL_SCENE, ServerProcess, ball
from test_service_http import metric_values

from sphrender.core.protocol import MessageType, encode_frame, encode_npz_frame

#: A frame of this many particles hangs in the render step until the watchdog kills the renderer.
HANG = 777
CONFIG: dict[str, dict[str, Any]] = {
    "limits": {"render_timeout_s": 2.0},
    "scheduler": {"encoder_threads": 2},  # up to 5 frames sent ahead into the renderer
}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    env = fault_env(f"hang_with_particles={HANG}")
    with ServerProcess(tmp_path_factory.mktemp("watchdog"), CONFIG, env=env) as server:
        yield server


def restarts(server: ServerProcess, reason: str) -> float:
    values = metric_values(server.metrics_text())
    return values.get(("sphrender_worker_restarts_total", (("reason", reason),)), 0.0)


def render(server: ServerProcess, count: int) -> tuple[int, bytes]:
    body = encode_npz_frame(ball(count), scene=SMALL_SCENE)
    status, _headers, data = server.request(
        "POST", "/v1/render", body, {"Content-Type": "application/x-npz"}, timeout=60
    )
    return status, data


def wait_for_in_flight(server: ServerProcess) -> None:
    deadline = time.monotonic() + 20
    while server.json("GET", "/v1/status")[1]["in_flight"] < 1:
        assert time.monotonic() < deadline, "the frame never reached the renderer"
        time.sleep(0.05)


def test_late_http_frame_is_render_failed_and_another_clients_frames_render(
    server: ServerProcess,
) -> None:
    before = restarts(server, "hung")
    late: list[tuple[int, bytes]] = []
    thread = threading.Thread(target=lambda: late.append(render(server, HANG)))
    with server.stream() as other:
        other.hello(SMALL_SCENE)
        thread.start()
        wait_for_in_flight(server)
        time.sleep(0.3)  # the late frame is in the renderer; these go in behind it
        other.send(b"".join(encode_frame(i, ball(500, seed=i)) for i in range(1, 5)))
        answers = [other.receive() for _ in range(4)]
        thread.join(60)
    # §4.4 / §9: the late frame is 500 render_failed naming the limit, not 503 busy.
    status, data = late[0]
    error = json.loads(data)
    assert (status, error["code"]) == (500, "render_failed"), (status, error)
    assert "limits.render_timeout_s" in error["error"]
    # §4.4: the frames the killed renderer held are rendered again, not failed.
    assert [(k, h["id"]) for k, h, _p in answers] == [(MessageType.IMAGE, i) for i in range(1, 5)]
    # The next request after the restart renders normally.
    assert render(server, 500)[0] == 200
    assert restarts(server, "hung") == before + 1
    restart = [e for e in server.log_events() if e.get("event") == "worker_restart"][-1]
    assert restart["frames_lost"] == 1 and restart["frames_resent"] == 4


def test_late_stream_frame_is_render_failed_and_the_session_goes_on(
    server: ServerProcess,
) -> None:
    before = restarts(server, "hung")
    with server.stream() as client:
        welcome = client.hello(SMALL_SCENE)
        assert welcome["timeouts"]["render_s"] == 2.0  # §4.1: the limit is announced
        client.send(encode_frame(1, ball(500)) + encode_frame(2, ball(HANG)))
        client.send(encode_frame(3, ball(500)))
        answers = [client.receive() for _ in range(3)]
        assert [(k, h["id"]) for k, h, _p in answers] == [
            (MessageType.IMAGE, 1),
            (MessageType.ERROR, 2),
            (MessageType.IMAGE, 3),
        ]
        error = answers[1][1]
        assert (error["code"], error["fatal"]) == ("render_failed", False)
        assert "limits.render_timeout_s" in error["error"]
        client.frame(4, ball(500))  # the same session, on the new renderer
        assert client.receive()[0] == MessageType.IMAGE
    assert restarts(server, "hung") == before + 1


def test_one_off_crash_costs_no_frame_and_a_frame_crashing_twice_fails_alone(
    tmp_path: Path,
) -> None:
    """§4.4: frames held by a renderer that died are sent again; a frame the renderer dies on
    each time it holds it (a second time alone) is answered render_failed, nothing else."""
    env = fault_env("crash_at_frames=1;crash_with_particles=1501")
    with ServerProcess(tmp_path / "server", CONFIG, env=env) as server:
        with server.stream() as client:
            client.hello(SMALL_SCENE)
            frames = [encode_frame(i, ball(1501 if i == 3 else 500)) for i in range(1, 9)]
            client.send(b"".join(frames))
            answers = [client.receive() for _ in range(8)]
        assert [h["id"] for _k, h, _p in answers] == list(range(1, 9))
        failed = [h for k, h, _p in answers if k != MessageType.IMAGE]
        assert [h["id"] for h in failed] == [3]
        assert failed[0]["code"] == "render_failed" and "SIGSEGV" in failed[0]["error"]
        assert 2 <= restarts(server, "crash") <= 3
        assert render(server, 500)[0] == 200


def test_http_frame_still_queued_after_the_limit_is_busy(server: ServerProcess) -> None:
    """§9: a frame that waited in the render queue, not begun, for ``limits.render_timeout_s``
    is answered 503 busy with Retry-After (a separate answer from the render limit's 500)."""
    with server.stream() as client:
        client.hello(SMALL_SCENE)
        # The late frame and 4 behind it fill the renderer (2 x encoder_threads + 1 in flight);
        # after the kill the 4 are re-sent one at a time, so the HTTP frame waits in the queue.
        frames = [encode_frame(1, ball(HANG))]
        frames += [encode_frame(i, ball(500, seed=i)) for i in range(2, 6)]
        client.send(b"".join(frames))
        wait_for_in_flight(server)
        time.sleep(0.3)
        body = encode_npz_frame(ball(500), scene=SMALL_SCENE)
        status, headers, data = server.request(
            "POST", "/v1/render", body, {"Content-Type": "application/x-npz"}, timeout=60
        )
        answers = [client.receive() for _ in range(5)]
    error = json.loads(data)
    assert (status, error["code"]) == (503, "busy"), (status, error)
    assert "render queue" in error["error"] and "limits.render_timeout_s" in error["error"]
    assert int(headers["Retry-After"]) >= 1
    assert [k for k, _h, _p in answers] == [MessageType.ERROR] + [MessageType.IMAGE] * 4
    assert render(server, 500)[0] == 200
