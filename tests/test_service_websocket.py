"""The stream protocol over WebSocket (``GET /v1/stream``, PROTOCOL.md §10) against a real
`sphrender serve` on loopback.

Well-behaved traffic goes through the independent `websockets` client; hostile traffic through
`ws_client.RawWebSocket`, which builds frames byte by byte. Images over WebSocket are compared
byte for byte with the raw stream's answer to the same frame on the same server (the raw stream
is checked against the in-process renderer in test_service_stream.py), so the transport may
change nothing about a frame.
"""

from __future__ import annotations

import json
import random
import signal
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fuzz_inputs import Tally
from fuzz_ws_inputs import run_ws_connection_input, run_ws_frame_batch, ws_hello
from service_harness import SMALL_SCENE, ServerProcess, ball
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect
from websockets.typing import Subprotocol
from ws_client import PING, PONG, TEXT, RawWebSocket, frame_bytes, upgrade_request

from sphrender.core.protocol import (
    PREFIX,
    PREFIX_SIZE,
    MessageType,
    encode_frame,
    encode_message,
    parse_header,
    parse_prefix,
)

TOKEN = "websocket-test-token-0123"
BEARER = {"Authorization": f"Bearer {TOKEN}"}
TRAINER = "http://trainer.example:8000"
MAX_PAYLOAD = 65536
#: The largest WebSocket message: a stream message at the stream's limits (16 + header + payload).
MAX_MESSAGE = PREFIX_SIZE + 65536 + MAX_PAYLOAD
CONFIG = {
    "security": {"token": TOKEN, "allowed_origins": [TRAINER]},
    "stream": {
        "max_payload_bytes": MAX_PAYLOAD,
        "max_header_bytes": 65536,
        "idle_timeout_s": 3.0,
        "message_timeout_s": 2.0,
        "handshake_timeout_s": 2.0,
    },
}
HELLO = encode_message(MessageType.HELLO, {"scene": SMALL_SCENE})


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    with ServerProcess(tmp_path_factory.mktemp("ws"), CONFIG) as process:
        yield process


def decode(message: bytes | str) -> tuple[MessageType, dict[str, Any], bytes]:
    assert isinstance(message, bytes), "the server sends binary messages only"
    kind, hlen, plen = parse_prefix(
        message[:PREFIX_SIZE], max_header_bytes=1 << 20, max_payload_bytes=1 << 30
    )
    header = parse_header(message[PREFIX_SIZE : PREFIX_SIZE + hlen]) if hlen else {}
    assert len(message) == PREFIX_SIZE + hlen + plen
    return kind, header, message[PREFIX_SIZE + hlen :]


def ws_url(server: ServerProcess) -> str:
    return f"ws://127.0.0.1:{server.http_port}/v1/stream"


def hello(ws: ClientConnection, **fields: Any) -> dict[str, Any]:
    ws.send(encode_message(MessageType.HELLO, {"scene": SMALL_SCENE, **fields}))
    kind, header, _ = decode(ws.recv(timeout=60))
    assert kind == MessageType.WELCOME, header
    return header


def raw_stream_image(server: ServerProcess, frame: bytes) -> bytes:
    """The raw stream's answer to `frame` (the reference for the WebSocket's)."""
    with server.stream() as client:
        client.hello(token=TOKEN)
        client.send(frame)
        kind, header, payload = client.receive()
        assert kind == MessageType.IMAGE, header
        return payload


def raw_open(server: ServerProcess, **headers: str) -> RawWebSocket:
    ws = RawWebSocket(server.http_port)
    status, _fields, body = ws.open({**BEARER, **headers})
    assert status == 101, body
    return ws


def raw_hello(ws: RawWebSocket) -> None:
    ws.send_message(HELLO)
    kind, header, _ = ws.receive()
    assert kind == MessageType.WELCOME, header


