"""Service parts that need no server process: scheduler fairness, metrics text, configuration,
scene merging, the environment-directory rule, and the render watchdog's bookkeeping."""

from __future__ import annotations

import math
import os
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.core.protocol import LimitError
from sphrender.server.scene import Scene, merge_scene_dicts
from sphrender.server.service.config import (
    ServerConfig,
    check_bind_policy,
    is_loopback,
    load_server_config,
    server_config_from_dict,
)
from sphrender.server.service.metrics import Registry
from sphrender.server.service.render.in_flight import InFlight
from sphrender.server.service.render.jobs import DroppedOutcome, ErrorOutcome, FrameJob
from sphrender.server.service.render.scheduler import FairScheduler, QueueFull, SchedulerClosed
from sphrender.server.service.render.worker import sort_held
from sphrender.server.service.sessions import SceneValidator

REPO = Path(__file__).resolve().parents[1]
PARTICLES = make_frame(np.zeros((1, 3)))


def job(key: str, n: int = 0) -> FrameJob:
    return FrameJob(key, PARTICLES, Scene(), "png", "stream", frame_id=n)


def drain(scheduler: FairScheduler) -> list[tuple[str, int | None]]:
    order = []
    while (item := scheduler.take(timeout=0)) is not None:
        assert isinstance(item, FrameJob)
        order.append((item.key, item.frame_id))
    return order


def test_round_robin_a_busy_session_cannot_starve_others() -> None:
    scheduler = FairScheduler(per_key=8, total=64)
    for n in range(8):
        scheduler.submit(job("busy", n))
    scheduler.submit(job("quiet", 0))
    scheduler.submit(job("other", 0))
    order = drain(scheduler)
    # The quiet sessions are served after at most one frame of the busy one each.
    assert order[:3] == [("busy", 0), ("quiet", 0), ("other", 0)]
    assert order[3:] == [("busy", n) for n in range(1, 8)]


def test_frames_of_one_session_stay_in_order_under_interleaving() -> None:
    scheduler = FairScheduler(per_key=4, total=12)
    for n in range(4):
        for key in ("a", "b", "c"):
            scheduler.submit(job(key, n))
    order = drain(scheduler)
    assert order == [(key, n) for n in range(4) for key in ("a", "b", "c")]


def test_bounds_per_session_and_total() -> None:
    scheduler = FairScheduler(per_key=2, total=3)
    scheduler.submit(job("a"))
    scheduler.submit(job("a"))
    with pytest.raises(QueueFull):
        scheduler.submit(job("a"))
    scheduler.submit(job("b"))
    with pytest.raises(QueueFull):
        scheduler.submit(job("c"))  # total reached
    assert scheduler.depth == 3


def test_latest_supersedes_only_frames_not_started() -> None:
    scheduler = FairScheduler(per_key=4, total=8)
    first, second, third = job("live", 1), job("live", 2), job("live", 3)
    scheduler.submit(first, latest=True)
    started = scheduler.take(timeout=0)  # the render thread picked frame 1
    assert started is first
    scheduler.submit(second, latest=True)
    scheduler.submit(third, latest=True)
    assert second.future.result(0) == DroppedOutcome("superseded")
    assert not first.done and not third.done
    assert drain(scheduler) == [("live", 3)]


def test_blocking_submit_waits_for_room_and_close_ends_it() -> None:
    scheduler = FairScheduler(per_key=1, total=1)
    scheduler.submit(job("a", 1))
    done = threading.Event()

    def blocked() -> None:
        scheduler.submit(job("a", 2), block=True)
        done.set()

    thread = threading.Thread(target=blocked)
    thread.start()
    assert not done.wait(0.3)
    assert drain(scheduler)[:1] == [("a", 1)]
    assert done.wait(5)
    thread.join(5)
    scheduler.close()
    with pytest.raises(SchedulerClosed):
        scheduler.submit(job("a", 3))
    assert drain(scheduler) == [("a", 2)]  # what was queued is still handed out
    assert scheduler.finished


def test_cancel_key_answers_queued_frames_once() -> None:
    scheduler = FairScheduler(per_key=4, total=8)
    jobs = [job("gone", n) for n in range(3)]
    for item in jobs:
        scheduler.submit(item)
    assert scheduler.cancel_key("gone") == 3
    assert all(item.future.result(0) == DroppedOutcome("cancelled") for item in jobs)
    assert not jobs[0].resolve(DroppedOutcome("superseded"))  # first answer wins
    assert scheduler.depth == 0


def test_metrics_exposition_parses_and_escapes() -> None:
    registry = Registry()
    counter = registry.counter("demo_frames_total", "Frames\nby outcome \\ kind", ("outcome",))
    gauge = registry.gauge("demo_depth", "Depth")
    histogram = registry.histogram("demo_seconds", "Latency", ("stage",), buckets=(0.1, 1.0))
    counter.inc('we"ird\\label\n')
    counter.inc("image", amount=2)
    gauge.set(3.5)
    for value in (0.05, 0.1, 0.5, 7.0):
        histogram.observe(value, "splat")
    families = {f.name: f for f in text_string_to_metric_families(registry.exposition())}
    frames = {s.labels["outcome"]: s.value for s in families["demo_frames"].samples}
    assert frames == {'we"ird\\label\n': 1.0, "image": 2.0}
    assert families["demo_frames"].documentation == "Frames\nby outcome \\ kind"
    samples = {(s.name, s.labels.get("le")): s.value for s in families["demo_seconds"].samples}
    # le is inclusive: 0.1 falls in the 0.1 bucket; buckets are cumulative.
    assert samples[("demo_seconds_bucket", "0.1")] == 2
    assert samples[("demo_seconds_bucket", "1.0")] == 3
    assert samples[("demo_seconds_bucket", "+Inf")] == 4
    assert samples[("demo_seconds_count", None)] == 4
    assert math.isclose(samples[("demo_seconds_sum", None)], 7.65)
    assert families["demo_depth"].samples[0].value == 3.5


