"""PROTOCOL.md against a real server, point by point: error texts in the project's own words
(section 1), HTTP versions other than 1.0/1.1 refused (section 9), the image-size limit with
WELCOME's number and code (sections 4.4 and 5.1) on every path, and a degenerate camera named
as bad input."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import zipfile
from collections.abc import Iterator
from typing import Any

import pytest
from error_texts import text_faults
from service_harness import SMALL_SCENE, ServerProcess, ball
from test_service_hostile import expect_json_error, raw_http

from sphrender.core.errors import InputError, LimitError
from sphrender.core.npz_body import decode_npz_frame
from sphrender.core.protocol import (
    MessageType,
    encode_frame,
    encode_message,
    encode_npz_frame,
    parse_json_object,
)
from sphrender.server.scene import scene_from_dict
from sphrender.server.service.logs import LOGGING_ENV

MAX_PIXELS = 160 * 120
CONFIG: dict[str, dict[str, Any]] = {
    "limits": {"max_pixels": MAX_PIXELS, "max_particles": 10_000},
    "stream": {"message_timeout_s": 3.0},
}
HUGE = {"image": {"width": 16384, "height": 16384}}  # over the absolute cap of any server
OVER = {"image": {"width": 200, "height": 120}}  # over this server's limit only
FAR = {"camera": {"target": [1e308, 0.0, 0.0]}}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    with ServerProcess(tmp_path_factory.mktemp("conformance"), CONFIG) as process:
        yield process


def plain(error: dict[str, Any]) -> dict[str, Any]:
    assert text_faults(error.get("error")) == [], error
    return error


# -- section 1: error texts ------------------------------------------------------------------


@pytest.mark.parametrize(
    "data",
    [b"{", b'{"a": 1,}', b'{"a" 1}', b"[1] x", b'"\\q"', b"{" * 30000],
)
def test_json_errors_name_the_place_not_the_library(data: bytes) -> None:
    """Section 1: a header or scene that is not JSON is said in plain words."""
    with pytest.raises(InputError) as caught:
        parse_json_object(data, "header")
    assert caught.value.message.startswith("is not valid JSON")
    assert text_faults(caught.value.message) == []


@pytest.mark.parametrize(
    ("descr", "shown"),
    [("[('a', '<f8')]", "structured"), ("'|O'", "object"), ("'<c16'", "<c16")],
)
def test_npy_dtypes_are_named_without_python_quoting(descr: str, shown: str) -> None:
    header = f"{{'descr': {descr}, 'fortran_order': False, 'shape': (1,), }}"
    header += " " * (63 - (len(header) + 10) % 64) + "\n"
    npy = b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + bytes(16)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("positions.npy", npy)
    with pytest.raises(InputError) as caught:
        decode_npz_frame(buffer.getvalue(), max_particles=10, max_uncompressed_bytes=1 << 20)
    assert shown in caught.value.message
    assert text_faults(caught.value.message) == []


@pytest.mark.parametrize("value", ["1e3", "\u00b2", "0x10", " 1 2"])
def test_a_bad_content_length_is_quoted_as_json(server: ServerProcess, value: str) -> None:
    """Section 1 and 9: values written as JSON (`got "1e3"`), never Python-style."""
    data = f"POST /v1/render HTTP/1.1\r\nContent-Length: {value}\r\n\r\n".encode("latin-1")
    error = plain(expect_json_error(raw_http(server.http_port, data), 400, "bad_input"))
    assert error["field"] == "Content-Length"
    assert f"got {json.dumps(value.strip(), ensure_ascii=False)}" in error["error"]


@pytest.mark.parametrize(
    ("data", "status", "code"),
    [
        (b"GARBAGE\r\n\r\n", 400, "bad_input"),
        (b"GET / HTTP/1.1 x\r\n\r\n", 400, "bad_input"),
        (b"GET / FTP/1.1\r\n\r\n", 400, "bad_input"),
        (b"BREW /healthz HTTP/1.1\r\n\r\n", 405, "bad_input"),
        (b"GET /" + b"a" * 70000 + b" HTTP/1.1\r\n\r\n", 414, "too_large"),
        (b"GET /healthz HTTP/1.1\r\nX-A: " + b"b" * 70000 + b"\r\n\r\n", 431, "too_large"),
        (b"POST /v1/sessions HTTP/1.1\r\nContent-Length: 3\r\n\r\n{'a", 400, "bad_input"),
    ],
)
def test_the_standard_library_errors_are_in_this_apis_words(
    server: ServerProcess, data: bytes, status: int, code: str
) -> None:
    plain(expect_json_error(raw_http(server.http_port, data), status, code))


# -- section 9: HTTP versions ----------------------------------------------------------------


@pytest.mark.parametrize(
    "line",
    [b"GET /healthz", b"GET /healthz HTTP/0.9", b"GET /healthz HTTP/1.2", b"GET /healthz HTTP/2.0"],
)
def test_http_versions_but_1_0_and_1_1_get_400_unsupported_version(
    server: ServerProcess, line: bytes
) -> None:
    """Section 9: any version but 1.0/1.1 (HTTP/0.9's two-word request line included) is
    answered 400 unsupported_version, with a status line and headers, and the connection
    closes."""
    answer = raw_http(server.http_port, line + b"\r\n\r\n")
    error = plain(expect_json_error(answer, 400, "unsupported_version"))
    assert error["field"] == "version"
    assert answer[1]["connection"] == "close"
    for version in (b"HTTP/1.0", b"HTTP/1.1"):
        status, _headers, body = raw_http(
            server.http_port, b"GET /healthz " + version + b"\r\n\r\n"
        )
        assert (status, json.loads(body)) == (200, {"status": "ok"})


# -- sections 4.4 and 5.1: the image-size limit ----------------------------------------------


def _welcome_max_pixels(server: ServerProcess) -> int:
    with server.stream() as client:
        return int(client.hello()["limits"]["max_pixels"])


def _expect_too_large(error: dict[str, Any]) -> None:
    assert error["code"] == "too_large", error
    assert error["field"] == "image", error
    assert f"limit of {MAX_PIXELS} " in error["error"] and "limits.max_pixels" in error["error"]
    plain(error)


@pytest.mark.parametrize("size", [HUGE, OVER], ids=["16384x16384", "200x120"])
def test_a_hello_scene_over_max_pixels_is_too_large_with_welcomes_number(
    server: ServerProcess, size: dict[str, Any]
) -> None:
    assert _welcome_max_pixels(server) == MAX_PIXELS
    with server.stream() as client:
        client.send(encode_message(MessageType.HELLO, {"scene": {**SMALL_SCENE, **size}}))
        kind, header, _payload = client.receive()
        assert kind == MessageType.ERROR and header["fatal"], header
        _expect_too_large(header)


@pytest.mark.parametrize("size", [HUGE, OVER], ids=["16384x16384", "200x120"])
def test_a_frame_override_over_max_pixels_is_too_large_and_not_fatal(
    server: ServerProcess, size: dict[str, Any]
) -> None:
    with server.stream() as client:
        client.hello()
        client.send(encode_frame(1, ball(50), scene=size))
        client.frame(2, ball(50))
        kind, header, _payload = client.receive()
        assert kind == MessageType.ERROR and not header["fatal"] and header["id"] == 1
        _expect_too_large(header)
        assert client.receive()[0] == MessageType.IMAGE


def test_http_sessions_and_renders_over_max_pixels_are_413_too_large(
    server: ServerProcess,
) -> None:
    for size in (HUGE, OVER):
        scene = {**SMALL_SCENE, **size}
        status, error = server.json("POST", "/v1/sessions", scene)
        assert status == 413, error
        _expect_too_large(error)
        body = encode_npz_frame(ball(50), scene=scene)
        status, _headers, payload = server.request("POST", "/v1/render", body)
        assert status == 413, payload
        _expect_too_large(json.loads(payload))
        status, created = server.json("POST", "/v1/sessions", SMALL_SCENE)
        assert status == 201, created
        path = f"/v1/sessions/{created['id']}/frames"
        status, _headers, payload = server.request(
            "POST", path, encode_npz_frame(ball(50), scene=size)
        )
        assert status == 413, payload
        _expect_too_large(json.loads(payload))
        assert server.request("DELETE", f"/v1/sessions/{created['id']}")[0] == 204


def test_the_scene_check_uses_the_servers_limit_first() -> None:
    with pytest.raises(LimitError) as caught:
        scene_from_dict(HUGE, max_pixels=MAX_PIXELS)
    assert caught.value.field == "image" and str(MAX_PIXELS) in caught.value.message
    with pytest.raises(InputError) as plain_error:
        scene_from_dict(HUGE)  # without a server: the absolute cap, as before
    assert not isinstance(plain_error.value, LimitError)


# -- a degenerate camera ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("scene", "field"),
    [
        (FAR, "camera.target"),
        ({"camera": {"eye": [0.0, -1e200, 0.0]}}, "camera.target"),
        ({"camera": {"up": [0.0, 1e308, 1e308]}}, "camera.up"),
        (
            {"lights": [{"type": "directional", "direction": [1e300, 1e300, 0.0]}]},
            "lights[0].direction",
        ),
    ],
)
def test_vectors_whose_length_overflows_are_bad_input(scene: dict[str, Any], field: str) -> None:
    with pytest.raises(InputError) as caught:
        scene_from_dict(scene)
    assert caught.value.field == field
    assert "overflows" in caught.value.message


def test_a_camera_target_at_1e308_is_bad_input_on_both_transports(server: ServerProcess) -> None:
    with server.stream() as client:
        client.hello()
        client.send(encode_frame(1, ball(50), scene=FAR))
        kind, header, _payload = client.receive()
        assert kind == MessageType.ERROR and header["field"] == "camera.target", header
        plain(header)
    body = encode_npz_frame(ball(50), scene={**SMALL_SCENE, **FAR})
    status, _headers, payload = server.request("POST", "/v1/render", body)
    assert status == 400 and json.loads(payload)["field"] == "camera.target", payload


# -- --log-json: warnings are log records ----------------------------------------------------

_WARN = """
import sys, warnings
import numpy as np
from sphrender.server.service import logs
if sys.argv[1] == "main":
    logs.configure_logging(json_lines=True, level="info")
else:
    logs.configure_inherited_logging()  # the render process's way
warnings.warn("a plain warning")
np.zeros(3) / np.zeros(3)  # numpy's RuntimeWarning, with its source line
"""


@pytest.mark.parametrize("process", ["main", "child"])
def test_python_warnings_are_json_log_lines(process: str) -> None:
    env = {**os.environ, LOGGING_ENV: json.dumps({"json_lines": True, "level": "info"})}
    done = subprocess.run(
        [sys.executable, "-c", _WARN, process], env=env, capture_output=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    records = [json.loads(line) for line in done.stderr.decode().splitlines()]
    assert [r["category"] for r in records] == ["UserWarning", "RuntimeWarning"]
    assert records[1]["event"] == "python_warning" and "divide" in records[1]["message"]


def test_values_from_the_request_are_shown_as_json(server: ServerProcess) -> None:
    """Section 1: an unknown path is quoted as a JSON string; a demo frame's scene that is not
    an object is named by its JSON kind, not a Python type."""
    status, error = server.json("GET", "/v1/nothing")
    assert (status, error["code"]) == (404, "not_found")
    assert '"/v1/nothing"' in plain(error)["error"]
    status, created = server.json("POST", "/v1/demo/sessions", {"image": SMALL_SCENE["image"]})
    assert status == 201, created
    frames = f"/v1/sessions/{created['id']}/frames"
    for value, kind in ((None, "null"), ([1], "an array")):
        status, _headers, payload = server.request(
            "POST",
            frames,
            json.dumps({"scene": value}).encode(),
            {"Content-Type": "application/json"},
        )
        error = plain(json.loads(payload))
        assert (status, error["field"]) == (400, "scene") and error["error"].endswith(kind)
    assert server.request("DELETE", f"/v1/sessions/{created['id']}")[0] == 204
