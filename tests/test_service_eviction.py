"""Idle stream sessions do not lock other clients out (PROTOCOL.md §5 connection limit, §4.6
GOODBYE ``evicted``, §4.1 ``timeouts.evict_idle_s``): with every ``max_stream_connections`` slot
held by sessions that said HELLO and nothing else, a new client is refused ``busy`` for at most
``evict_idle_s``, then the session idle longest gets GOODBYE ``evicted`` and the newcomer its
WELCOME. A session that keeps sending frames is never the one closed. Real server, cap of 4."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

from service_harness import SMALL_SCENE, ServerProcess, StreamClient, ball

from sphrender.core.protocol import MessageType, encode_message

EVICT_IDLE_S = 1.0
CONFIG: dict[str, dict[str, Any]] = {
    "stream": {"max_connections": 4, "evict_idle_s": EVICT_IDLE_S, "idle_timeout_s": 120.0},
}


def try_hello(server: ServerProcess) -> tuple[StreamClient, MessageType, dict[str, Any]]:
    """Connect and say HELLO; the answer is WELCOME or a fatal ERROR busy."""
    client = server.stream(timeout=30)
    client.send(encode_message(MessageType.HELLO, {"scene": SMALL_SCENE}))
    try:
        kind, header, _payload = client.receive()
    except (EOFError, ConnectionError):
        return client, MessageType.ERROR, {"code": "closed"}
    return client, kind, header


def test_idle_sessions_keep_a_new_client_out_for_at_most_evict_idle_s(tmp_path: Path) -> None:
    with ServerProcess(tmp_path / "server", CONFIG) as server:
        # An active session: a frame every 0.2 s all along; it is never the one evicted.
        active = server.stream(timeout=30)
        welcome = active.hello(SMALL_SCENE)
        assert welcome["timeouts"]["evict_idle_s"] == EVICT_IDLE_S
        stop = threading.Event()
        kinds: list[MessageType] = []

        def keep_sending() -> None:
            frame_id = 0
            while not stop.is_set():
                frame_id += 1
                active.frame(frame_id, ball(200))
                kinds.append(active.receive()[0])
                time.sleep(0.2)

        sender = threading.Thread(target=keep_sending, daemon=True)
        sender.start()
        # 64 misbehaving clients: HELLO, then nothing. With 3 slots left, most are refused busy.
        idle: list[StreamClient] = []
        refused = 0
        for _ in range(64):
            client, kind, header = try_hello(server)
            if kind == MessageType.WELCOME:
                idle.append(client)
            else:
                assert header["code"] in ("busy", "closed"), header
                refused += 1
                client.close()
        assert idle and refused  # the cap was full
        # A well-behaved client retrying on busy gets in within evict_idle_s (and slack).
        start = time.monotonic()
        while True:
            client, kind, header = try_hello(server)
            if kind == MessageType.WELCOME:
                break
            assert header["code"] in ("busy", "closed"), header
            if header["code"] == "busy":
                assert "stream.evict_idle_s" in header["error"]
            client.close()
            assert time.monotonic() - start < EVICT_IDLE_S + 5, "locked out by idle sessions"
            time.sleep(0.1)
        waited = time.monotonic() - start
        client.frame(1, ball(200))
        assert client.receive()[0] == MessageType.IMAGE
        client.close()
        # The idle ones that made room were told why (§4.6), then closed.
        evicted = 0
        for old in idle:
            old.sock.settimeout(0.5)
            try:
                kind, header, _payload = old.receive()
            except TimeoutError:
                continue
            assert (kind, header) == (MessageType.GOODBYE, {"reason": "evicted"})
            assert old.closed_by_server()
            evicted += 1
        assert evicted >= 1, waited
        stop.set()
        sender.join(10)
        assert kinds and set(kinds) == {MessageType.IMAGE}
        active.close()
        for old in idle:
            old.close()