def check_still_serving(server: ServerProcess) -> None:
    status, _h, _b = server.request("GET", "/healthz")
    assert status == 200
    with connect(ws_url(server), additional_headers=BEARER) as ws:
        hello(ws)
        ws.send(encode_frame(9, ball(300, seed=9)))
        assert decode(ws.recv(timeout=60))[0] == MessageType.IMAGE


# -- the transport carries the stream ----------------------------------------------------------


def test_hello_frame_image_over_websocket_equals_the_raw_stream(server: ServerProcess) -> None:
    frame = encode_frame(1, ball(800, seed=1))
    with connect(ws_url(server), additional_headers=BEARER, subprotocols=None) as ws:
        welcome = hello(ws)  # no token in HELLO: the upgrade carried it
        assert welcome["limits"]["max_payload_bytes"] == MAX_PAYLOAD
        ws.send(frame)
        kind, header, image = decode(ws.recv(timeout=60))
        assert kind == MessageType.IMAGE, header
        assert (header["id"], header["format"], header["width"]) == (
            1,
            "png",
            SMALL_SCENE["image"]["width"],
        )
        ws.send(encode_message(MessageType.BYE, {}))
        kind, header, _ = decode(ws.recv(timeout=10))
        assert (kind, header["reason"]) == (MessageType.GOODBYE, "bye")
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1000
    assert image == raw_stream_image(server, frame)


def test_subprotocol_is_selected_when_offered(server: ServerProcess) -> None:
    with connect(
        ws_url(server), additional_headers=BEARER, subprotocols=[Subprotocol("sphrender.stream.v1")]
    ) as ws:
        assert ws.subprotocol == "sphrender.stream.v1"
        hello(ws)


def test_fragmented_messages_with_a_ping_between_fragments(server: ServerProcess) -> None:
    """RFC 6455 5.4: a message may come in any number of frames, control frames between."""
    frame = encode_frame(2, ball(800, seed=2))
    expected = raw_stream_image(server, frame)
    with raw_open(server) as ws:
        ws.send_message(HELLO, fragments=5)
        assert ws.receive()[0] == MessageType.WELCOME
        step = len(frame) // 9 + 1
        parts = [frame[i : i + step] for i in range(0, len(frame), step)]
        for i, part in enumerate(parts):
            ws.send(frame_bytes(0x2 if i == 0 else 0x0, part, fin=i == len(parts) - 1))
            if i == 3:
                ws.send(frame_bytes(PING, b"between"))
        opcode, _fin, payload = ws.read_frame()
        assert (opcode, payload) == (PONG, b"between")
        kind, header, image = ws.receive()
        assert kind == MessageType.IMAGE, header
        assert image == expected
    with connect(ws_url(server), additional_headers=BEARER) as lib:  # the library's fragments
        hello(lib)
        lib.send([frame[:7], frame[7:1000], frame[1000:]])
        assert decode(lib.recv(timeout=60))[2] == expected


def test_latest_mode_drops_superseded_frames_over_websocket(server: ServerProcess) -> None:
    count = 12
    scene = {**SMALL_SCENE, "image": {"width": 160, "height": 120}}
    with connect(ws_url(server), additional_headers=BEARER) as ws:
        ws.send(encode_message(MessageType.HELLO, {"scene": scene, "mode": "latest"}))
        assert decode(ws.recv(timeout=60))[1]["mode"] == "latest"
        frames = [encode_frame(i, ball(2000, seed=i)) for i in range(count)]

        def send_all() -> None:
            for data in frames:
                ws.send(data)

        sender = threading.Thread(target=send_all)
        sender.start()
        answers = [decode(ws.recv(timeout=60)) for _ in range(count)]
        sender.join(30)
    assert [h["id"] for _k, h, _p in answers] == list(range(count))
    kinds = [k for k, _h, _p in answers]
    assert set(kinds) <= {MessageType.IMAGE, MessageType.DROPPED}
    assert kinds.count(MessageType.DROPPED) >= 1
    assert kinds[-1] == MessageType.IMAGE


# -- refused before the upgrade: the API's JSON errors ------------------------------------------


