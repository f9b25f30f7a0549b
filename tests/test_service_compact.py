"""The compact frame encoding against a real server (PROTOCOL.md §4.7): offered in WELCOME and
/v1/info; a compact frame renders exactly the image of its decoded particles sent raw (the
renderer is deterministic, so the images are byte-identical); frame prediction, the client's
fallback to a full frame when the server lacks the base; and every bad input answered with a
clear, non-fatal error naming the field, the connection going on."""

from __future__ import annotations

import copy
import json
import struct
from collections.abc import Iterator
from typing import Any, Literal

import numpy as np
import pytest
from error_texts import text_faults
from service_harness import SMALL_SCENE, ServerProcess, ball

from sphrender.client.api import Client
from sphrender.core.compact import CompactDecoder
from sphrender.core.compact_encoder import CompactEncoder
from sphrender.core.frame_message import FRAME_CONTENT_TYPE
from sphrender.core.protocol import MessageType, encode_frame, encode_message

RADIUS = SMALL_SCENE["particles"]["radius"]
ERROR = RADIUS / 100  # the client's default bound (POSITION_ERROR_FRACTION)
CONFIG: dict[str, dict[str, Any]] = {
    "limits": {"max_particles": 20_000, "max_pixels": 160 * 120, "max_scene_bytes": 4096},
    "stream": {"message_timeout_s": 3.0, "max_in_flight": 4},
}
RAW = {**SMALL_SCENE, "output": {"format": "raw"}}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    with ServerProcess(tmp_path_factory.mktemp("compact"), CONFIG) as process:
        yield process


def compact_message(frame_id: int, arrays: dict[str, np.ndarray], **kw: Any) -> bytes:
    header, payload = CompactEncoder(position_error=ERROR, **kw).encode(frame_id, arrays)
    return encode_message(MessageType.FRAME, header, payload)


