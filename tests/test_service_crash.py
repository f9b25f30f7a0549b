"""Crash isolation: a native fault (a real SIGSEGV) in the renderer process costs no frame: a new
renderer starts, the frames the dead one held are sent to it again (PROTOCOL.md §4.4
``render_failed``), every frame renders the same pixels, and the listeners never stop. The fault
is injected through the test seam (render_faults.py); a frame that crashes the renderer each time
is test_service_watchdog.py's."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from render_faults import fault_env
from service_harness import SMALL_SCENE, ServerProcess, ball, png_pixels
from test_service_http import metric_values

from sphrender.core.protocol import MessageType, encode_frame


def test_renderer_segfault_costs_no_frame_and_the_service_goes_on(tmp_path: Path) -> None:
    env = {**fault_env("crash_at_frames=3"), "PYTHONFAULTHANDLER": "1"}
    positions = ball(1500, seed=4)
    health: list[int] = []
    stop = threading.Event()
    with ServerProcess(tmp_path / "server", env=env) as server:

        def poll() -> None:  # the HTTP listener answers all along
            while not stop.wait(0.1):
                health.append(server.json("GET", "/healthz", timeout=10)[0])

        poller = threading.Thread(target=poll, daemon=True)
        poller.start()
        with server.stream() as client:
            client.hello(SMALL_SCENE)
            # 8 frames: frame 3 crashes the renderer (once: the fault is keyed by the send count).
            client.send(b"".join(encode_frame(i, positions) for i in range(1, 9)))
            answers = [client.receive() for _ in range(8)]
        stop.set()
        poller.join(10)
        assert [h["id"] for _k, h, _p in answers] == list(range(1, 9))
        # Frame 3 crashed the renderer. The frames it held (up to 2 x encoder_threads + 1 are
        # sent ahead, so encoding overlaps the next render) are rendered by the new one.
        assert [k for k, _h, _p in answers] == [MessageType.IMAGE] * 8
        images = [payload for kind, _h, payload in answers if kind == MessageType.IMAGE]
        for payload in images:  # before and after the restart: the same pixels
            np.testing.assert_array_equal(
                png_pixels(payload, tmp_path), png_pixels(images[-1], tmp_path)
            )
        values = metric_values(server.metrics_text())
        assert values[("sphrender_worker_restarts_total", (("reason", "crash"),))] == 1
        assert server.json("GET", "/readyz") == (200, {"status": "ready"})
        assert health and set(health) == {200}
        with server.stream() as client:  # a new session on the new renderer
            client.hello(SMALL_SCENE)
            client.frame(9, positions)
            kind, header, payload = client.receive()
            assert (kind, header["id"]) == (MessageType.IMAGE, 9)
        time.sleep(0.1)
        events = server.log_events()
        restart = [e for e in events if e.get("event") == "worker_restart"]
        assert restart and restart[0]["reason"] == "crash"
        assert restart[0]["frames_lost"] == 0 and restart[0]["frames_resent"] >= 1
        # PYTHONFAULTHANDLER / faulthandler in the child: the native fault's stacks are logged.
        assert "Fatal Python error: Segmentation fault" in server.logs()
