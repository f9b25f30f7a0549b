"""The device buffers of one `SphEngine` and the launch size of every 1-D SPH kernel.

`BufferPool` hands out named OpenCL buffers, reused across frames and grown geometrically, so a
steady sequence allocates nothing per frame; the kernel modules (`anisotropy.py`,
`density_below.py`) take their buffers from the engine's pool and own none. Released together
with the engine, on the CL context's owner thread.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sphrender.server.engine.gpu.cl_context import CLContext

#: Work-group size for every 1-D launch (global sizes are padded to a multiple of it).
WORK_GROUP = 64


def round_up(n: int, multiple: int = WORK_GROUP) -> int:
    """`n` padded up to a multiple of `multiple` (at least one multiple: no empty launch)."""
    return max(multiple, -(-n // multiple) * multiple)


class BufferPool:
    """Named device buffers on one `CLContext`: `pool(name, nbytes)` returns a buffer of at
    least `nbytes`, the same one while it is large enough."""

    def __init__(self, cl: CLContext) -> None:
        import pyopencl

        self._cl = cl
        self._pyopencl: Any = pyopencl
        self._buffers: dict[str, Any] = {}

    def __call__(self, name: str, nbytes: int) -> Any:
        """A device buffer of at least `nbytes`, reused across frames, grown geometrically."""
        nbytes = max(nbytes, 16)
        buffer = self._buffers.get(name)
        if buffer is None or buffer.size < nbytes:
            if buffer is not None:
                nbytes = max(nbytes, buffer.size * 2)  # size first: a released buffer has none
                buffer.release()
            buffer = self._pyopencl.Buffer(
                self._cl.context, self._pyopencl.mem_flags.READ_WRITE, nbytes
            )
            self._buffers[name] = buffer
        return buffer

    def __getitem__(self, name: str) -> Any:
        """The buffer last handed out under `name`."""
        return self._buffers[name]

    def upload(self, name: str, array: np.ndarray) -> Any:
        """`array` copied into the buffer `name` (grown to fit)."""
        buffer = self(name, array.nbytes)
        if array.nbytes:
            self._pyopencl.enqueue_copy(self._cl.queue, buffer, np.ascontiguousarray(array))
        return buffer

    def download(self, buffer: Any, array: np.ndarray) -> np.ndarray:
        """`buffer`'s first `array.nbytes` bytes copied into `array` (returned)."""
        if array.nbytes:
            self._pyopencl.enqueue_copy(self._cl.queue, array, buffer)
        return array

    def release(self) -> None:
        """Release every buffer; the pool can hand out new ones afterwards."""
        for buffer in self._buffers.values():
            buffer.release()
        self._buffers.clear()
