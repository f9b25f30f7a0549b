"""`LiveSession` (client/live.py) against a real `sphrender serve` on loopback: submits from
several threads, results by callback and by poll, latest-frame-wins, close with frames in flight,
errors of one frame and of the whole session. Each test checks the session's promise: every
accepted frame gets exactly one result."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from service_harness import SMALL_SCENE, ServerProcess, ball, png_pixels, reference_png

from sphrender.client.api import Client, StreamResult
from sphrender.client.live import LiveSession, SessionClosed, SessionEnded
from sphrender.core.errors import InputError
from sphrender.server.engine.renderer import SurfaceRenderer

WAIT_S = 120.0


def client_of(server: ServerProcess) -> Client:
    return Client(f"http://127.0.0.1:{server.http_port}", timeout=WAIT_S)


class Collector:
    """`on_result` / `on_error` that remember what they got, and on which thread."""

    def __init__(self) -> None:
        self.results: list[StreamResult] = []
        self.errors: list[BaseException] = []
        self.threads: set[str] = set()
        self.lock = threading.Lock()
        self.ended = threading.Event()

    def on_result(self, result: StreamResult) -> None:
        with self.lock:
            self.results.append(result)
            self.threads.add(threading.current_thread().name)

    def on_error(self, error: BaseException) -> None:
        with self.lock:
            self.errors.append(error)
        self.ended.set()

    def by_id(self) -> dict[int, StreamResult]:
        ids = [r.id for r in self.results]
        assert len(ids) == len(set(ids)), f"a frame was answered twice: {sorted(ids)}"
        return {r.id: r for r in self.results}


def test_threads_submit_concurrently_and_each_frame_is_answered_once_in_order(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    collected = Collector()
    sizes: dict[int, int] = {}
    sizes_lock = threading.Lock()
    live = LiveSession(  # raw arrays: the image is compared with an in-process render
        client_of(service), SMALL_SCENE, on_result=collected.on_result, mode="queue", compact=False
    )

    def producer(k: int) -> None:
        for step in range(4):
            count = 300 + 40 * k + step  # each frame's own particle count identifies its answer
            frame_id = live.submit(ball(count, seed=k))
            with sizes_lock:
                sizes[frame_id] = count

    with live:
        threads = [threading.Thread(target=producer, args=(k,)) for k in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        assert live.drain(WAIT_S)
        assert live.in_flight == 0 and live.pending == 0
        assert len(collected.results) == len(sizes)  # drained: every result handed over
        check_id = live.submit(ball(2000))  # one frame checked against the engine in-process
        assert live.drain(WAIT_S)
    results = collected.by_id()
    assert sorted(results) == sorted([*sizes, check_id])
    assert all(r.kind == "image" for r in results.values())
    assert [r.id for r in collected.results] == sorted(results)  # in the order of the ids
    for frame_id, count in sizes.items():
        assert results[frame_id].header["particles"] == count
    assert collected.threads == {"sphrender-live-deliver"}
    expected = png_pixels(reference_png(renderer, ball(2000), SMALL_SCENE), tmp_path)
    got = png_pixels(results[check_id].data, tmp_path)
    assert np.array_equal(got, expected)  # the same engine and inputs: the same bytes of image


def test_a_fast_producer_sees_its_newest_frame_rendered_and_the_rest_dropped(
    service: ServerProcess,
) -> None:
    collected = Collector()
    with LiveSession(client_of(service), SMALL_SCENE, on_result=collected.on_result) as live:
        assert live.max_in_flight == 2
        positions = ball(3000)
        accepted = []
        for step in range(40):  # a simulator's step callback, far faster than the renderer
            positions[:, 1] -= 0.001  # moved in place: submit must have copied the last one
            accepted.append(live.submit(positions, temperatures=np.full(3000, 1800.0 + step)))
            assert live.in_flight <= live.max_in_flight and live.pending <= 1
        last = accepted[-1]
    results = collected.by_id()
    assert sorted(results) == accepted
    kinds = {r.kind for r in results.values()}
    assert kinds <= {"image", "dropped"} and "dropped" in kinds
    assert results[last].kind == "image"  # latest wins: the newest frame is always rendered
    dropped = [r for r in results.values() if r.kind == "dropped"]
    assert {r.header["reason"] for r in dropped} == {"superseded"}
    assert any(r.header["local"] for r in dropped)  # superseded while waiting in the client


def test_poll_is_non_blocking_and_returns_every_result(service: ServerProcess) -> None:
    with LiveSession(client_of(service), SMALL_SCENE, mode="queue") as live:
        assert live.poll() is None  # nothing submitted: answers at once
        ids = [live.submit(ball(500, seed=k)) for k in range(3)]
        got: list[StreamResult] = []
        while len(got) < 3:
            result = live.poll(timeout=WAIT_S)
            assert result is not None
            got.append(result)
        assert [r.id for r in got] == ids and all(r.kind == "image" for r in got)
        assert live.poll() is None
    assert live.poll() is None


def test_close_answers_frames_in_flight_and_then_refuses_frames(service: ServerProcess) -> None:
    collected = Collector()
    live = LiveSession(
        client_of(service),
        SMALL_SCENE,
        on_result=collected.on_result,
        mode="queue",
        max_in_flight=2,
    )
    ids = [live.submit(ball(1500, seed=k)) for k in range(5)]
    live.close()  # sends what was accepted and waits for the answers
    results = collected.by_id()
    assert sorted(results) == ids and all(r.kind == "image" for r in results.values())
    with pytest.raises(SessionClosed):
        live.submit(ball(10))
    live.close()  # idempotent


def test_close_that_stops_waiting_reports_the_rest_closed(service: ServerProcess) -> None:
    collected = Collector()
    live = LiveSession(
        client_of(service),
        SMALL_SCENE,
        on_result=collected.on_result,
        mode="queue",
        max_in_flight=1,
    )
    ids = [live.submit(ball(4000, seed=k)) for k in range(4)]
    live.close(timeout=0.0)
    results = collected.by_id()
    assert sorted(results) == ids
    for result in results.values():
        assert result.kind == "image" or (
            result.kind == "dropped" and result.header["reason"] == "closed"
        ), result.header
    assert any(r.kind == "dropped" for r in results.values())


def test_an_error_answer_reaches_the_callback_and_the_session_goes_on(
    service: ServerProcess,
) -> None:
    collected = Collector()
    with LiveSession(
        client_of(service),
        SMALL_SCENE,
        on_result=collected.on_result,
        on_error=collected.on_error,
        mode="queue",
    ) as live:
        bad = live.submit(ball(500), scene={"image": {"width": -5}})
        good = live.submit(ball(500), scene={"camera": {"eye": [0.0, 0.2, 1.2]}})
        assert live.drain(WAIT_S)
        with pytest.raises(InputError):
            live.poll()  # results go to the callback; poll is for sessions without one
    results = collected.by_id()
    assert results[bad].kind == "error"
    error = results[bad].error
    assert error is not None and error.code == "bad_input" and error.field == "image.width"
    assert results[good].kind == "image"
    assert collected.errors == []  # one frame's error is not the session's


def test_bad_input_is_refused_by_submit_with_the_field(service: ServerProcess) -> None:
    with LiveSession(client_of(service), SMALL_SCENE) as live:
        positions = ball(100)
        positions[7, 2] = np.nan
        with pytest.raises(InputError) as info:
            live.submit(positions)
        assert info.value.field == "positions[7]"
        with pytest.raises(InputError) as info:
            live.submit(ball(100), scene={"camera": {"fov_y": float("nan")}})
        assert info.value.field == "scene"
        with pytest.raises(InputError) as info:  # every frame array is checked, solid included
            live.submit(ball(100), solid=np.full(100, 2, np.uint8))
        assert info.value.field.startswith("solid")


def session_ends(tmp_path: Path) -> tuple[list[BaseException], dict[int, StreamResult], list[Any]]:
    """A server that ends an idle session, then dies with frames in flight."""
    config = {"stream": {"idle_timeout_s": 1.0}, "limits": {"max_pixels": 320 * 240}}
    with ServerProcess(tmp_path, config) as server:
        idle = Collector()
        live = LiveSession(client_of(server), SMALL_SCENE, on_error=idle.on_error)
        assert idle.ended.wait(WAIT_S)
        assert live.poll() is None  # no on_result: results (none here) come by poll
        with pytest.raises(SessionClosed):
            live.submit(ball(10))
        live.close()
        dying = Collector()
        scene = {**SMALL_SCENE, "image": {"width": 320, "height": 240}}
        live = LiveSession(
            client_of(server),
            scene,
            on_result=dying.on_result,
            on_error=dying.on_error,
            mode="queue",
        )
        accepted = [live.submit(ball(20000, seed=k)) for k in range(6)]
        server.proc.send_signal(signal.SIGKILL)
        server.proc.wait(30)
        live.close(timeout=WAIT_S)
    return idle.errors + dying.errors, dying.by_id(), accepted


def test_session_errors_reach_on_error_and_lost_frames_are_reported(tmp_path: Path) -> None:
    errors, results, accepted = session_ends(tmp_path)
    assert isinstance(errors[0], SessionEnded) and errors[0].reason == "idle_timeout"
    assert len(errors) == 2 and isinstance(errors[1], ConnectionError)
    assert sorted(results) == accepted
    lost = [r for r in results.values() if r.kind == "dropped"]
    assert lost and all(r.header["reason"] == "disconnected" for r in lost)


def test_the_simulator_example_streams_from_its_step_callback(service: ServerProcess) -> None:
    example = Path(__file__).resolve().parents[1] / "examples" / "live_drops.py"
    url = f"http://127.0.0.1:{service.http_port}"
    done = subprocess.run(
        [sys.executable, str(example), "--server", url, "--steps", "16", "--size", "96x64"],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
    )
    assert done.returncode == 0, done.stderr
    counts = json.loads(done.stdout.split("answers: ")[1].split(";")[0].replace("'", '"'))
    assert counts["image"] >= 1 and counts["error"] == 0
    assert sum(counts.values()) == 16  # one result per step's frame
