"""Encodings over a real `sphrender serve` (stream and HTTP), WELCOME's timeouts and resolved
scene, BYE's rule, and plain-words error texts over a fuzzed set of bad inputs.

Images are compared with renders of the same engine in the test process (`renderer`): the raw
float32 payload must equal the RenderedFrame bit for bit, and the rgba8 payload the PNG's codes.
"""

from __future__ import annotations

import json
import random
import re
import socket
from typing import Any

import numpy as np
import pytest
from fuzz_inputs import connection_input, frame_input, http_body
from service_harness import SMALL_SCENE, ServerProcess, ball
from test_encodings import decode

from sphrender.client.api import Client, decode_raw
from sphrender.core.frame import make_frame
from sphrender.core.protocol import (
    MessageType,
    encode_frame,
    encode_message,
    encode_npz_frame,
)
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import encode_for_scene
from sphrender.server.scene import Scene, scene_from_dict, scene_to_dict

#: What a Python repr or type name looks like inside an error text.
PYTHONISMS = re.compile(
    r"b'|b\"|np\.|numpy\.|<class|got (list|dict|str|int|float|NoneType|tuple|bool)\b|"
    r"\bNone\b|\bTrue\b|\bFalse\b|'[^']*'|Traceback|Error:|(got|shape) \(\d+,"
)


def test_stream_session_and_per_frame_encodings(
    service: ServerProcess, renderer: SurfaceRenderer
) -> None:
    positions = ball(800, seed=3)
    scene_dict = {**SMALL_SCENE, "output": {"format": "jpeg", "jpeg_quality": 80}}
    scene = scene_from_dict(scene_dict)
    rendered, _ = renderer.render(make_frame(positions), scene, depth=True, normals=True)
    with service.stream() as client:
        welcome = client.hello(scene_dict)
        assert welcome["scene"] == scene_to_dict(scene)  # defaults filled in
        assert welcome["scene"]["camera"]["up"] == [0.0, 1.0, 0.0]
        assert welcome["timeouts"]["idle_s"] == 60.0 and welcome["timeouts"]["message_s"] == 1.5
        assert welcome["timeouts"]["handshake_s"] == 3.0
        client.frame(1, positions)
        raw32 = {"output": {"format": "raw", "raw_type": "float32", "aovs": ["Z"]}}
        client.frame(2, positions, scene=raw32)
        client.frame(3, positions, scene={"output": {"format": "raw"}})
        client.frame(4, positions, scene={"output": {"format": "gif"}})
        client.frame(5, positions, scene={"output": {"format": "png"}})

        kind, header, payload = client.receive()
        assert (kind, header["id"], header["format"]) == (MessageType.IMAGE, 1, "jpeg")
        assert payload[:3] == b"\xff\xd8\xff" and payload[-2:] == b"\xff\xd9"
        assert "arrays" not in header

        kind, header, payload = client.receive()
        assert (kind, header["format"]) == (MessageType.IMAGE, "raw")
        assert header["arrays"] == [
            {"name": "rgba", "dtype": "<f4", "shape": [48, 64, 4]},
            {"name": "Z", "dtype": "<f4", "shape": [48, 64]},
        ]
        arrays = decode_raw(header["arrays"], payload)
        assert arrays["rgba"].tobytes() == rendered.rgba.tobytes()
        assert rendered.depth is not None and arrays["Z"].tobytes() == rendered.depth.tobytes()

        kind, header, rgba8 = client.receive()
        assert header["arrays"] == [{"name": "rgba", "dtype": "u1", "shape": [48, 64, 4]}]
        png_scene = scene_from_dict({**scene_dict, "output": {"format": "png"}})
        png = encode_for_scene(rendered, png_scene, "png")
        assert rgba8 == decode(png, ".png").astype(np.uint8).tobytes()

        kind, header, _ = client.receive()
        assert (kind, header["id"], header["code"]) == (MessageType.ERROR, 4, "bad_input")
        assert header["field"] == "output.format" and not header["fatal"]
        assert '"png", "exr", "jpeg", "raw", got "gif"' in header["error"]

        kind, header, payload = client.receive()
        assert (header["id"], header["format"], payload) == (5, "png", png)

        client.send(encode_message(MessageType.BYE, {"reason": "done"}))
        kind, header, _ = client.receive()
        assert (kind, header["code"], header["field"]) == (
            MessageType.ERROR,
            "protocol",
            "header.reason",
        )
        assert header["fatal"] and header["id"] is None
        assert client.closed_by_server()


