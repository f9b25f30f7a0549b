"""Large temporaries reused between frames instead of allocated afresh.

The service fixes glibc's mmap threshold (server/service/heap.py), so every block of 128 KiB or
more is a mapping of its own whose pages fault in on first touch and go back to the system when
freed. A decoder that makes a dozen such temporaries per frame pays those faults on every frame.
A `ScratchPool` keeps the buffers its leases return (at most `max_bytes` in all, the largest
dropped first) and hands them out again; a `Lease` gives back everything it took when its
``with`` block ends, or when released. Nothing taken from a lease may be used after that.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

__all__ = ["DECODE_SCRATCH", "Allocate", "Lease", "ScratchPool"]

#: Smaller blocks come cheaply from malloc's heaps (the service maps blocks from 128 KiB on).
MIN_POOLED_BYTES = 64 << 10


class Allocate(Protocol):
    """Where an array comes from: `np.empty` or a lease's `Lease.array`."""

    def __call__(self, shape: Any, dtype: npt.DTypeLike, /) -> np.ndarray[Any, Any]: ...


class ScratchPool:
    """Touched byte buffers shared by the threads that lease from it."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._free: list[npt.NDArray[np.uint8]] = []
        self._lock = threading.Lock()

    @property
    def pooled_bytes(self) -> int:
        with self._lock:
            return sum(buffer.nbytes for buffer in self._free)

    @contextmanager
    def lease(self) -> Iterator[Lease]:
        """A lease that gives its buffers back when the ``with`` block ends."""
        lease = Lease(self)
        try:
            yield lease
        finally:
            lease.release()

    def hold(self) -> Lease:
        """A lease the caller ends with `Lease.release` (or never: its buffers are then freed
        with the last array that views them)."""
        return Lease(self)

    def _take(self, nbytes: int) -> npt.NDArray[np.uint8]:
        """The smallest free buffer of at least `nbytes`, else a new one."""
        with self._lock:
            fits = [i for i, buffer in enumerate(self._free) if buffer.nbytes >= nbytes]
            if fits:
                return self._free.pop(min(fits, key=lambda i: self._free[i].nbytes))
        return np.empty(nbytes, np.uint8)

    def _give(self, buffers: list[npt.NDArray[np.uint8]]) -> None:
        with self._lock:
            self._free.extend(buffers)
            self._free.sort(key=lambda buffer: buffer.nbytes)
            total = sum(buffer.nbytes for buffer in self._free)
            while total > self.max_bytes:
                total -= self._free.pop().nbytes


class Lease:
    """Arrays from one pool, valid until the lease is released."""

    def __init__(self, pool: ScratchPool) -> None:
        self._pool = pool
        self.taken: list[npt.NDArray[np.uint8]] = []

    def array(self, shape: Any, dtype: npt.DTypeLike, /) -> np.ndarray[Any, Any]:
        """An uninitialised C-contiguous array, valid until the lease ends."""
        kind = np.dtype(dtype)
        dims = (int(shape),) if np.ndim(shape) == 0 else tuple(int(d) for d in shape)
        nbytes = math.prod(dims) * kind.itemsize
        if nbytes < MIN_POOLED_BYTES:
            return np.empty(dims, kind)
        buffer = self._pool._take(nbytes)
        self.taken.append(buffer)
        return buffer[:nbytes].view(kind).reshape(dims)

    def release(self) -> None:
        """Give every buffer back; arrays taken from this lease must no longer be used."""
        taken, self.taken = self.taken, []
        self._pool._give(taken)


#: The compact decoder's temporaries and sessions' kept integers: about 8 MB for a session of
#: 100k-particle frames, 80 MB for 1M (past the cap, the largest are freed, not kept).
DECODE_SCRATCH = ScratchPool(max_bytes=64 << 20)