def refusal(server: ServerProcess, headers: dict[str, str], before: bytes = b"") -> Any:
    with RawWebSocket(server.http_port) as ws:
        status, fields, body = ws.open(headers, before=before)
    assert status != 101
    assert fields["content-type"] == "application/json"
    return status, fields, json.loads(body)


def test_origins_not_allowed_are_refused_before_the_upgrade(server: ServerProcess) -> None:
    for origin in ("http://evil.example", "null", f"http://127.0.0.1:{server.http_port + 1}"):
        status, _f, body = refusal(server, {**BEARER, "Origin": origin})
        assert (status, body["code"], body["field"]) == (403, "unauthorized", "Origin"), origin
        assert "security.allowed_origins" in body["error"]
    for origin in (TRAINER, f"http://127.0.0.1:{server.http_port}"):  # listed; the server's own
        raw_open(server, Origin=origin).close()


def test_bad_token_is_refused_before_the_upgrade(server: ServerProcess) -> None:
    for headers in ({}, {"Authorization": "Bearer wrong-token-0123456789"}):
        status, fields, body = refusal(server, headers)
        assert (status, body["code"], body["field"]) == (401, "unauthorized", "Authorization")
        assert fields["www-authenticate"].startswith("Bearer")
    # The viewer's cookie is the browser's credential (a page cannot set Authorization).
    with RawWebSocket(server.http_port) as ws:
        status, _f, _b = ws.open({"Cookie": f"sphrender_token={TOKEN}"})
        assert status == 101
        raw_hello(ws)
    # A token in HELLO is still checked when present.
    with raw_open(server) as ws:
        ws.send_message(encode_message(MessageType.HELLO, {"token": "not-the-token-at-all"}))
        seen, close = ws.until_close()
    assert [(k, h["code"], h["field"]) for k, h, _p in seen] == [
        (MessageType.ERROR, "unauthorized", "token")
    ]
    assert close[1] == 1008


def test_bad_upgrade_headers_are_json_errors(server: ServerProcess) -> None:
    cases = [
        ({"Upgrade": "h2c"}, 426, "Upgrade"),
        ({"Connection": "keep-alive"}, 400, "Connection"),
        ({"Sec-WebSocket-Version": "8"}, 426, "Sec-WebSocket-Version"),
        ({"Sec-WebSocket-Key": "c2hvcnQ="}, 400, "Sec-WebSocket-Key"),
    ]
    for headers, status, field in cases:
        got, fields, body = refusal(server, {**BEARER, **headers})
        assert (got, body["field"]) == (status, field), body
    got, fields, _b = refusal(server, {**BEARER, "Sec-WebSocket-Version": "8"})
    assert fields["sec-websocket-version"] == "13"


def test_garbage_before_the_handshake_is_a_json_400(server: ServerProcess) -> None:
    status, _f, body = refusal(server, BEARER, before=b"\x16\x03\x01garbage\r\n")
    assert (status, body["code"]) == (400, "bad_input")


# -- after the upgrade: Close codes with reasons -------------------------------------------------


def test_unmasked_client_frame_closes_1002(server: ServerProcess) -> None:
    with raw_open(server) as ws:
        ws.send(frame_bytes(0x2, HELLO, mask=False))
        seen, close = ws.until_close()
        assert ws.closed_after()
    assert seen == []
    assert close[1] == 1002 and "masked" in close[2]