def test_http_formats(service: ServerProcess, renderer: SurfaceRenderer) -> None:
    positions = ball(600, seed=4)
    scene_dict = {**SMALL_SCENE, "output": {"raw_type": "float16", "aovs": ["N"]}}
    body = encode_npz_frame(positions, scene=scene_dict)
    status, headers, data = service.request("POST", "/v1/render?format=raw", body)
    assert status == 200 and headers["Content-Type"] == "application/octet-stream"
    layout = json.loads(headers["X-Sphrender-Arrays"])
    assert [a["name"] for a in layout] == ["rgba", "N"]
    assert (headers["X-Sphrender-Width"], headers["X-Sphrender-Height"]) == ("64", "48")
    rendered, _ = renderer.render(
        make_frame(positions), scene_from_dict(scene_dict), depth=True, normals=True
    )
    arrays = decode_raw(layout, data)
    assert arrays["rgba"].tobytes() == rendered.rgba.astype(np.float16).tobytes()
    assert rendered.normals is not None
    assert arrays["N"].tobytes() == rendered.normals.astype(np.float16).tobytes()

    status, headers, data = service.request("POST", "/v1/render?format=jpeg", body)
    assert status == 200 and headers["Content-Type"] == "image/jpeg" and data[:2] == b"\xff\xd8"

    status, _headers, data = service.request("POST", "/v1/render?format=gif", body)
    error = json.loads(data)
    assert (status, error["field"], error["code"]) == (400, "format", "bad_input")
    assert error["error"] == "must be one of png, exr, jpeg, raw"

    client = Client(f"http://127.0.0.1:{service.http_port}")
    decoded = client.render_raw(positions, {**scene_dict, "output": {"raw_type": "rgba8"}})
    assert decoded["rgba"].dtype == np.uint8 and decoded["rgba"].shape == (48, 64, 4)
    jpeg = client.render(positions, SMALL_SCENE, format="jpeg")
    assert jpeg[:2] == b"\xff\xd8"


def test_welcome_scene_is_the_default_scene(service: ServerProcess) -> None:
    small = {"image": {"width": 64, "height": 48}}  # the shared server allows 320x240 at most
    with service.stream() as client:
        welcome = client.hello(small)
    assert welcome["scene"] == scene_to_dict(scene_from_dict(small))
    assert welcome["scene"]["camera"] == scene_to_dict(Scene())["camera"]
    assert welcome["limits"]["session_idle_timeout_s"] == 600.0  # HTTP sessions, kept apart


def _collect_errors(header: dict[str, Any], texts: list[str]) -> None:
    if "error" in header:
        texts.append(str(header["error"]))