def decoded(arrays: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(the arrays as the server decodes them, `arrays` in that order: the encoder may send the
    particles in another order, `encoder.order`)."""
    encoder = CompactEncoder(position_error=ERROR)
    header, payload = encoder.encode(0, arrays)
    order = encoder.order if encoder.order is not None else slice(None)
    sent = {name: array[order] for name, array in arrays.items()}
    return CompactDecoder().decode(header, payload, max_particles=10**6), sent


def answer(client: Any) -> tuple[MessageType, dict[str, Any], bytes]:
    kind, header, payload = client.receive()
    if kind == MessageType.ERROR:
        assert not text_faults(header["error"]), header
    return kind, header, payload


def test_encodings_are_offered(server: ServerProcess) -> None:
    with server.stream() as client:
        assert client.hello()["frame_encodings"] == ["raw", "compact"]
    status, info = server.json("GET", "/v1/info")
    assert status == 200 and info["frame_encodings"] == ["raw", "compact"]
    assert FRAME_CONTENT_TYPE in info["frame_content_types"]


def test_compact_frame_renders_its_decoded_particles_exactly(server: ServerProcess) -> None:
    rng = np.random.default_rng(1)
    arrays = {
        "positions": ball(2000, seed=1),
        "temperatures": (1500 + 500 * rng.random(2000)).astype(np.float32),
        "velocities": rng.normal(0, 2, (2000, 3)).astype(np.float32),  # within 0.001, carried
        "ids": rng.permutation(10_000)[:2000].astype(np.int64),  # lossless, checked unique
    }
    truth, sent = decoded(arrays)
    assert np.abs(truth["positions"] - sent["positions"]).max() <= ERROR
    assert np.abs(truth["velocities"] - sent["velocities"]).max() <= 1e-3
    assert np.array_equal(truth["ids"], sent["ids"])
    with server.stream() as client:
        client.hello(RAW)
        client.send(compact_message(1, arrays))
        client.frame(2, truth["positions"], temperatures=truth["temperatures"])
        (k1, h1, image1), (k2, h2, image2) = answer(client), answer(client)
    assert (k1, k2) == (MessageType.IMAGE, MessageType.IMAGE), (h1, h2)
    assert image1 == image2 and h1["particles"] == 2000
    # The same over HTTP, as a whole FRAME message body.
    body = compact_message(0, arrays)
    status, _headers, png = server.request(
        "POST",
        "/v1/render?format=raw",
        _with_scene(body, RAW),
        {"Content-Type": FRAME_CONTENT_TYPE},
    )
    assert status == 200, png
    assert png == image1


def test_python_http_client_sends_compact_frames_when_asked(server: ServerProcess) -> None:
    positions = ball(1500, seed=6)
    client = Client(f"http://127.0.0.1:{server.http_port}", compact=True)
    image = client.render(positions, RAW)
    truths, sent = decoded({"positions": positions})
    truth = truths["positions"]
    assert 0 < np.abs(truth - sent["positions"]).max() <= ERROR
    assert image == Client(f"http://127.0.0.1:{server.http_port}").render(truth, RAW)


def _with_scene(message: bytes, scene: dict[str, Any]) -> bytes:
    """The same FRAME message with `scene` in its header."""
    header_len, _payload_len = struct.unpack_from("<II", message, 8)
    header = json.loads(message[16 : 16 + header_len])
    header["scene"] = scene
    return encode_message(MessageType.FRAME, header, message[16 + header_len :])


def test_python_client_streams_compact_with_prediction_and_falls_back(
    server: ServerProcess,
) -> None:
    """Frames 0..5 of a slowly moving ball: the client predicts each from the one before. Frame
    2 is refused from its header (image too large), so the server never holds it: frame 3,
    predicted from it, is refused on ``base`` and the client sends it again in full."""
    rng = np.random.default_rng(2)
    frames = [ball(1500, seed=3)]
    for _ in range(5):
        frames.append(frames[-1] + rng.normal(0, 2e-4, frames[-1].shape))
    client = Client(f"http://127.0.0.1:{server.http_port}")
    too_big = {"image": {"width": 400, "height": 400}}
    with client.stream(RAW, max_in_flight=4) as session:
        assert session.compact is not None
        ids = [
            session.send(positions, scene=too_big) if i == 2 else session.send(positions)
            for i, positions in enumerate(frames)
        ]
        results = [session.receive() for _ in ids]
    assert [r.id for r in results] == ids
    assert [r.kind for r in results] == ["image", "image", "error", "image", "image", "image"]
    assert results[2].header["code"] == "too_large"
    # Each image is that of the positions the encoder produced, decoded: re-encode the same
    # sequence as the client did (frame 2 sent, frame 3 then sent again in full).
    encoder, decoder = CompactEncoder(position_error=ERROR), CompactDecoder()
    with server.stream() as raw_client:
        raw_client.hello(RAW)
        for i, positions in enumerate(frames):
            if i == 3:
                encoder.reset()
            header, payload = encoder.encode(i, {"positions": positions})
            if i == 2:
                continue
            truth = decoder.decode(header, payload, max_particles=10**6)["positions"]
            raw_client.frame(i, truth)
            kind, _header, image = answer(raw_client)
            assert kind == MessageType.IMAGE and image == results[i].data, i


def test_delta_against_a_frame_the_server_lacks_names_the_base(server: ServerProcess) -> None:
    encoder = CompactEncoder(position_error=ERROR)
    positions = ball(500, seed=4)
    encoder.encode(40, {"positions": positions})  # never sent
    header, payload = encoder.encode(41, {"positions": positions + 1e-5})
    assert header["base"] == 40
    with server.stream() as client:
        client.hello()
        client.send(encode_message(MessageType.FRAME, header, payload))
        kind, error, _ = answer(client)
        assert (kind, error["field"], error["code"], error["fatal"]) == (
            MessageType.ERROR,
            "base",
            "bad_input",
            False,
        )
        assert "frame 40 is not held" in error["error"] and "in full" in error["error"]
        client.frame(42, positions)  # the connection goes on
        assert answer(client)[0] == MessageType.IMAGE


def _bad_frames() -> list[tuple[str, dict[str, Any], bytes, str]]:
    """(what, header, payload, field the error must name)."""
    header, payload = CompactEncoder(position_error=ERROR).encode(
        7, {"positions": ball(400, seed=5), "densities": np.full(400, 1000.0, np.float32)}
    )
    first = header["arrays"][0]["bytes"]

    def edit(index: int, **changes: Any) -> dict[str, Any]:
        edited = copy.deepcopy(header)
        edited["arrays"][index].update(changes)
        return edited

    corrupt = bytearray(payload)
    corrupt[first // 2 : first // 2 + 6] = b"\x55" * 6
    lo, hi = header["arrays"][0]["bounds"]
    cases = [
        ("truncated", header, payload[:-5], "arrays[1].bytes"),
        ("corrupted", header, bytes(corrupt), "arrays[0].bytes"),
        ("sizes that lie", edit(0, bytes=first - 3), payload, "payload_length"),
        ("width that lies", edit(0, width=8), payload, "arrays[0].bytes"),
        ("bounds without the particles", edit(0, bounds=[lo, [hi[0] - 0.1, *hi[1:]]]), payload,
         "positions["),
        ("no encoding of that name", {**header, "encoding": "zfp"}, payload, "header.encoding"),
    ]  # fmt: skip
    for step in (0, -ERROR, "NaN"):  # a NaN literal is not JSON: the header is refused (§1)
        cases.append((f"step {step}", edit(0, step=step), payload, "arrays[0].step"))
    return cases


@pytest.mark.parametrize("case", range(9))
def test_bad_compact_frames_get_clear_errors_and_the_stream_goes_on(
    server: ServerProcess, case: int
) -> None:
    what, header, payload, field = _bad_frames()[case]
    with server.stream() as client:
        client.hello()
        client.send(encode_message(MessageType.FRAME, header, payload))
        kind, error, _ = answer(client)
        assert kind == MessageType.ERROR and error["id"] == 7, (what, error)
        assert error["field"].startswith(field) and error["code"] == "bad_input", (what, error)
        assert error["fatal"] is False
        client.frame(8, ball(200))
        assert answer(client)[0] == MessageType.IMAGE, what


def test_bad_compact_bodies_over_http_are_400_naming_the_field(server: ServerProcess) -> None:
    for what, header, payload, field in _bad_frames():
        body = encode_message(MessageType.FRAME, {**header, "scene": SMALL_SCENE}, payload)
        status, _headers, data = server.request(
            "POST", "/v1/render", body, {"Content-Type": FRAME_CONTENT_TYPE}
        )
        error = json.loads(data)
        assert status == 400 and error["field"].startswith(field), (what, status, error)
        assert not text_faults(error["error"]), error
    # A scene over the limit is refused before anything is decoded.
    header, payload = CompactEncoder(position_error=ERROR).encode(1, {"positions": ball(50)})
    body = encode_message(MessageType.FRAME, {**header, "scene": {"pad": "x" * 5000}}, payload)
    status, _headers, data = server.request(
        "POST", "/v1/render", body, {"Content-Type": FRAME_CONTENT_TYPE}
    )
    assert status == 413 and json.loads(data)["field"] == "scene", data
    # A delta frame over HTTP is refused: HTTP frames stand alone.
    header, payload = CompactEncoder(position_error=ERROR).encode(1, {"positions": ball(50)})
    body = encode_message(MessageType.FRAME, {**header, "base": 0}, payload)
    status, _headers, data = server.request(
        "POST", "/v1/render", body, {"Content-Type": FRAME_CONTENT_TYPE}
    )
    assert status == 400 and b"header.base" in data


def test_declared_particles_over_the_limit_are_refused_unread(server: ServerProcess) -> None:
    header, payload = CompactEncoder(position_error=ERROR).encode(9, {"positions": ball(100)})
    header["arrays"][0]["shape"] = [10**6, 3]
    with server.stream() as client:
        client.hello()
        client.send(encode_message(MessageType.FRAME, header, payload))
        kind, error, _ = answer(client)
        assert (kind, error["code"], error["field"]) == (
            MessageType.ERROR,
            "too_large",
            "arrays[0].shape",
        )
        client.send(encode_frame(10, ball(100)))
        assert answer(client)[0] == MessageType.IMAGE


def test_the_stream_reorders_unless_told_to_keep_the_order(server: ServerProcess) -> None:
    positions = ball(1500, seed=7)
    client = Client(f"http://127.0.0.1:{server.http_port}")
    cases: list[tuple[bool | Literal["ordered"], bool]] = [(True, True), ("ordered", False)]
    for compact, reordered in cases:
        with client.stream(RAW, compact=compact) as session:
            assert session.compact is not None
            session.send(positions)
            assert session.receive().kind == "image"
            assert (session.compact.encoder.order is not None) == reordered, compact
