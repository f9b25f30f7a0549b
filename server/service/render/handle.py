"""One render process as the worker sees it: the process, its pipe and its receiver thread.

`ProcessHandle.spawn` starts a process (`process.process_main`, multiprocessing ``spawn``) and
waits for its `Ready`; the receiver thread decodes every answer (never unpickling) and hands it
to the worker's callback until the pipe closes.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from multiprocessing.context import SpawnContext, SpawnProcess

import numpy as np

from sphrender.server.service.render.messages import (
    Answer,
    Health,
    ImageAnswer,
    Ready,
    Request,
    StopRequest,
    decode_answer,
)
from sphrender.server.service.render.process import process_main

#: Called on the receiver thread: answer, its health, the image bytes, ms spent receiving them.
AnswerCallback = Callable[[Answer, Health, bytes | None, float], None]


def exit_text(code: int | None) -> str:
    """A process's exit code in words ("signal 11 (SIGSEGV)")."""
    if code is None:
        return "did not exit"
    if code < 0:
        try:
            return f"signal {-code} ({signal.Signals(-code).name})"
        except ValueError:
            return f"signal {-code}"
    return f"exit status {code}"


class ProcessHandle:
    """See the module docstring."""

    def __init__(self, process: SpawnProcess, conn: Connection, ready: Ready) -> None:
        self.process = process
        self.conn = conn
        self.ready = ready
        self.dead = threading.Event()  # the pipe closed: the receiver has stopped
        self.hung = False  # killed by the watchdog
        self._receiver: threading.Thread | None = None

    @classmethod
    def spawn(
        cls,
        context: SpawnContext,
        environment_dirs: tuple[str, ...],
        encoders: int,
        start_timeout_s: float,
    ) -> ProcessHandle:
        """Start a render process and wait until it is warm (RuntimeError on failure)."""
        ours, theirs = context.Pipe(duplex=True)
        process = context.Process(
            target=process_main,
            args=(theirs, environment_dirs, encoders),
            name="sphrender-renderer",
            daemon=True,
        )
        process.start()
        theirs.close()
        try:
            if not ours.poll(start_timeout_s):
                raise RuntimeError(f"the renderer process was not ready within {start_timeout_s} s")
            hello, _health = decode_answer(ours.recv_bytes())
        except (EOFError, OSError, RuntimeError, ValueError) as exc:
            process.kill()
            process.join(5)
            detail = exit_text(process.exitcode) if isinstance(exc, EOFError) else str(exc)
            raise RuntimeError(f"the renderer process failed to start: {detail}") from None
        if not isinstance(hello, Ready):
            process.join(5)
            error = getattr(hello, "error", type(hello).__name__)
            raise RuntimeError(f"the renderer process failed to start: {error}")
        return cls(process, ours, hello)

    @property
    def pid(self) -> int | None:
        return self.process.pid

    def start_receiver(self, on_answer: AnswerCallback, wake: Callable[[], None]) -> None:
        """Read answers on a thread of their own; `wake` is called once the pipe closes."""
        self._receiver = threading.Thread(
            target=self._receive,
            args=(on_answer, wake),
            name="sphrender-render-receiver",
            daemon=True,
        )
        self._receiver.start()

    def _receive(self, on_answer: AnswerCallback, wake: Callable[[], None]) -> None:
        try:
            while True:
                answer, health = decode_answer(self.conn.recv_bytes())
                data = None
                start = time.perf_counter()
                if isinstance(answer, ImageAnswer):
                    data = self.conn.recv_bytes()
                on_answer(answer, health, data, (time.perf_counter() - start) * 1e3)
        except (EOFError, OSError, ValueError):
            pass
        finally:
            self.dead.set()
            wake()

    def send(self, request: Request, buffers: Sequence[np.ndarray] = ()) -> None:
        """A request, then each buffer's raw bytes (no pickling; empty arrays too)."""
        self.conn.send(request)
        for value in buffers:
            self.conn.send_bytes(np.ascontiguousarray(value).reshape(-1).view(np.uint8).data)

    def alive(self) -> bool:
        return not self.dead.is_set() and self.process.is_alive()

    def kill(self) -> None:
        self.process.kill()
        self.process.join(5)

    def stop(self, *, kill: bool = False) -> None:
        """Ask the process to finish (or kill it), then wait for it and the receiver."""
        if not kill:
            with contextlib.suppress(OSError):
                self.conn.send(StopRequest())
            self.process.join(10)
        if self.process.is_alive():
            self.kill()
        self.dead.wait(5)
        if self._receiver is not None:
            self._receiver.join(5)
        self.conn.close()