def test_error_texts_are_plain_words(service: ServerProcess) -> None:
    """Error texts of a seeded set of bad stream frames, connections and HTTP bodies carry no
    Python repr (b'..', np.float32(..), <class ..>, 'quoted', None/True, tuples) and no type
    name ("got list")."""
    rng = random.Random(1414)
    texts: list[str] = []
    with service.stream() as client:
        client.hello()
        for frame_id in range(60):
            client.send(frame_input(rng, frame_id))
            _kind, header, _ = client.receive()
            _collect_errors(header, texts)
    for _ in range(40):
        data, needs_hello = connection_input(rng)
        with service.stream(timeout=10) as client:
            if needs_hello:
                client.hello()
            try:
                client.send(data)
                client.sock.shutdown(socket.SHUT_WR)
                while True:
                    _kind, header, _ = client.receive()
                    _collect_errors(header, texts)
            except (EOFError, OSError):
                pass
    for _ in range(30):
        status, _headers, data = service.request("POST", "/v1/render", http_body(rng))
        if status != 200:
            _collect_errors(json.loads(data), texts)
    # A few hand-made ones that used to leak reprs.
    specials = [
        encode_message(MessageType.FRAME, {"id": 9, "arrays": [[1]]}),
        encode_message(MessageType.FRAME, {"id": 9, "arrays": [{"name": "positions"}] * 2}),
        encode_frame(9, np.array([[0.0, np.inf, 0.0]])),
        encode_frame(9, ball(3), radii=np.array([1.0, -np.inf, 1.0], np.float32)),
        encode_frame(9, ball(3), scene={"camera": {"fov_y": "wide"}}),
        encode_frame(9, ball(3), scene={"image": []}),
        encode_frame(9, ball(3), scene={"output": {"format": None}}),
    ]
    with service.stream() as client:
        client.hello()
        for data in specials:
            client.send(data)
            _kind, header, _ = client.receive()
            _collect_errors(header, texts)
    with service.stream() as client:
        client.send(b"SPHX" + bytes(12))
        _kind, header, _ = client.receive()
        assert header["field"] == "magic" and "53 50 48 58" in header["error"]
        _collect_errors(header, texts)
    assert len(texts) > 80
    leaks = sorted({text for text in texts if PYTHONISMS.search(text)})
    assert not leaks, leaks
    for fragment in ("Infinity", "must be a number", "must be a table"):
        assert any(fragment in text for text in texts), fragment


@pytest.mark.parametrize(
    "header",
    [b'{"id": 1, "arrays": NaN}', b'{"id": 1, "scene": ' + b"[" * 17 + b"]" * 17 + b"}"],
    ids=["nan-literal", "17-levels"],
)
def test_unparseable_header_is_fatal_protocol(service: ServerProcess, header: bytes) -> None:
    """PROTOCOL.md §4.4: a header that cannot be parsed is a fatal `protocol` error naming
    `header` (16 levels of nesting are allowed, 17 are not)."""
    from fuzz_inputs import message

    with service.stream() as client:
        client.hello()
        client.send(message(MessageType.FRAME, header))
        kind, answer, _ = client.receive()
        assert (kind, answer["code"], answer["field"], answer["fatal"]) == (
            MessageType.ERROR,
            "protocol",
            "header",
            True,
        )
        assert client.closed_by_server()


def test_payload_length_mismatch_answers_that_frame(service: ServerProcess) -> None:
    """Payload longer than its arrays: `bad_input` naming `payload_length`, not fatal; shorter:
    the array that does not fit. The connection goes on."""
    good = encode_frame(1, ball(50))
    prefix, rest = bytearray(good[:16]), good[16:]
    longer = bytearray(prefix)
    longer[12:16] = (int.from_bytes(prefix[12:16], "little") + 8).to_bytes(4, "little")
    shorter = bytearray(prefix)
    shorter[12:16] = (int.from_bytes(prefix[12:16], "little") - 8).to_bytes(4, "little")
    with service.stream() as client:
        client.hello()
        client.send(bytes(longer) + rest + bytes(8))
        client.send(bytes(shorter) + rest[:-8])
        client.frame(2, ball(50))
        answers = [client.receive() for _ in range(3)]
    assert [(a[1].get("code"), a[1].get("field"), a[1].get("fatal")) for a in answers[:2]] == [
        ("bad_input", "payload_length", False),
        ("bad_input", "arrays[0].shape", False),
    ]
    assert answers[2][0] == MessageType.IMAGE and answers[2][1]["id"] == 2
