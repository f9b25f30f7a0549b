"""The streaming protocol (PROTOCOL.md) against a real `sphrender serve` process on loopback.

Pixels are compared exactly, for the reason given in test_service_http.py. Malformed-input
tests run while a well-behaved client keeps streaming, whose every frame must still come back
right: one client's garbage must never disturb another's frames.
"""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_harness import run_sphrender
from service_harness import (
    SMALL_SCENE,
    ServerProcess,
    StreamClient,
    ball,
    png_pixels,
    reference_png,
    toml_text,
)
from test_service_http import metric_values

from sphrender.core.protocol import (
    MAX_FRAME_ID,
    PREFIX,
    MessageType,
    encode_frame,
    encode_message,
    encode_npz_frame,
)
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.encoders import read_exr


def quiet_metrics(service: ServerProcess) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """/metrics once no stream session is open (earlier tests' connections fully counted)."""
    deadline = time.monotonic() + 20
    while (values := metric_values(service.metrics_text())).get(
        ("sphrender_sessions", (("transport", "stream"),)), 0
    ) > 0:
        assert time.monotonic() < deadline, "stream sessions stay open"
        time.sleep(0.05)
    return values


def test_stream_frame_matches_sphrender_render(service: ServerProcess, tmp_path: Path) -> None:
    positions = ball(3000)
    npz = tmp_path / "frame.npz"
    np.savez(npz, positions=positions)
    scene_toml = tmp_path / "scene.toml"
    scene_toml.write_text(toml_text(SMALL_SCENE))
    out = tmp_path / "cli.png"
    cli = run_sphrender("render", str(npz), "--scene", str(scene_toml), "-o", str(out))
    assert cli.returncode == 0, cli.stderr
    with service.stream() as client:
        welcome = client.hello(SMALL_SCENE)
        assert welcome["mode"] == "queue" and welcome["max_in_flight"] == 8
        client.frame(42, positions)
        kind, header, payload = client.receive()
    assert kind == MessageType.IMAGE, header
    assert header["id"] == 42 and header["format"] == "png"
    assert (header["width"], header["height"], header["particles"]) == (64, 48, 3000)
    np.testing.assert_array_equal(
        png_pixels(payload, tmp_path), png_pixels(out.read_bytes(), tmp_path)
    )


def test_stream_exr_matches_in_process_render(
    service: ServerProcess, renderer: SurfaceRenderer
) -> None:
    from sphrender.core.frame import make_frame
    from sphrender.server.scene import scene_from_dict

    scene = {**SMALL_SCENE, "output": {"format": "exr", "exr_pixel_type": "float"}}
    positions = ball(2000, seed=5)
    with service.stream() as client:
        client.hello(scene)
        client.frame(1, positions)
        kind, header, payload = client.receive()
    assert kind == MessageType.IMAGE and header["format"] == "exr"
    expected, _stats = renderer.render(
        make_frame(positions), scene_from_dict(scene), depth=True, normals=True
    )
    channels = read_exr(payload)
    np.testing.assert_array_equal(channels["Z"], expected.depth)
    alpha = expected.rgba[..., 3]
    np.testing.assert_array_equal(channels["A"], alpha)
    np.testing.assert_array_equal(channels["R"], expected.rgba[..., 0] * alpha)  # premultiplied


