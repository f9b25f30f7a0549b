"""Seeded hostile inputs for the WebSocket transport (``GET /v1/stream``) and the clients that
throw them at a real server (benchmarks/fuzz_campaign.py ``--websocket``).

* **frame-level** (`run_ws_frame_batch`): `fuzz_inputs.frame_input` FRAMEs, each one binary
  message split into random fragments with pings between them, pipelined on one connection:
  exactly one answer each, in order, never fatal;
* **connection-level** (`run_ws_connection_input`): one connection per input, one of
  `WS_KINDS`: refused upgrades (bad origin, bad token, bad headers, garbage instead of a
  request), then frames RFC 6455 forbids (unmasked, reserved bits, bad opcodes, long or
  fragmented control frames, stray continuations, bad Close frames), text messages, oversized
  messages, random bytes, and `fuzz_inputs.connection_input` stream garbage inside binary
  messages. The server must end each with the HTTP JSON error or a Close frame whose code is a
  documented one (PROTOCOL.md §10) and whose reason is a clear text, within the timeout.
"""

from __future__ import annotations

import contextlib
import json
import random
import struct
import time
from typing import Any

from fuzz_inputs import SCENE, Tally, connection_input, frame_input
from ws_client import BINARY, CLOSE, CONTINUATION, PING, TEXT, RawWebSocket, frame_bytes

from sphrender.core.protocol import PREFIX, MessageType, encode_frame, encode_message

#: The close codes PROTOCOL.md §10 documents.
CLOSE_CODES = {1000, 1001, 1002, 1003, 1007, 1008, 1009, 1011, 1013}
WS_KINDS = (
    "origin",
    "token",
    "headers",
    "garbage_request",
    "unmasked",
    "reserved",
    "opcode",
    "control",
    "continuation",
    "bad_close",
    "text",
    "oversized_declared",
    "oversized_message",
    "random_bytes",
    "stream_garbage",
)


def fragments(rng: random.Random, data: bytes) -> bytes:
    """`data` as one binary message in 1-6 masked frames, sometimes a ping between two."""
    count = rng.randrange(1, 7)
    cuts = sorted(rng.randrange(len(data) + 1) for _ in range(count - 1))
    parts = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
    out = []
    for i, part in enumerate(parts):
        out.append(frame_bytes(BINARY if i == 0 else CONTINUATION, part, fin=i == len(parts) - 1))
        if i < len(parts) - 1 and rng.random() < 0.3:
            out.append(frame_bytes(PING, b"p"))
    return b"".join(out)


def ws_hello(port: int, token: str, rng: random.Random, timeout: float = 10.0) -> RawWebSocket:
    ws = RawWebSocket(port, timeout)
    status, _fields, body = ws.open({"Authorization": f"Bearer {token}"})
    assert status == 101, body
    ws.send(fragments(rng, encode_message(MessageType.HELLO, {"scene": SCENE, "max_in_flight": 8})))
    answer = ws.receive()
    assert answer[0] == MessageType.WELCOME, answer
    return ws


def run_ws_frame_batch(
    ws: RawWebSocket, rng: random.Random, first_id: int, count: int, tally: Tally
) -> None:
    """As `fuzz_inputs.run_frame_batch`, over the WebSocket."""
    ws.send(b"".join(fragments(rng, frame_input(rng, first_id + i)) for i in range(count)))
    for i in range(count):
        try:
            answer = ws.receive()
        except TimeoutError:
            tally.hangs += 1
            tally.note(f"ws frame batch hang at id {first_id + i}")
            raise
        if answer[0] == "close":
            tally.note(f"ws frame {first_id + i}: closed {answer}")
            raise EOFError
        kind, header, _payload = answer
        if header.get("id") != first_id + i or kind not in (0x82, 0x83) or header.get("fatal"):
            tally.note(f"ws frame {first_id + i}: unexpected answer {kind:#x} {header}")
            raise EOFError
        if kind == 0x83:
            tally.check_text(header, f"ws frame {first_id + i}")
            if header.get("code") == "render_failed":
                tally.server_errors += 1
        else:
            tally.images += 1
    tally.inputs += count
    tally.stream_inputs += count


def _refused_upgrade(kind: str, port: int, token: str, rng: random.Random) -> dict[str, str]:
    auth = {"Authorization": f"Bearer {token}"}
    if kind == "origin":
        host = rng.choice(("evil.example", "127.0.0.1:1", "null", "localhost"))
        return {**auth, "Origin": f"http://{host}" if host != "null" else "null"}
    if kind == "token":
        return {"Authorization": rng.choice(("", "Bearer ", "Bearer x", f"Basic {token}"))}
    name = rng.choice(("Upgrade", "Connection", "Sec-WebSocket-Version", "Sec-WebSocket-Key"))
    value = rng.choice(("", "h2c", "8", "close", "AAAA", "\u00e9t\u00e9", "x" * 300))
    return {**auth, name: value}


