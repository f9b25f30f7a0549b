"""Large temporaries reused between frames instead of allocated afresh.

The service fixes glibc's mmap threshold (server/service/heap.py), so every block of 128 KiB or
more is a mapping of its own whose pages fault in on first touch and go back to the system when
freed. A decoder that makes a dozen such temporaries per frame pays those faults on every frame.
A `ScratchPool` keeps the buffers its leases return (at most `max_bytes` in all, the largest
dropped first) and hands them out again; a `Lease` gives back everything it took when its
``with`` block ends. Nothing taken from a lease may outlive the block.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["DECODE_SCRATCH", "Lease", "ScratchPool"]

#: Below this, malloc's heaps serve a block without a mapping of its own: not worth pooling.
MIN_POOLED_BYTES = 64 << 10


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
        lease = Lease(self)
        try:
            yield lease
        finally:
            self._give(lease.taken)

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
    """Arrays from one pool for the length of a ``with`` block."""

    def __init__(self, pool: ScratchPool) -> None:
        self._pool = pool
        self.taken: list[npt.NDArray[np.uint8]] = []

    def array(self, shape: int | tuple[int, ...], dtype: npt.DTypeLike) -> np.ndarray[Any, Any]:
        """An uninitialised C-contiguous array, valid until the lease ends."""
        kind = np.dtype(dtype)
        dims = (shape,) if isinstance(shape, int) else shape
        nbytes = math.prod(dims) * kind.itemsize
        if nbytes < MIN_POOLED_BYTES:
            return np.empty(dims, kind)
        buffer = self._pool._take(nbytes)
        self.taken.append(buffer)
        return buffer[:nbytes].view(kind).reshape(dims)


#: The compact decoder's temporaries: a 100k-particle frame's take about 5 MB, a 1M one's 50.
DECODE_SCRATCH = ScratchPool(max_bytes=64 << 20)
