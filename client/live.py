"""A streaming session for producers that push frames: a simulator's step callback, a capture
thread, several threads at once. numpy + standard library only.

    def show(result: StreamResult) -> None:          # on the session's delivery thread
        if result.kind == "image":
            window.update(result.data)

    with LiveSession(client, scene, on_result=show) as live:
        simulator.on_step(lambda step: live.submit(step.positions, temperatures=step.kelvin))

`submit` is thread-safe and never waits for the network: it validates and copies the arrays (the
producer may overwrite them as soon as it returns), gives the frame an id and hands it to the
session's sender thread. Every frame `submit` accepted gets exactly one `StreamResult`:

* ``"image"`` or ``"error"`` (the server's answer to that frame: a bad override, a render failure);
  these arrive in the order the frames were sent, which is the order of their ids;
* ``"dropped"``, ``header["reason"]``: ``"superseded"`` (``latest`` mode: a newer frame took its
  place, in this client while it waited to be sent, ``header["local"]`` true, or in the server's
  queue before it began rendering), ``"closed"`` (`close` gave up waiting) or ``"disconnected"``
  (the connection ended before its answer; `error` says why). None of those was rendered.

Results go to ``on_result`` when given, called on one thread of the session's own
("sphrender-live-deliver"), one result at a time, so a slow callback delays later results but
never the socket; otherwise `poll` returns them. A session-level failure (a fatal ERROR, GOODBYE
from the server, a dropped connection) is kept in `error`, passed to ``on_error`` on the same
thread after the frames it cost were reported dropped, and raised (as `SessionClosed`) by the next
`submit`. An exception raised by a callback is logged and the session goes on.

Modes: ``"latest"`` (the default, for live viewing): at most ``max_in_flight`` frames (default 2)
are unanswered and one more waits in this client; a newer frame replaces the waiting one, so a
producer faster than the server sees its newest frame rendered next and never blocks. ``"queue"``:
every frame is rendered; `submit` waits while ``max_in_flight`` frames are unanswered and as many
wait to be sent (back-pressure on the producer).

Per-frame overrides: ``submit(..., scene={...})`` takes a partial scene laid over the session's for
that frame only (PROTOCOL.md §4.2), e.g. ``{"camera": {"eye": [x, y, z]}}`` for a moving camera,
``{"output": {"format": "jpeg"}}``; a bad override is answered ``"error"`` for that frame alone.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from sphrender.client.api import Client, ServerError, StreamResult, StreamSession
from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.core.protocol import ProtocolError

log = logging.getLogger("sphrender.client.live")

#: Unanswered frames a ``latest`` session allows by default: one rendering, one on its way.
LATEST_IN_FLIGHT = 2

ARRAY_NAMES = ("densities", "radii", "temperatures", "velocities", "ids")


class SessionClosed(Exception):
    """`submit` after the session ended: closed by the client, or failed (the cause is chained)."""


class SessionEnded(ConnectionError):
    """The server ended the session with GOODBYE ``reason`` (``idle_timeout``, ``shutdown``,
    ``evicted``: PROTOCOL.md §4.6); the frames it had not answered were not rendered."""

    def __init__(self, reason: str) -> None:
        super().__init__(f"the server ended the session: {reason}")
        self.reason = reason


@dataclass
class _Frame:
    id: int
    positions: np.ndarray
    arrays: dict[str, Any] = field(default_factory=dict)


def _dropped(frame_id: int, reason: str, *, local: bool = True) -> StreamResult:
    return StreamResult(frame_id, "dropped", {"id": frame_id, "reason": reason, "local": local})


def _snapshot(positions: object, scene: Mapping[str, Any] | None, arrays: dict[str, Any]) -> _Frame:
    """Validate the frame as the server would (a clear `InputError` now, on the producer's thread)
    and copy its arrays, keeping their dtypes (float32 positions stay float32 on the wire)."""
    present = {name: value for name, value in arrays.items() if value is not None}
    make_frame(positions, **present)
    copied: dict[str, Any] = {name: np.array(value, copy=True) for name, value in present.items()}
    if scene is not None:
        try:
            copied["scene"] = json.loads(json.dumps(dict(scene), allow_nan=False))
        except (TypeError, ValueError):
            raise InputError(
                "scene", "must be a JSON object of numbers, strings, lists and objects (no NaN)"
            ) from None
    return _Frame(-1, np.array(positions, copy=True), copied)


class LiveSession:
    """A stream session fed from any thread; answers by callback or `poll` (module docstring)."""

    def __init__(
        self,
        client: Client,
        scene: Mapping[str, Any] | None = None,
        *,
        on_result: Callable[[StreamResult], None] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        mode: Literal["latest", "queue"] = "latest",
        max_in_flight: int | None = None,
        stream_port: int | None = None,
        compact: bool | Literal["ordered"] = True,
    ) -> None:
        """Open the session (HELLO; the server prepares the scene before it answers WELCOME).
        `compact`: frames in the compact encoding when the server offers it (as `Client.stream`)."""
        if mode not in ("latest", "queue"):
            raise InputError("mode", "must be latest or queue")
        if max_in_flight is None and mode == "latest":
            max_in_flight = LATEST_IN_FLIGHT
        self._session: StreamSession = client.stream(
            scene, mode=mode, max_in_flight=max_in_flight, stream_port=stream_port, compact=compact
        )
        self._session.set_timeout(None)  # an idle producer is not an error; `close` wakes reads
        self.welcome: dict[str, Any] = self._session.welcome
        self.mode = mode
        #: Frames this session keeps unanswered at most (WELCOME's ``max_in_flight``).
        self.max_in_flight: int = self._session.max_in_flight
        #: Why the session ended, when it ended other than by `close`; None while it is up.
        self.error: BaseException | None = None
        self._callbacks = (on_result, on_error)
        self._lock = threading.Condition()
        self._waiting: deque[_Frame] = deque()
        self._sent: dict[int, None] = {}  # ids sent and not answered, in the order sent
        self._next_id = 0
        self._undelivered = 0  # accepted frames whose result has not been handed over yet
        self._closing = False
        self._results: queue.SimpleQueue[StreamResult | BaseException | None] = queue.SimpleQueue()
        self._polled: queue.SimpleQueue[StreamResult | None] = queue.SimpleQueue()
        self._threads = tuple(
            threading.Thread(target=target, name=f"sphrender-live-{name}", daemon=True)
            for name, target in (
                ("send", self._send_loop),
                ("read", self._read_loop),
                ("deliver", self._deliver_loop),
            )
        )
        for thread in self._threads:
            thread.start()

    # -- what a producer calls ------------------------------------------------------------

    @property
    def in_flight(self) -> int:
        """Frames sent to the server and not yet answered."""
        with self._lock:
            return len(self._sent)

    @property
    def pending(self) -> int:
        """Frames accepted by `submit` and not yet sent (at most one in ``latest`` mode)."""
        with self._lock:
            return len(self._waiting)

    def submit(
        self,
        positions: object,
        *,
        scene: Mapping[str, Any] | None = None,
        densities: object | None = None,
        radii: object | None = None,
        temperatures: object | None = None,
        velocities: object | None = None,
        ids: object | None = None,
        peak_temperatures: object | None = None,
        solid: object | None = None,
        timeout: float | None = None,
    ) -> int:
        """Accept one frame (thread-safe) and return its id; its result follows (module
        docstring). Arrays as PROTOCOL.md §4.2: positions (N, 3), densities, radii, temperatures,
        peak_temperatures, ids, solid (N,), velocities (N, 3); `scene`: a partial override for
        this frame alone.
        Raises `InputError` for a frame the server would refuse, `SessionClosed` once the
        session has ended, `TimeoutError` when a ``queue`` session had no room for `timeout` s."""
        arrays = {"densities": densities, "radii": radii, "temperatures": temperatures}
        arrays |= {"velocities": velocities, "ids": ids, "solid": solid}
        frame = _snapshot(positions, scene, {**arrays, "peak_temperatures": peak_temperatures})
        superseded: list[_Frame] = []
        with self._lock:
            room = self._lock.wait_for(
                lambda: self._ended() or self.mode == "latest" or self._has_room(), timeout
            )
            if self._ended():
                raise SessionClosed("the session has ended") from self.error
            if not room:
                raise TimeoutError(f"no room for a frame within {timeout} s")
            frame.id = self._next_id
            self._next_id += 1
            self._undelivered += 1
            if self.mode == "latest":
                superseded = list(self._waiting)
                self._waiting.clear()
            self._waiting.append(frame)
            self._lock.notify_all()
        for old in superseded:
            self._results.put(_dropped(old.id, "superseded"))
        return frame.id

    def poll(self, timeout: float = 0.0) -> StreamResult | None:
        """The next result, waiting at most `timeout` s (0: never waits); None when there is
        none. Only for sessions without ``on_result`` (which receives them instead)."""
        if self._callbacks[0] is not None:
            raise InputError("on_result", "this session delivers results to its callback")
        try:
            item = self._polled.get(block=timeout > 0, timeout=timeout if timeout > 0 else None)
        except queue.Empty:
            return None
        if item is None:
            self._polled.put(None)  # the session has ended: stays the last item
        return item

    def drain(self, timeout: float | None = None) -> bool:
        """Wait until every accepted frame's result has been handed over (``on_result`` returned,
        or `poll` can return it): True, or False after `timeout` s. Not from a callback."""
        with self._lock:
            return self._lock.wait_for(lambda: self._undelivered == 0, timeout)

    def close(self, timeout: float = 30.0) -> None:
        """Stop accepting frames, send those accepted, wait up to `timeout` s for their answers,
        say BYE and end the threads. Frames still unanswered then are reported ``"closed"``.
        Idempotent; may be called from a callback."""
        with self._lock:
            self._closing = True
            self._lock.notify_all()
        sender, reader, deliverer = self._threads
        deadline = time.monotonic() + timeout
        reader.join(max(deadline - time.monotonic(), 0.0))
        if reader.is_alive():
            self._session.abort()  # the reader wakes and reports what is left "closed"
            reader.join()
        sender.join()
        self._end(None, "closed")
        self._results.put(None)  # after every result: the deliverer's (and `poll`'s) end
        if threading.current_thread() is not deliverer:
            deliverer.join()

    def __enter__(self) -> LiveSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- the session's threads --------------------------------------------------------------

    def _has_room(self) -> bool:
        return len(self._waiting) < self.max_in_flight

    def _ended(self) -> bool:
        return self._closing or self.error is not None

    def _send_loop(self) -> None:
        """Send waiting frames while fewer than ``max_in_flight`` are unanswered; BYE at close."""
        while True:
            with self._lock:
                self._lock.wait_for(
                    lambda: (
                        self.error is not None
                        or (self._waiting and len(self._sent) < self.max_in_flight)
                        or (self._closing and not self._waiting and not self._sent)
                    )
                )
                if self.error is not None:
                    return
                if not self._waiting:
                    break
                frame = self._waiting.popleft()
                self._sent[frame.id] = None
                self._lock.notify_all()
            try:
                self._session.send(frame.positions, frame_id=frame.id, **frame.arrays)
            except OSError as exc:
                self._broken(exc)
                return
        try:
            self._session.bye()
        except OSError as exc:
            self._broken(exc)

    def _read_loop(self) -> None:
        """Answers from the socket to their frames, until GOODBYE or the connection ends."""
        while True:
            try:
                result = self._session.receive()
            except ServerError as exc:  # a fatal ERROR: the server closes the connection
                self._end(exc, "disconnected")
                break
            except (OSError, ProtocolError) as exc:
                self._broken(exc)
                break
            with self._lock:
                self._sent.pop(result.id, None)
                self._lock.notify_all()
            self._results.put(result)
        self._session.close()

    def _broken(self, exc: BaseException) -> None:
        """The connection failed: `close` ended it (BYE answered, or aborted after its
        timeout), or the server did (a GOODBYE's reason, or it went away), even mid-close."""
        reason = self._session.closed_reason
        if reason == "aborted" or (self._closing and reason == "bye"):
            self._end(None, "closed")
        else:
            self._end(SessionEnded(reason) if reason else exc, "disconnected")

    def _end(self, error: BaseException | None, reason: str) -> None:
        """Report every frame without an answer dropped (`reason`), once; keep `error`."""
        with self._lock:
            if error is not None and self.error is None:
                self.error = error
            else:
                error = None
            lost = [*self._sent, *(frame.id for frame in self._waiting)]
            self._sent.clear()
            self._waiting.clear()
            self._lock.notify_all()
        for frame_id in sorted(lost):
            self._results.put(_dropped(frame_id, reason))
        if error is not None:
            self._results.put(error)

    def _deliver_loop(self) -> None:
        """Results to ``on_result`` (or to `poll`), session errors to ``on_error``, in order."""
        on_result, on_error = self._callbacks
        while True:
            item = self._results.get()
            if item is None:
                self._polled.put(None)
                return
            try:
                if isinstance(item, BaseException):
                    if on_error is not None:
                        on_error(item)
                elif on_result is not None:
                    on_result(item)
                else:
                    self._polled.put(item)
            except Exception:
                log.exception("a LiveSession callback raised; the session goes on")
            if isinstance(item, StreamResult):
                with self._lock:
                    self._undelivered -= 1
                    self._lock.notify_all()
