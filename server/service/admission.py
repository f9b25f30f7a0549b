"""What a frame may cost before the service reads it, and the one place decode failures become
documented errors.

**Memory budget.** Every frame is charged, before its bytes are read or its arrays allocated, an
estimate of the memory it will need on its way through the service::

    estimate = bytes received (body or payload) + particles x PARTICLE_BYTES + pixels x PIXEL_BYTES
               + particles x EXTRA_PARTICLE_BYTES[a] for each of velocities, ids the frame carries

`PARTICLE_BYTES` covers the decoded arrays, the validated float64/float32 copies, the copy sent
to the renderer process and the renderer's per-particle work (view-space positions, culling,
the splat buffers). Measured on llvmpipe with 2M particles at 640x360: the service process
peaked 96 MB above its resting RSS (48 B/particle), the renderer process 1155 MB (578
B/particle); 640 covers both. `EXTRA_PARTICLE_BYTES`: velocities and ids stay in the service
(the renderer does not get them): their validated copies (float32 x 3, int64) and the checks'
temporaries (finite mask; the ids' bitmap or sorted copy). `PIXEL_BYTES` the render targets,
the RGBA float read-back and the encoder's buffers. One frame over ``limits.max_request_bytes``
is refused (413 / ``too_large``, naming the numbers); frames in progress together may hold at
most ``limits.memory_budget_bytes`` (HTTP: 503 + Retry-After; stream: the reader waits, which is
TCP backpressure). A reservation is released when the frame has been answered.

**Decode boundary.** `decoding(field)` wraps every step that turns client bytes into values
(JSON, .npz, FRAME arrays, scenes). `InputError` passes through; any other exception is a bug in
a decoder that a client could trigger, so it is logged with its traceback and becomes an
`InputError` naming the field: the client gets ``bad_input`` (HTTP 400), never a 500, a dead
thread or an unanswered frame.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterable, Iterator

from sphrender.core.errors import InputError, LimitError

log = logging.getLogger("sphrender.service.admission")

#: Estimated bytes per particle of a frame on its way through the service (see module docstring).
PARTICLE_BYTES = 640
#: Estimated bytes per image pixel (targets, read-back, encoder).
PIXEL_BYTES = 120
#: Bytes per particle for the arrays the service holds but does not send to the renderer.
EXTRA_PARTICLE_BYTES: dict[str, int] = {"velocities": 16, "ids": 16}
#: Bytes per particle more for a compact frame: its inflated byte planes, integers and the
#: float64 arithmetic of the decode (core/compact.py), on top of the decoded arrays.
COMPACT_PARTICLE_BYTES = 192
_MIB = 1 << 20


class Busy(Exception):
    """No room in the memory budget right now (HTTP 503 + Retry-After, stream ``busy``)."""


def frame_estimate(received: int, particles: int, pixels: int, arrays: Iterable[str] = ()) -> int:
    extra = sum(EXTRA_PARTICLE_BYTES.get(name, 0) for name in arrays)
    return received + particles * (PARTICLE_BYTES + extra) + pixels * PIXEL_BYTES


def _mib(n: int) -> str:
    return f"{n / _MIB:.1f} MiB"


class Reservation:
    """Bytes held from a `MemoryBudget`; `release` is idempotent."""

    def __init__(self, budget: MemoryBudget, amount: int) -> None:
        self._budget = budget
        self.amount = amount

    def release(self) -> None:
        amount, self.amount = self.amount, 0
        if amount:
            self._budget._give_back(amount)


class MemoryBudget:
    """A pool of bytes shared by all frames in progress, with a per-frame cap."""

    def __init__(self, total: int, per_request: int) -> None:
        self.total = total
        self.per_request = per_request
        self._used = 0
        self._cond = threading.Condition()

    @property
    def used(self) -> int:
        with self._cond:
            return self._used

    def check(self, amount: int, what: str, field: str) -> None:
        """Refuse one frame whose estimate is over the per-frame cap (`LimitError`)."""
        if amount > self.per_request:
            raise LimitError(
                field,
                f"{what} would need about {_mib(amount)} of server memory; the limit is "
                f"{_mib(self.per_request)} per frame (limits.max_request_bytes)",
            )

    def reserve(
        self,
        amount: int,
        what: str,
        field: str,
        *,
        timeout: float = 0.0,
        abort: Callable[[], bool] | None = None,
    ) -> Reservation | None:
        """Hold `amount` bytes, waiting up to `timeout` for room; None when there is none
        (the caller answers busy). Raises `LimitError` over the per-frame cap."""
        self.check(amount, what, field)
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._used + amount > self.total:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or (abort is not None and abort()):
                    return None
                self._cond.wait(min(remaining, 0.2))
            self._used += amount
        return Reservation(self, amount)

    def _give_back(self, amount: int) -> None:
        with self._cond:
            self._used -= amount
            self._cond.notify_all()


@contextlib.contextmanager
def decoding(field: str, transport: str) -> Iterator[None]:
    """The decode boundary (module docstring): anything but `InputError` -> `InputError`."""
    try:
        yield
    except (InputError, Busy):
        raise
    except (MemoryError, RecursionError):
        raise LimitError(field, "is too large or too deeply nested to decode") from None
    except Exception:
        log.exception(
            "decoder failed on client input",
            extra={"event": "decode_bug", "field": field, "transport": transport},
        )
        raise InputError(
            field, "could not be decoded (the server logged the details as decode_bug)"
        ) from None