def test_garbage_after_the_handshake_closes_1002(server: ServerProcess) -> None:
    with raw_open(server) as ws:  # an HTTP request where a frame should be: reserved bits set
        ws.send(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
        _seen, close = ws.until_close()
    assert close[1] == 1002 and "RFC 6455" in close[2]
    with raw_open(server) as ws:  # a binary message that is no stream message
        ws.send_message(b"not a stream message at all")
        seen, close = ws.until_close()
    assert [(k, h["code"]) for k, h, _p in seen] == [(MessageType.ERROR, "protocol")]
    assert close[1] == 1002 and "magic" in close[2]
    with raw_open(server) as ws:  # text messages carry nothing here
        ws.send(frame_bytes(TEXT, b'{"hello": 1}'))
        _seen, close = ws.until_close()
    assert close[1] == 1003 and "binary" in close[2]
    with raw_open(server) as ws:  # two stream messages in one WebSocket message
        raw_hello(ws)
        ws.send_message(encode_frame(1, ball(50)) + encode_frame(2, ball(50)))
        seen, close = ws.until_close()
    assert close[1] == 1002 and "exactly one binary WebSocket message" in close[2]


def test_oversized_messages_close_1009(server: ServerProcess) -> None:
    with raw_open(server) as ws:  # a stream message declaring a payload over the limit
        raw_hello(ws)
        ws.send_message(PREFIX.pack(b"SPHR", 1, int(MessageType.FRAME), 0, 2, MAX_PAYLOAD + 1))
        seen, close = ws.until_close()
    assert [(k, h["code"]) for k, h, _p in seen] == [(MessageType.ERROR, "too_large")]
    assert close[1] == 1009 and str(MAX_PAYLOAD) in close[2]
    with raw_open(server) as ws:  # a WebSocket message over the limit, whatever it holds
        raw_hello(ws)
        ws.send_message(encode_frame(3, ball(50)) + bytes(MAX_MESSAGE), fragments=3)
        seen, close = ws.until_close()
    assert {k for k, _h, _p in seen} <= {MessageType.IMAGE}
    assert close[1] == 1009 and f"limit of {MAX_MESSAGE} bytes" in close[2]
    check_still_serving(server)


def test_idle_and_slow_clients_follow_the_streams_timeouts(server: ServerProcess) -> None:
    with raw_open(server) as ws:  # no HELLO within handshake_timeout_s
        seen, close = ws.until_close()
    assert [(k, h["code"]) for k, h, _p in seen] == [(MessageType.ERROR, "timeout")]
    assert close[1] == 1008
    with raw_open(server) as ws:  # idle after WELCOME: GOODBYE after idle_timeout_s
        raw_hello(ws)
        started = time.monotonic()
        seen, close = ws.until_close()
        assert time.monotonic() - started >= 2.5
    assert [(k, h.get("reason")) for k, h, _p in seen] == [(MessageType.GOODBYE, "idle_timeout")]
    assert close[1] == 1000
    with raw_open(server) as ws:  # half a message, then silence: message_timeout_s
        raw_hello(ws)
        ws.send(frame_bytes(0x2, encode_frame(4, ball(50))[:20], fin=False))
        seen, close = ws.until_close()
    assert [(k, h["code"]) for k, h, _p in seen] == [(MessageType.ERROR, "timeout")]
    assert close[1] == 1008 and "message_timeout_s" in close[2]
    with raw_open(server) as ws:  # a frame's head without its data: the message has begun
        raw_hello(ws)
        ws.send(frame_bytes(0x2, bytes(100))[:6])
        seen, close = ws.until_close()
    assert [(k, h["code"]) for k, h, _p in seen] == [(MessageType.ERROR, "timeout")]
    assert close[1] == 1008 and "message_timeout_s" in close[2]


def test_close_from_the_client_ends_the_session(server: ServerProcess) -> None:
    with raw_open(server) as ws:
        raw_hello(ws)
        ws.send(frame_bytes(0x8, struct.pack("!H", 1000) + b"done"))
        _seen, close = ws.until_close()
        assert close[1] == 1000
        assert ws.closed_after()
    check_still_serving(server)


def test_metrics_count_the_upgrades(server: ServerProcess) -> None:
    text = server.metrics_text(BEARER)
    assert 'route="/v1/stream",code="101"' in text
    assert 'route="/v1/stream",code="403"' in text


def test_watch_pushes_a_sessions_images_until_it_ends(server: ServerProcess) -> None:
    with RawWebSocket(server.http_port) as ws:  # unknown session: 404 before any upgrade
        ws.sock.sendall(upgrade_request(server.http_port, f"/v1/sessions/{'0' * 32}/watch", BEARER))
        status, _f, body = ws.read_answer()
    assert (status, json.loads(body)["field"]) == (404, "session")
    with server.stream() as client:
        session = client.hello(token=TOKEN)["session"]
        with RawWebSocket(server.http_port) as watcher:
            watcher.sock.sendall(
                upgrade_request(server.http_port, f"/v1/sessions/{session}/watch", BEARER)
            )
            assert watcher.read_answer()[0] == 101
            images = []
            for frame_id in (1, 2):
                client.frame(frame_id, ball(400, seed=frame_id))
                kind, _header, image = client.receive()
                assert kind == MessageType.IMAGE
                images.append(image)
                pushed_kind, pushed, data = watcher.receive()
                assert (pushed_kind, pushed["image"], pushed["session"]) == (
                    MessageType.IMAGE,
                    frame_id,
                    session,
                )
                assert data == image
            client.send(encode_message(MessageType.BYE, {}))
            assert client.receive()[1] == {"reason": "bye"}
            seen, close = watcher.until_close()
    assert [(k, h) for k, h, _p in seen] == [(MessageType.GOODBYE, {"reason": "session_closed"})]
    assert close[1] == 1000


def test_seeded_hostile_inputs_each_end_clearly(server: ServerProcess) -> None:
    """A bounded run of the campaign's WebSocket inputs (benchmarks/fuzz_campaign.py
    --websocket): every connection ends with a JSON error or a documented Close code and a
    clear reason, promptly; pipelined fragmented bad FRAMEs get one non-fatal answer each."""
    tally = Tally()
    rng = random.Random(20261206)
    for _ in range(90):
        run_ws_connection_input(server.http_port, TOKEN, rng, tally, MAX_MESSAGE)
    ws = ws_hello(server.http_port, TOKEN, rng)
    for batch in range(4):
        run_ws_frame_batch(ws, rng, 1 + 8 * batch, 8, tally)
    ws.close()
    assert (tally.hangs, tally.bad_texts, tally.server_errors) == (0, 0, 0), tally.notes
    assert tally.texts >= 90
    check_still_serving(server)


def test_drain_says_goodbye_on_websockets_and_exits_0(tmp_path: Path) -> None:
    """SIGTERM: a WebSocket stream gets GOODBYE shutdown and Close 1001, a watcher Close 1001,
    and the process still exits 0 (the drain reaches connections of both transports)."""
    with ServerProcess(tmp_path, CONFIG) as process:
        stream = raw_open(process)
        raw_hello(stream)
        stream.send_message(encode_frame(1, ball(300)))
        assert stream.receive()[0] == MessageType.IMAGE
        session = process.json("GET", "/v1/status", headers=BEARER)[1]["session_list"][0]["id"]
        watcher = RawWebSocket(process.http_port)
        path = f"/v1/sessions/{session}/watch"
        watcher.sock.sendall(upgrade_request(process.http_port, path, BEARER))
        assert watcher.read_answer()[0] == 101
        assert watcher.receive()[0] == MessageType.IMAGE  # the latest, at once
        process.proc.send_signal(signal.SIGTERM)
        seen, close = stream.until_close()
        assert [(k, h) for k, h, _p in seen] == [(MessageType.GOODBYE, {"reason": "shutdown"})]
        assert close[1] == 1001
        assert watcher.until_close()[1][1] == 1001
        assert process.proc.wait(60) == 0
        stream.close()
        watcher.close()


def test_frames_sent_with_the_upgrade_request_are_kept(server: ServerProcess) -> None:
    """A client that does not wait for the 101 (RFC 6455 says it should): the frames that came
    in the same packets as its request are the start of the WebSocket, not lost."""
    with RawWebSocket(server.http_port) as ws:
        hello = frame_bytes(0x2, HELLO)
        ws.send(upgrade_request(server.http_port, headers=BEARER) + hello)
        assert ws.read_answer()[0] == 101
        assert ws.receive()[0] == MessageType.WELCOME