def test_shipped_server_config_is_the_defaults() -> None:
    assert load_server_config(REPO / "configs" / "server.toml") == ServerConfig()


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({"http": {"port": 70000}}, "http.port"),
        ({"http": {"hostname": "x"}}, "http.hostname"),
        ({"stream": {"max_in_flight": 0}}, "stream.max_in_flight"),
        ({"limits": {"max_particles": "many"}}, "limits.max_particles"),
        ({"security": {"token": "short"}}, "security.token"),
        ({"security": {"environment_dirs": ["relative/dir"]}}, "security.environment_dirs[0]"),
        ({"scheduler": {"queue_per_session": 10, "queue_total": 5}}, "scheduler.queue_per_session"),
        ({"tls": {}}, "tls"),
    ],
)
def test_config_errors_name_the_key(data: dict, field: str) -> None:
    with pytest.raises(InputError) as info:
        server_config_from_dict(data)
    assert info.value.field == field


def test_token_from_environment_overrides_the_file(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SPHRENDER_TOKEN", "t" * 24)
    assert load_server_config(None).security.token == "t" * 24


def test_bind_policy_refuses_remote_without_token() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.0.2.1")
    remote = server_config_from_dict({"http": {"host": "0.0.0.0"}})
    with pytest.raises(InputError) as info:
        check_bind_policy(remote)
    assert info.value.field == "http.host"
    check_bind_policy(remote.with_overrides({"security": {"token": "x" * 16}}))
    check_bind_policy(remote.with_overrides({"security": {"allow_remote_without_token": True}}))


def test_merge_scene_merges_tables_and_replaces_the_rest() -> None:
    base: dict[str, Any] = {"camera": {"eye": [0, 0, 1], "fov_y": 40.0}, "lights": [{"a": 1}]}
    merged = merge_scene_dicts(base, {"camera": {"eye": [1, 1, 1]}, "lights": []})
    assert merged == {"camera": {"eye": [1, 1, 1], "fov_y": 40.0}, "lights": []}
    assert base["camera"]["eye"] == [0, 0, 1]  # the session's scene is untouched


def test_environment_files_only_from_configured_directories(tmp_path: Path) -> None:
    allowed = tmp_path / "envs"
    allowed.mkdir()
    (allowed / "sky.exr").write_bytes(b"x")
    secret = tmp_path / "secret.exr"
    secret.write_bytes(b"x")
    os.symlink(secret, allowed / "escape.exr")
    validator = SceneValidator(10**6, [str(allowed)])
    scene = validator.from_dict({"environment": {"file": "sky.exr"}})
    assert scene.environment.file == "sky.exr"  # the render thread resolves it the same way
    for name in ("../secret.exr", str(secret), "escape.exr", "missing.exr"):
        with pytest.raises(InputError) as info:
            validator.from_dict({"environment": {"file": name}})
        assert info.value.field == "environment.file"
        assert str(allowed) not in info.value.message  # never the server's own directories
    with pytest.raises(InputError, match="no environment directories"):
        SceneValidator(10**6, []).from_dict({"environment": {"file": "a.exr"}})


def test_pixel_limit_is_a_limit_error() -> None:
    with pytest.raises(LimitError) as info:
        SceneValidator(100, []).from_dict({"image": {"width": 20, "height": 20}})
    assert info.value.field == "image"


def test_watchdog_times_a_job_from_its_start_not_its_send() -> None:
    """PROTOCOL.md §4.1 ``render_s``: time a frame waited in the renderer's pipe does not count."""
    in_flight = InFlight()
    first, second = in_flight.add(job("a", 1)), in_flight.add(job("b", 2))
    in_flight.started(first)
    time.sleep(0.05)
    assert in_flight.overdue(0.02)  # the first has been rendering past the limit
    in_flight.pop(first)
    assert not in_flight.overdue(0.02)  # the second was sent long ago, but waited behind it
    in_flight.started(second)
    assert not in_flight.overdue(0.02)
    time.sleep(0.05)
    assert in_flight.overdue(0.02)
    stalled = InFlight()  # a process that never begins what it was sent is stuck too
    stalled.add(job("c", 3))
    time.sleep(0.05)
    assert stalled.overdue(0.02)


def test_a_dead_renderers_jobs_the_late_one_fails_the_others_go_again() -> None:
    """§4.4: the late frame is render_failed naming the limit; the others are re-sent, in the
    order sent, unless this was their second death."""
    in_flight = InFlight()
    jobs = [job("a", 1), job("b", 2), job("c", 3)]
    late = in_flight.add(jobs[0])
    in_flight.add(jobs[1])
    in_flight.add(jobs[2], restarts=1)
    in_flight.started(late)
    time.sleep(0.05)
    resend, failed = sort_held(in_flight.take_all(), 0.02, "signal 9 (SIGKILL)")
    assert resend == [(jobs[1], 1)] and failed == 2
    timed_out, twice = jobs[0].future.result(0), jobs[2].future.result(0)
    assert isinstance(timed_out, ErrorOutcome) and isinstance(twice, ErrorOutcome)
    assert timed_out.code == "render_failed" and "limits.render_timeout_s" in timed_out.message
    assert twice.code == "render_failed" and "each time" in twice.message
