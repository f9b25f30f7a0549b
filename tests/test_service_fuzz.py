"""A bounded, seeded subset of the hostile-network campaign (benchmarks/fuzz_campaign.py runs
the long one): stream frame-level and connection-level inputs and HTTP inputs from
`fuzz_inputs`, with a well-behaved client alongside whose every frame must be the same image.
A failure names its seed; rerun with it to reproduce."""

from __future__ import annotations

import json
import random
from collections.abc import Iterator

import pytest
from fuzz_inputs import (
    SCENE,
    HttpConn,
    Tally,
    run_connection_input,
    run_frame_batch,
    run_http_input,
    stream_hello,
)
from service_harness import ServerProcess, ball
from test_service_http import metric_values

from sphrender.core.protocol import MessageType, encode_frame, encode_message

SEEDS = (11, 12, 13)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    with ServerProcess(tmp_path_factory.mktemp("fuzz"), {}) as process:
        yield process


def _good_frame(server: ServerProcess, reference: list[bytes]) -> None:
    with server.stream() as client:
        client.hello(SCENE)
        client.send(encode_frame(0, ball(300, seed=5)))
        kind, _header, payload = client.receive()
        assert kind == 0x82
        reference.append(payload)
        assert payload == reference[0]


def _check(tally: Tally, seed: int) -> None:
    """No hang, no 5xx, and every error text in plain words and JSON values (PROTOCOL.md 1)."""
    assert (tally.hangs, tally.server_errors, tally.bad_texts) == (0, 0, 0), (seed, tally.notes)
    assert tally.texts > 0


@pytest.mark.parametrize("seed", SEEDS)
def test_stream_frame_fuzz(server: ServerProcess, seed: int) -> None:
    rng, tally, reference = random.Random(seed), Tally(), []  # type: ignore[var-annotated]
    conn = stream_hello(server.stream_port)
    try:
        for batch in range(150):
            run_frame_batch(conn, rng, 1 + 8 * batch, 8, tally)
            if batch % 50 == 0:
                _good_frame(server, reference)
    finally:
        conn.close()
    _check(tally, seed)
    assert tally.stream_inputs == 1200


@pytest.mark.parametrize("seed", SEEDS)
def test_stream_connection_fuzz(server: ServerProcess, seed: int) -> None:
    rng, tally, reference = random.Random(seed), Tally(), []  # type: ignore[var-annotated]
    for index in range(150):
        run_connection_input(server.stream_port, rng, tally)
        if index % 50 == 0:
            _good_frame(server, reference)
    _check(tally, seed)


@pytest.mark.parametrize("seed", SEEDS)
def test_http_fuzz(server: ServerProcess, seed: int) -> None:
    rng, tally, reference = random.Random(seed), Tally(), []  # type: ignore[var-annotated]
    http = HttpConn(server.http_port)
    try:
        for index in range(400):
            run_http_input(http, rng, tally)
            if index % 100 == 0:
                _good_frame(server, reference)
    finally:
        http.close()
    _check(tally, seed)


def test_a_camera_target_at_1e308(server: ServerProcess) -> None:
    """The campaign's numpy warning: now a bad_input naming the field, on both transports."""
    far = {**SCENE, "camera": {**SCENE["camera"], "target": [1e308, 0.0, 0.0]}}
    with server.stream() as client:
        client.send(encode_message(MessageType.HELLO, {"scene": far}))
        kind, header, _payload = client.receive()
        assert (kind, header["code"], header["field"]) == (0x83, "bad_input", "camera.target")
    with server.stream() as client:
        client.hello(SCENE)
        client.send(encode_frame(1, ball(30), scene={"camera": far["camera"]}))
        assert client.receive()[1]["field"] == "camera.target"
    status, answer = server.json("POST", "/v1/sessions", far)
    assert (status, answer["field"]) == (400, "camera.target")


def test_with_log_json_every_stderr_line_is_a_json_object(server: ServerProcess) -> None:
    """`--log-json` (service_harness starts every server with it): after the fuzz inputs, the
    main and the render process wrote nothing to stderr but JSON objects, one a line."""
    lines = server.logs().splitlines()
    assert lines
    for line in lines:
        assert isinstance(json.loads(line), dict), line


def test_after_the_fuzz_the_server_is_whole(server: ServerProcess) -> None:
    assert server.proc.poll() is None
    assert server.json("GET", "/healthz") == (200, {"status": "ok"})
    values = metric_values(server.metrics_text())
    for reason in ("crash", "hung", "rss"):
        assert values[("sphrender_worker_restarts_total", (("reason", reason),))] == 0
    assert "decode_bug" not in [e.get("event") for e in server.log_events()]