def test_pipelined_frames_keep_order_and_echo_ids(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    ids = [5, 900, 3, MAX_FRAME_ID, 0, 17, 17, 44, 1, 2, 3, 8]  # more than max_in_flight (8)
    frames = [ball(600, seed=100 + i) for i in range(len(ids))]
    with service.stream() as client:
        client.hello()
        client.send(b"".join(encode_frame(i, p) for i, p in zip(ids, frames, strict=True)))
        answers = [client.receive() for _ in ids]
    assert [h["id"] for _k, h, _p in answers] == ids
    for (kind, _header, payload), positions in zip(answers, frames, strict=True):
        assert kind == MessageType.IMAGE
        expected = reference_png(renderer, positions, SMALL_SCENE)
        np.testing.assert_array_equal(png_pixels(payload, tmp_path), png_pixels(expected, tmp_path))


def test_latest_mode_answers_superseded_frames_dropped(service: ServerProcess) -> None:
    scene = {**SMALL_SCENE, "image": {"width": 240, "height": 180}}
    count = 30
    before = quiet_metrics(service)
    with service.stream() as client:
        assert client.hello(scene, mode="latest")["mode"] == "latest"
        data = b"".join(encode_frame(i, ball(20_000, seed=i)) for i in range(count))
        sender = threading.Thread(target=client.send, args=(data,))
        sender.start()
        answers = [client.receive() for _ in range(count)]
        sender.join(30)
    assert [h["id"] for _k, h, _p in answers] == list(range(count))  # each once, in order
    kinds = [k for k, _h, _p in answers]
    assert set(kinds) <= {MessageType.IMAGE, MessageType.DROPPED}
    dropped = kinds.count(MessageType.DROPPED)
    assert dropped >= 1
    assert kinds[-1] == MessageType.IMAGE  # the newest frame is never superseded
    assert all(h["reason"] == "superseded" for k, h, _p in answers if k == MessageType.DROPPED)
    after = metric_values(service.metrics_text())
    key = ("sphrender_frames_total", (("outcome", "dropped"), ("transport", "stream")))
    assert after.get(key, 0) - before.get(key, 0) == dropped


def test_16_concurrent_stream_clients_every_frame_answered_once(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    clients, per_client = 16, 6

    def particles(client: int, frame: int) -> np.ndarray:
        return ball(500, seed=1000 * client + frame)

    expected = {
        (c, f): png_pixels(reference_png(renderer, particles(c, f), SMALL_SCENE), tmp_path)
        for c in range(clients)
        for f in range(per_client)
    }
    received: dict[int, list[tuple[MessageType, dict[str, Any], bytes]]] = {}
    errors: list[BaseException] = []
    barrier = threading.Barrier(clients)

    def run(c: int) -> None:
        try:
            with service.stream() as client:
                client.hello()
                barrier.wait(30)
                for f in range(per_client):
                    client.frame(c * 100 + f, particles(c, f))
                received[c] = [client.receive() for _ in range(per_client)]
        except BaseException as exc:  # reported below
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(c,)) for c in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(180)
    assert not errors, errors
    for c in range(clients):
        answers = received[c]
        assert [h["id"] for _k, h, _p in answers] == [c * 100 + f for f in range(per_client)]
        for f, (kind, _header, payload) in enumerate(answers):
            assert kind == MessageType.IMAGE
            np.testing.assert_array_equal(png_pixels(payload, tmp_path), expected[(c, f)])


@contextmanager
def bystander(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> Iterator[list[int]]:
    """A well-behaved client streaming frames the whole time; its answers must stay right."""
    positions = ball(400, seed=77)
    expected = png_pixels(reference_png(renderer, positions, SMALL_SCENE), tmp_path)
    stop = threading.Event()
    good: list[int] = []
    failures: list[BaseException] = []

    def run() -> None:
        try:
            with service.stream() as client:
                client.hello()
                frame_id = 0
                while not stop.is_set():
                    client.frame(frame_id, positions)
                    kind, header, payload = client.receive()
                    assert (kind, header["id"]) == (MessageType.IMAGE, frame_id), header
                    np.testing.assert_array_equal(png_pixels(payload, tmp_path), expected)
                    good.append(frame_id)
                    frame_id += 1
        except BaseException as exc:
            failures.append(exc)

    def wait_for_frames(count: int) -> None:
        deadline = time.monotonic() + 60
        while len(good) < count and not failures and time.monotonic() < deadline:
            time.sleep(0.01)

    thread = threading.Thread(target=run)
    thread.start()
    try:
        wait_for_frames(1)  # streaming before the misbehaving clients start
        yield good
        wait_for_frames(len(good) + 1)  # and still served after them
    finally:
        stop.set()
        thread.join(60)
    assert not failures, failures
    assert len(good) >= 2, "the bystander was not served before and after"


def expect_fatal(client: StreamClient, code: str, field: str | None) -> dict[str, Any]:
    kind, header, _payload = client.receive()
    assert kind == MessageType.ERROR, header
    assert header["id"] is None and header["fatal"] is True
    assert (header["code"], header["field"]) == (code, field), header
    assert client.closed_by_server()
    return header


def expect_frame_error(client: StreamClient, frame_id: int, code: str, field: str) -> None:
    kind, header, _payload = client.receive()
    assert kind == MessageType.ERROR, header
    assert (header["id"], header["code"], header["field"], header["fatal"]) == (
        frame_id,
        code,
        field,
        False,
    ), header


def prefix(kind: int, header_len: int, payload_len: int, magic: bytes = b"SPHR", v: int = 1):
    return PREFIX.pack(magic, v, kind, 0, header_len, payload_len)


FATAL_CASES: dict[str, tuple[bytes, str, str | None]] = {
    "bad magic": (prefix(2, 2, 0, magic=b"HTTP") + b"{}", "protocol", "magic"),
    "bad version": (prefix(2, 2, 0, v=9) + b"{}", "unsupported_version", "version"),
    "unknown type": (prefix(0x42, 2, 0) + b"{}", "protocol", "type"),
    "non-JSON header": (prefix(2, 9, 0) + b"{not json", "protocol", "header"),
    "header not an object": (prefix(2, 2, 0) + b"[]", "protocol", "header"),
    "frame without id": (
        encode_message(MessageType.FRAME, {"arrays": []}, b""),
        "protocol",
        "id",
    ),
    "negative id": (encode_message(MessageType.FRAME, {"id": -1, "arrays": []}), "protocol", "id"),
    "payload over the limit": (prefix(2, 2, 5 << 20) + b"{}", "too_large", "payload_length"),
    "header over the limit": (prefix(2, 1 << 20, 0), "too_large", "header_length"),
    "second HELLO": (encode_message(MessageType.HELLO, {"scene": {}}), "protocol", "type"),
}


@pytest.mark.parametrize("case", list(FATAL_CASES))
def test_framing_errors_are_fatal_for_that_connection_only(
    case: str, service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    data, code, field = FATAL_CASES[case]
    with bystander(service, renderer, tmp_path), service.stream() as client:
        client.hello()
        client.frame(1, ball(100))  # owed before the garbage: still answered first
        client.send(data)
        kind, header, _payload = client.receive()
        assert (kind, header["id"]) == (MessageType.IMAGE, 1)
        expect_fatal(client, code, field)


def test_densities_in_other_units_are_rendered_with_a_note(
    service: ServerProcess, tmp_path: Path
) -> None:
    """A ball whose densities are written x 7 (molten steel in kg/m^3 against the default
    sph.rest_density 1000): the frame is rendered, on densities computed from the positions,
    and its IMAGE carries one note naming `densities` and the field to set, over the stream and
    (the same array as JSON) over HTTP; the same frame in the scene's units has no note, and a
    client's next frame is not affected."""
    positions = ball(2000, seed=3)
    water = np.linspace(980.0, 1010.0, len(positions), dtype=np.float32)  # a fluid at rest
    steel = np.float32(7.0) * water
    with service.stream() as client:
        client.hello(SMALL_SCENE)
        client.frame(1, positions, densities=steel)
        client.frame(2, positions, densities=water)
        answers = [client.receive(), client.receive()]
    (kind, noted, payload), (kind2, plain, _) = answers
    assert kind == kind2 == MessageType.IMAGE, answers
    assert png_pixels(payload, tmp_path)[..., 3].max() == 255  # rendered
    assert [n["field"] for n in noted["notes"]] == ["densities"]
    message = noted["notes"][0]["message"]
    assert "7.07 x sph.rest_density (1000)" in message and "computed from the positions" in message
    assert "notes" not in plain
    body = encode_npz_frame(positions, densities=steel, scene=SMALL_SCENE)
    status, headers, data = service.request(
        "POST", "/v1/render", body, {"Content-Type": "application/x-npz"}
    )
    assert status == 200, data
    assert json.loads(headers["X-Sphrender-Notes"]) == noted["notes"]


def test_content_errors_answer_that_frame_and_the_connection_goes_on(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    nan = ball(100)
    nan[42, 0] = np.nan
    lying_shape = encode_message(
        MessageType.FRAME,
        {"id": 12, "arrays": [{"name": "positions", "dtype": "<f8", "shape": [1000, 3]}]},
        bytes(24),
    )
    short_arrays = encode_message(
        MessageType.FRAME,
        {"id": 13, "arrays": [{"name": "positions", "dtype": "<f8", "shape": [1, 3]}]},
        bytes(32),
    )
    positions = ball(300, seed=9)
    expected = png_pixels(reference_png(renderer, positions, SMALL_SCENE), tmp_path)
    with bystander(service, renderer, tmp_path), service.stream() as client:
        client.hello()
        client.frame(10, nan)
        expect_frame_error(client, 10, "bad_input", "positions[42]")
        client.frame(11, ball(60_000).astype(np.float32))  # over max_particles (50 000)
        expect_frame_error(client, 11, "too_large", "arrays[0].shape")
        client.send(lying_shape)
        expect_frame_error(client, 12, "bad_input", "arrays[0].shape")
        client.send(short_arrays)
        expect_frame_error(client, 13, "bad_input", "payload_length")
        client.frame(14, positions, scene={"camera": {"fov_y": 400.0}})
        expect_frame_error(client, 14, "bad_input", "camera.fov_y")
        client.send(encode_message(MessageType.FRAME, {"id": 15, "arrays": [], "colour": 1}))
        expect_frame_error(client, 15, "bad_input", "header.colour")
        client.frame(16, positions)
        kind, header, payload = client.receive()
        assert (kind, header["id"]) == (MessageType.IMAGE, 16)
        np.testing.assert_array_equal(png_pixels(payload, tmp_path), expected)


@pytest.mark.parametrize(
    ("hello", "code", "field"),
    [
        ({"scene": {"camera": {"fov_y": 0.0}}}, "bad_input", "camera.fov_y"),
        ({"scene": {"image": {"width": 1000, "height": 1000}}}, "too_large", "image"),
        ({"scene": SMALL_SCENE, "mode": "fastest"}, "bad_input", "mode"),
        ({"scene": SMALL_SCENE, "max_in_flight": 1000}, "bad_input", "max_in_flight"),
        ({"scene": SMALL_SCENE, "colour": "red"}, "bad_input", "header.colour"),
        ({"scene": [1, 2]}, "bad_input", "scene"),
    ],
)
def test_bad_handshakes(service: ServerProcess, hello: dict, code: str, field: str) -> None:
    with service.stream() as client:
        client.send(encode_message(MessageType.HELLO, hello))
        expect_fatal(client, code, field)


def test_frame_before_hello_is_refused(service: ServerProcess) -> None:
    with service.stream() as client:
        client.frame(1, ball(10))
        expect_fatal(client, "protocol", "type")


def test_silent_client_gets_a_handshake_timeout(service: ServerProcess) -> None:
    with service.stream() as client:
        start = time.monotonic()
        header = expect_fatal(client, "timeout", None)
        assert "HELLO" in header["error"]
        assert 2.5 < time.monotonic() - start < 10  # handshake_timeout_s = 3


def test_slow_client_mid_message_times_out(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    """Half a frame, then nothing: after message_timeout_s (1.5 s) the server answers a fatal
    timeout and frees the connection; the bystander is served all along."""
    frame = encode_frame(3, ball(100))
    with bystander(service, renderer, tmp_path), service.stream() as client:
        client.hello()
        client.send(frame[: len(frame) // 2])
        start = time.monotonic()
        expect_fatal(client, "timeout", None)
        assert 1.0 < time.monotonic() - start < 8


def test_payload_shorter_than_announced_times_out(service: ServerProcess) -> None:
    """A lying payload length (more than is sent) cannot make the server wait forever."""
    header = b'{"id":1,"arrays":[{"name":"positions","dtype":"<f8","shape":[1,3]}]}'
    with service.stream() as client:
        client.hello()
        client.send(prefix(2, len(header), 1000) + header + bytes(24))
        # Judged from the header before the payload is read: that frame gets its error...
        kind, answer, _payload = client.receive()
        assert kind == MessageType.ERROR, answer
        assert (answer["id"], answer["code"], answer["field"]) == (1, "bad_input", "payload_length")
        # ...and the 976 bytes that never come time the connection out.
        expect_fatal(client, "timeout", None)


def test_client_vanishing_mid_frame_and_mid_pipeline(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    before = quiet_metrics(service)
    with bystander(service, renderer, tmp_path):
        # Gone in the middle of a message.
        with service.stream() as client:
            client.hello()
            data = encode_frame(1, ball(5000))
            client.send(data[: len(data) // 3])
        # Gone with frames in flight, without reading any answer.
        with service.stream() as client:
            client.hello()
            client.send(b"".join(encode_frame(i, ball(5000, seed=i)) for i in range(6)))
            client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))

    def ended() -> dict[str, float]:
        after = metric_values(service.metrics_text())
        return {
            dict(labels)["end"]: value - before.get((name, labels), 0)
            for (name, labels), value in after.items()
            if name == "sphrender_stream_connections_total"
        }

    deadline = time.monotonic() + 20
    while ended().get("vanished", 0) < 1 or sum(ended().values()) < 3:  # + the bystander
        assert time.monotonic() < deadline, ended()
        time.sleep(0.05)
    assert service.json("GET", "/healthz") == (200, {"status": "ok"})


def test_bye_answers_everything_then_says_goodbye(service: ServerProcess) -> None:
    with service.stream() as client:
        client.hello()
        client.send(
            b"".join(encode_frame(i, ball(300, seed=i)) for i in range(3))
            + encode_message(MessageType.BYE, {})
        )
        answers = [client.receive() for _ in range(3)]
        assert [(k, h["id"]) for k, h, _p in answers] == [(MessageType.IMAGE, i) for i in range(3)]
        kind, header, _payload = client.receive()
        assert (kind, header) == (MessageType.GOODBYE, {"reason": "bye"})
        assert client.closed_by_server()


def test_half_close_still_gets_its_answers(service: ServerProcess) -> None:
    with service.stream() as client:
        client.hello()
        client.send(b"".join(encode_frame(i, ball(300, seed=i)) for i in range(4)))
        client.sock.shutdown(socket.SHUT_WR)
        answers = [client.receive() for _ in range(4)]
        assert [h["id"] for _k, h, _p in answers] == [0, 1, 2, 3]
        kind, header, _payload = client.receive()
        assert (kind, header) == (MessageType.GOODBYE, {"reason": "eof"})


def test_stream_metrics_count_frames_and_bytes(service: ServerProcess) -> None:
    before = quiet_metrics(service)
    with service.stream() as client:
        client.hello()
        sent = 0
        for i in range(3):
            data = encode_frame(i, ball(200, seed=i))
            client.send(data)
            sent += len(data)
        bad = ball(5)
        bad[0, 0] = np.inf
        client.frame(3, bad)
        answers = [client.receive() for _ in range(4)]
    assert [k for k, _h, _p in answers] == [MessageType.IMAGE] * 3 + [MessageType.ERROR]
    key = ("sphrender_stream_connections_total", (("end", "eof"),))
    deadline = time.monotonic() + 20
    # The connection's end is counted once the server has seen the close.
    while (after := metric_values(service.metrics_text())).get(key, 0) == before.get(key, 0):
        assert time.monotonic() < deadline, "the connection end was never counted"
        time.sleep(0.05)

    def delta(name: str, **labels: str) -> float:
        key = (name, tuple(sorted(labels.items())))
        return after.get(key, 0.0) - before.get(key, 0.0)

    assert delta("sphrender_frames_total", transport="stream", outcome="image") == 3
    assert delta("sphrender_frames_total", transport="stream", outcome="error") == 1
    assert delta("sphrender_errors_total", transport="stream", code="bad_input") == 1
    assert delta("sphrender_received_bytes_total", transport="stream") >= sent
    assert delta("sphrender_sent_bytes_total", transport="stream") > 0
    assert delta("sphrender_stream_connections_total", end="eof") == 1
