"""Time spent inside GL calls, so a frame's host work can be told from the driver's.

On a GPU the driver returns from most calls at once and the frame time is what the render
thread does in Python and numpy; on llvmpipe the same calls rasterise. `RenderStats.host_ms` is
the render's wall time minus the time this clock saw inside the calls that do the device's work
(draws, compute dispatches, uploads, read-backs, clears, `finish`), each wrapped where it is
made: ``with clock: vao.render(...)``. Calls left unwrapped (uniform writes, binds) count as
host work, so the estimate errs high; `benchmarks/studies/host_time.py` checks it with a profiler.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any, TypeVar

T = TypeVar("T")

_thread = threading.local()


def thread_clock() -> GLClock:
    """The clock of the GL context this thread owns (helpers without a context handle, such as
    `draw.clear_and_scissor`, time their calls on it); a throwaway one on other threads."""
    clock = getattr(_thread, "clock", None)
    return clock if clock is not None else GLClock()


def own_on_this_thread(clock: GLClock) -> None:
    """Make `clock` this thread's (GLContext does, for its owner thread)."""
    _thread.clock = clock


class GLClock:
    """Accumulates the wall time of the calls made inside ``with clock:`` (owner thread only;
    nested uses count once)."""

    __slots__ = ("_depth", "_start", "seconds")

    def __init__(self) -> None:
        self.seconds = 0.0
        self._depth = 0
        self._start = 0.0

    def __enter__(self) -> None:
        if self._depth == 0:
            self._start = time.perf_counter()
        self._depth += 1

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._start

    def call(self, function: Callable[..., T], /, *args: Any, **kwargs: Any) -> T:
        """``function(*args, **kwargs)`` timed as ``with clock:`` would, in one Python call
        instead of two: for the helpers that wrap one GL call and run a dozen times a frame."""
        if self._depth:
            return function(*args, **kwargs)
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            self.seconds += time.perf_counter() - start


class StageTimer:
    """``with StageTimer(clock, finish, into, name):`` puts the block's wall time in
    milliseconds into ``into[name]``; with a `finish` (the context's), waits for the GPU at the
    end, so the time is the stage's own. A class, not a generator context manager: two calls
    per stage of a frame instead of six."""

    __slots__ = ("_clock", "_finish", "_into", "_name", "_start")

    def __init__(
        self,
        clock: GLClock,
        finish: Callable[[], None] | None,
        into: dict[str, float],
        name: str,
    ) -> None:
        self._clock, self._finish, self._into, self._name = clock, finish, into, name
        self._start = time.perf_counter()

    def __enter__(self) -> None:
        return None

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        if self._finish is not None:
            with self._clock:
                self._finish()
        elapsed = (time.perf_counter() - self._start) * 1e3  # sub-frames add up
        self._into[self._name] = self._into.get(self._name, 0.0) + elapsed
