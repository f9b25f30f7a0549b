"""The hostile-network campaign's findings, each against a real server on loopback: inputs that
used to raise inside a decoder, 500s for client mistakes, HTML error pages, memory bombs,
slowloris, the shared session cap, and drain with a half-sent message."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import struct
import threading
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from service_harness import HOST, SMALL_SCENE, ServerProcess, StreamClient, ball

from sphrender.core.protocol import (
    MessageType,
    encode_frame,
    encode_message,
    encode_npz_frame,
)

CONFIG: dict[str, dict[str, Any]] = {
    "http": {
        "max_body_bytes": 8 << 20,
        "read_timeout_s": 5.0,
        "header_timeout_s": 3.0,
        "body_timeout_s": 5.0,
        "max_connections": 16,
        "health_connections": 2,
    },
    "stream": {"max_payload_bytes": 64 << 20, "message_timeout_s": 3.0, "max_connections": 4},
    "limits": {
        "max_particles": 200_000,
        "max_pixels": 320 * 240,
        "max_sessions": 4,
        "max_scene_bytes": 4096,
        "max_npz_entries": 8,
        "max_request_bytes": 16 << 20,
        "memory_budget_bytes": 64 << 20,
    },
}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    with ServerProcess(tmp_path_factory.mktemp("hostile"), CONFIG) as process:
        yield process


def threads_of(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/task"))


def raw_http(port: int, data: bytes, timeout: float = 10.0) -> tuple[int, dict[str, str], bytes]:
    """Send raw bytes, read one answer (status, headers, body)."""
    with socket.create_connection((HOST, port), timeout=timeout) as sock:
        sock.sendall(data)
        buffer = b""
        while b"\r\n\r\n" not in buffer:
            chunk = sock.recv(65536)
            if not chunk:
                break
            buffer += chunk
        head, _, body = buffer.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        headers = {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
        length = int(headers.get("content-length", "0"))
        while len(body) < length:
            chunk = sock.recv(65536)
            if not chunk:
                break
            body += chunk
        return status, headers, body


def expect_json_error(answer: tuple[int, dict[str, str], bytes], status: int, code: str) -> Any:
    got, headers, body = answer
    assert got == status, body
    assert headers["content-type"] == "application/json", headers
    error = json.loads(body)
    assert error["code"] == code, error
    assert set(error) == {"error", "field", "code"}
    return error


# -- decoders that used to raise ------------------------------------------------------------


def test_frame_with_a_list_dtype_is_bad_input_and_leaks_no_thread(server: ServerProcess) -> None:
    header = b'{"id":2,"arrays":[{"name":"positions","dtype":[],"shape":[1,3]}]}'
    bad = struct.pack("<4sBBHII", b"SPHR", 1, 2, 0, len(header), 24) + header + bytes(24)
    assert bad[:16].hex() == "53504852010200004100000018000000"  # the campaign's bytes
    before = threads_of(server.proc.pid)
    for _ in range(30):
        with server.stream() as client:
            client.hello()
            client.frame(1, ball(200))
            client.send(bad)
            client.frame(3, ball(200))
            kinds = [client.receive() for _ in range(3)]
            assert [k for k, _h, _p in kinds] == [
                MessageType.IMAGE,
                MessageType.ERROR,
                MessageType.IMAGE,
            ]
            error = kinds[1][1]
            assert (error["id"], error["code"], error["field"]) == (
                2,
                "bad_input",
                "arrays[0].dtype",
            )
            assert error["fatal"] is False
            client.send(encode_message(MessageType.BYE, {}))
            assert client.receive()[1] == {"reason": "bye"}
    deadline = time.monotonic() + 10
    while threads_of(server.proc.pid) > before + 2 and time.monotonic() < deadline:
        time.sleep(0.1)
    assert threads_of(server.proc.pid) <= before + 2


def test_empty_frames_render_over_both_transports(server: ServerProcess) -> None:
    """N = 0 is a valid frame (PROTOCOL.md 4.2); zero-size arrays once broke the hand-off to
    the renderer process."""
    empty = np.zeros((0, 3))
    with server.stream() as client:
        client.hello()
        client.frame(1, empty, radii=np.zeros(0, dtype=np.float32))
        kind, header, _payload = client.receive()
        assert (kind, header["id"], header["particles"]) == (MessageType.IMAGE, 1, 0)
    status, _headers, _body = server.request(
        "POST", "/v1/render", encode_npz_frame(empty, scene=SMALL_SCENE)
    )
    assert status == 200


HUGE = "1" + "0" * 400


def test_integers_beyond_float_range_are_400_not_500(server: ServerProcess) -> None:
    scene_text = '{"camera": {"near": ' + HUGE + "}}"
    body = encode_npz_frame(ball(100), scene=scene_text)
    status, _headers, payload = server.request("POST", "/v1/render", body)
    assert status == 400, payload
    assert "out of range" in json.loads(payload)["error"]
    status, _headers, payload = server.request("POST", "/v1/sessions", scene_text.encode())
    assert status == 400, payload
    with server.stream() as client:
        client.send(_raw_hello(b'{"scene": {"camera": {"near": ' + HUGE.encode() + b"}}}"))
        kind, header, _payload = client.receive()
        assert kind == MessageType.ERROR and header["fatal"] is True
        assert header["code"] in ("protocol", "bad_input"), header
        assert "out of range" in header["error"]
    scene = {**SMALL_SCENE, "camera": {**SMALL_SCENE["camera"], "near": 1e300}}
    status, _headers, payload = server.request(
        "POST", "/v1/render", encode_npz_frame(ball(10), scene=scene)
    )
    assert status in (200, 400), payload  # finite: the scene's own rules decide, never a 500


def _raw_hello(header: bytes) -> bytes:
    return struct.pack("<4sBBHII", b"SPHR", 1, 1, 0, len(header), 0) + header


@pytest.mark.parametrize("expect", [False, True])
def test_unicode_digit_content_length_is_400(server: ServerProcess, expect: bool) -> None:
    head = "POST /v1/render HTTP/1.1\r\nHost: x\r\nContent-Length: ²\r\n"
    if expect:
        head += "Expect: 100-continue\r\n"
    answer = raw_http(server.http_port, (head + "\r\n").encode("utf-8"))
    error = expect_json_error(answer, 400, "bad_input")
    assert error["field"] == "Content-Length"


def test_npy_header_with_an_unclosed_brace_is_400(server: ServerProcess) -> None:
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), "
    header += " " * (63 - len(header) % 64) + "\n"
    npy = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + bytes(48)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("positions.npy", npy)
    status, _headers, payload = server.request("POST", "/v1/render", buffer.getvalue())
    assert status == 400, payload
    assert json.loads(payload)["field"] == "positions"


@pytest.mark.parametrize(
    ("data", "status", "code"),
    [
        (b"GARBAGE\r\n\r\n", 400, "bad_input"),
        (b"GET /" + b"a" * 70000 + b" HTTP/1.1\r\n\r\n", 414, "too_large"),
        (b"GET /healthz HTTP/1.1\r\n" + b"X-A: b\r\n" * 120 + b"\r\n", 431, "too_large"),
        (b"BREW /healthz HTTP/1.1\r\n\r\n", 405, "bad_input"),  # stdlib: 501
        (b"GET /healthz HTTP/2.0\r\n\r\n", 400, "unsupported_version"),  # stdlib: 505
    ],
)
def test_every_http_error_is_json(
    server: ServerProcess, data: bytes, status: int, code: str
) -> None:
    expect_json_error(raw_http(server.http_port, data), status, code)


# -- memory: checked before bytes are read or allocated -------------------------------------


def test_zip_with_many_entries_is_refused_before_it_is_parsed(server: ServerProcess) -> None:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("positions.npy", b"")
        for index in range(2000):
            archive.writestr(f"e{index}", b"")
    status, _headers, payload = server.request("POST", "/v1/render", buffer.getvalue())
    assert status == 413, payload
    assert "at most 8" in json.loads(payload)["error"]


def test_compressed_bomb_is_refused_by_the_memory_estimate(server: ServerProcess) -> None:
    body = encode_npz_frame(np.zeros((190_000, 3)), scene=SMALL_SCENE, compress=True)
    assert len(body) < 100_000
    status, _headers, payload = server.request("POST", "/v1/render", body)
    assert status == 413, payload
    error = json.loads(payload)
    assert "limits.max_request_bytes" in error["error"] and "MiB" in error["error"]


def test_scene_text_over_the_limit_is_413(server: ServerProcess) -> None:
    scene = {"camera": {"fov_y": 40.0}, "pad": "x" * 5000}
    status, _headers, payload = server.request(
        "POST", "/v1/render", encode_npz_frame(ball(10), scene=scene)
    )
    assert status == 413, payload
    assert json.loads(payload)["field"] == "scene"


def test_stream_payload_is_judged_before_it_is_read(server: ServerProcess) -> None:
    """A header declaring 1 particle with a 60 MB payload is answered at once; the payload is
    dropped as it arrives, never held."""
    header = b'{"id":5,"arrays":[{"name":"positions","dtype":"<f8","shape":[1,3]}]}'
    with server.stream() as client:
        client.hello()
        client.send(struct.pack("<4sBBHII", b"SPHR", 1, 2, 0, len(header), 60 << 20) + header)
        kind, answer, _payload = client.receive()  # before a byte of payload was sent
        assert kind == MessageType.ERROR and answer["field"] == "payload_length"
        chunk = bytes(1 << 20)
        for _ in range(60):
            client.send(chunk)
        client.frame(6, ball(300))
        kind, answer, _payload = client.receive()
        assert (kind, answer["id"]) == (MessageType.IMAGE, 6)


# -- caps and slow clients ------------------------------------------------------------------


def test_idle_http_sessions_do_not_block_streams(server: ServerProcess) -> None:
    created = []
    for _ in range(CONFIG["limits"]["max_sessions"]):
        status, body = server.json("POST", "/v1/sessions", SMALL_SCENE)
        assert status == 201
        created.append(body["id"])
    assert server.json("POST", "/v1/sessions", SMALL_SCENE)[0] == 503
    try:
        with server.stream() as client:
            client.hello()
            client.frame(1, ball(300))
            assert client.receive()[0] == MessageType.IMAGE
    finally:
        for session in created:
            server.request("DELETE", f"/v1/sessions/{session}")


def test_slowloris_does_not_block_health_or_renders(server: ServerProcess) -> None:
    stop = threading.Event()
    sockets: list[socket.socket] = []
    for _ in range(64):
        try:
            sockets.append(socket.create_connection((HOST, server.http_port), timeout=5))
        except OSError:
            break

    def dribble() -> None:
        request = b"POST /v1/render HTTP/1.1\r\nHost: x\r\n"
        for byte in request:
            if stop.wait(0.2):
                return
            for sock in list(sockets):
                try:
                    sock.send(bytes([byte]))
                except OSError:
                    sockets.remove(sock)

    thread = threading.Thread(target=dribble, daemon=True)
    thread.start()
    try:
        time.sleep(1.0)
        body = encode_npz_frame(ball(500), scene=SMALL_SCENE)
        for _ in range(3):
            start = time.monotonic()
            assert server.json("GET", "/healthz", timeout=5) == (200, {"status": "ok"})
            assert time.monotonic() - start < 1.0
            start = time.monotonic()
            status, _headers, _payload = server.request("POST", "/v1/render", body, timeout=5)
            assert status == 200
            assert time.monotonic() - start < 1.0 * 3  # a render on llvmpipe; far below 75 s
    finally:
        stop.set()
        thread.join(5)
        for sock in sockets:
            sock.close()


def test_stream_connections_stalled_before_hello_are_evicted(server: ServerProcess) -> None:
    stalled = [
        socket.create_connection((HOST, server.stream_port), timeout=5)
        for _ in range(CONFIG["stream"]["max_connections"])
    ]
    try:
        time.sleep(1.3)
        with StreamClient(server.stream_port, 10) as client:
            client.hello()
            client.frame(1, ball(300))
            assert client.receive()[0] == MessageType.IMAGE
    finally:
        for sock in stalled:
            sock.close()


def test_drain_does_not_wait_for_a_half_sent_message(tmp_path: Path) -> None:
    config = {"lifecycle": {"drain_read_timeout_s": 1.0}, "stream": {"message_timeout_s": 30.0}}
    with ServerProcess(tmp_path / "drain", config) as process:
        client = process.stream()
        client.hello()
        client.frame(1, ball(300))
        assert client.receive()[0] == MessageType.IMAGE
        frame = encode_frame(2, ball(300))
        client.send(frame[: len(frame) // 2])
        time.sleep(0.3)
        start = time.monotonic()
        process.proc.send_signal(signal.SIGTERM)
        kind, header, _payload = client.receive()
        assert (kind, header) == (MessageType.GOODBYE, {"reason": "shutdown"})
        assert process.proc.wait(20) == 0
        assert time.monotonic() - start < 6
        client.close()


def _status_bytes(pid: int, key: str) -> int:
    with open(f"/proc/{pid}/status") as handle:
        for line in handle:
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    raise AssertionError(key)


def _renderer_pid(pid: int) -> int:
    for tid in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{tid}/children") as handle:
            found = handle.read().split()
        if found:
            return int(found[0])
    raise AssertionError("no renderer process")


def test_peak_memory_of_bombs_stays_within_the_documented_budget(tmp_path: Path) -> None:
    """The campaign's bombs against a fresh server: refused ones do not move the peak RSS
    beyond the bytes received; an accepted deflate bomb stays within its estimate
    (PROTOCOL.md 5.1: bytes + particles x 640 + pixels x 120)."""
    config = {
        "http": {"max_body_bytes": 64 << 20},
        "stream": {"max_payload_bytes": 255 << 20},
        "limits": {"max_particles": 400_000, "max_pixels": 320 * 240},
    }
    with ServerProcess(tmp_path / "bombs", config) as process:
        pid = process.proc.pid
        renderer = _renderer_pid(pid)
        start = _status_bytes(pid, "VmHWM")
        # 1. a zip of 100 000 empty entries: refused from its directory record
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w") as archive:
            archive.writestr("positions.npy", b"")
            for index in range(100_000):
                archive.writestr(f"e{index}", b"")
        body = buffer.getvalue()
        assert process.request("POST", "/v1/render", body)[0] == 413
        # 2. four streams announcing 255 MiB payloads for one particle: refused unread
        header = b'{"id":1,"arrays":[{"name":"positions","dtype":"<f8","shape":[1,3]}]}'
        clients = [process.stream() for _ in range(4)]
        for client in clients:
            client.hello()
            client.send(struct.pack("<4sBBHII", b"SPHR", 1, 2, 0, len(header), 255 << 20))
            client.send(header + bytes(1 << 20))
            assert client.receive()[1]["field"] == "payload_length"
        for client in clients:
            client.close()
        refused_peak = _status_bytes(pid, "VmHWM") - start
        assert refused_peak < 2 * len(body) + (16 << 20), refused_peak
        # 3. an accepted deflate bomb: 400 000 particles in a few kB
        render_start = _status_bytes(renderer, "VmRSS")
        service_start = _status_bytes(pid, "VmRSS")
        bomb = encode_npz_frame(np.zeros((400_000, 3)), scene=SMALL_SCENE, compress=True)
        assert len(bomb) < 50_000
        assert process.request("POST", "/v1/render", bomb, timeout=120)[0] == 200
        growth = (_status_bytes(pid, "VmHWM") - service_start) + (
            _status_bytes(renderer, "VmHWM") - render_start
        )
        estimate = len(bomb) + 400_000 * 640 + 64 * 48 * 120
        assert growth < estimate, (growth, estimate)