def _after_upgrade(kind: str, rng: random.Random, max_message: int) -> bytes:
    """What a connection sends after a good HELLO (kinds from unmasked on)."""
    stream = encode_frame(1, [[0.0, 0.0, 0.0]] * rng.randrange(1, 40))
    if kind == "unmasked":
        return frame_bytes(BINARY, stream, mask=False)
    if kind == "reserved":
        return frame_bytes(BINARY, stream, rsv=rng.randrange(1, 8))
    if kind == "opcode":
        return frame_bytes(rng.choice((3, 4, 5, 6, 7, 11, 12, 13, 14, 15)), stream)
    if kind == "control":
        opcode = rng.choice((PING, CLOSE))
        if rng.random() < 0.5:
            return frame_bytes(opcode, bytes(rng.randrange(126, 400)))
        return frame_bytes(opcode, b"ab", fin=False) + frame_bytes(CONTINUATION, b"cd")
    if kind == "continuation":
        return frame_bytes(CONTINUATION, stream)
    if kind == "bad_close":
        return frame_bytes(
            CLOSE, rng.choice((b"\x03", struct.pack("!H", 999), b"\x03\xe8\xff\xfe", b"\x0b\xb8"))
        )
    if kind == "text":
        return frame_bytes(TEXT, json.dumps({"hello": 1}).encode())
    if kind == "oversized_declared":
        too_big = PREFIX.pack(b"SPHR", 1, 2, 0, 2, max_message) + b"{}"
        return fragments(rng, too_big)
    if kind == "oversized_message":
        return fragments(rng, stream + bytes(max_message))
    if kind == "random_bytes":
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
    data, _needs_hello = connection_input(rng)
    return fragments(rng, data)


def run_ws_connection_input(
    port: int, token: str, rng: random.Random, tally: Tally, max_message: int, timeout: float = 8.0
) -> None:
    kind = rng.choice(WS_KINDS)
    if kind in ("origin", "token", "headers", "garbage_request"):
        _run_refusal(kind, port, token, rng, tally, timeout)
    else:
        _run_after_upgrade(kind, port, token, rng, tally, max_message, timeout)
    tally.inputs += 1
    tally.stream_inputs += 1


def _run_refusal(
    kind: str, port: int, token: str, rng: random.Random, tally: Tally, timeout: float
) -> None:
    with RawWebSocket(port, timeout) as ws:
        try:
            if kind == "garbage_request":
                junk = bytes(rng.randrange(1, 256) for _ in range(rng.randrange(1, 80)))
                status, _f, body = ws.open({}, before=junk.replace(b"\n", b" ") + b"\r\n\r\n")
            else:
                status, _f, body = ws.open(_refused_upgrade(kind, port, token, rng))
        except (EOFError, ConnectionError):
            return  # closed without an answer: allowed for a request that is no request
        except TimeoutError:
            tally.hangs += 1
            tally.note(f"ws refusal hang ({kind})")
            return
    if status == 101 or status >= 500:
        tally.server_errors += status >= 500
        tally.note(f"ws {kind}: status {status}")
        return
    tally.check_text(json.loads(body), f"ws {kind} {status}")


def _run_after_upgrade(
    kind: str,
    port: int,
    token: str,
    rng: random.Random,
    tally: Tally,
    max_message: int,
    timeout: float,
) -> None:
    ws = ws_hello(port, token, rng)
    try:
        ws.sock.settimeout(timeout)
        # Then BYE: an input the server answers without closing (a FRAME error) ends with
        # GOODBYE and Close 1000 instead of waiting for the idle timeout.
        bye = frame_bytes(BINARY, encode_message(MessageType.BYE, {}))
        sent = _after_upgrade(kind, rng, max_message) + bye
        with contextlib.suppress(OSError):  # the server may close before taking it all
            ws.send(sent)
        start = time.monotonic()
        while True:
            try:
                answer: Any = ws.receive()
            except (TimeoutError, EOFError, ConnectionError) as exc:
                if isinstance(exc, TimeoutError):
                    tally.hangs += 1
                    tally.note(f"ws {kind}: no Close within {timeout} s after {sent[:48]!r}")
                else:
                    tally.note(f"ws {kind}: closed without a Close frame")
                    tally.bad_texts += 1
                return
            if answer[0] == "close":
                _check_close(kind, answer, tally)
                return
            if answer[0] == 0x83:
                tally.check_text(answer[1], f"ws {kind}")
            if time.monotonic() - start > timeout:
                tally.hangs += 1
                return
    finally:
        ws.close()


def _check_close(kind: str, answer: tuple[str, int, str], tally: Tally) -> None:
    _close, code, reason = answer
    if code not in CLOSE_CODES:
        tally.note(f"ws {kind}: undocumented close code {code} ({reason})")
        tally.bad_texts += 1
    if kind == "bad_close" and code == 1000:
        return  # a well-formed client Close is echoed
    tally.check_text({"error": reason}, f"ws {kind} close {code}")
