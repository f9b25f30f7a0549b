"""Keep a long-running process's resident memory flat under images and payloads of varying size,
without paying a page fault for every block a frame allocates.

glibc's malloc serves a block above its mmap threshold with its own mapping, returned to the
system when freed, but raises the threshold to the size of each such block freed (up to 32 MiB).
A service that handles a 30 MB image once then takes every later image and payload from its
heaps, where freed space between live small objects is seldom returned: resident memory climbs
with the variety of sizes seen. A fixed threshold keeps large blocks in their own mappings.
Below it, glibc gives a heap's free top back to the system as soon as it passes the trim
threshold (128 KiB), so the next frame's blocks fault their pages in again; a high trim
threshold keeps that space for reuse, and `HeapTrimmer`, every few seconds, returns the free
pages the heaps of many threads still hold.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time
from typing import Any

#: mallopt's parameter numbers for the trim and mmap thresholds (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: glibc's initial threshold: blocks from 128 KiB up get their own mapping, always.
MMAP_THRESHOLD_BYTES = 128 << 10
#: Free space a heap keeps at its top between two trims (blocks below the mmap threshold only).
TRIM_THRESHOLD_BYTES = 256 << 20


#: Seconds between two trims of a process's heaps.
TRIM_INTERVAL_S = 5.0


def _glibc_function(name: str) -> Any | None:
    """A function of glibc's malloc, or None where the C library is another one."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return getattr(libc, name)
    except (OSError, AttributeError):
        return None


def configure_malloc(
    mmap_threshold: int = MMAP_THRESHOLD_BYTES, trim_threshold: int = TRIM_THRESHOLD_BYTES
) -> bool:
    """Fix glibc's mmap threshold (no dynamic raise) and raise its trim threshold (the process
    must run a `HeapTrimmer`); False where the C library is not glibc."""
    mallopt = _glibc_function("mallopt")
    if mallopt is None:
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    fixed = bool(mallopt(_M_MMAP_THRESHOLD, mmap_threshold))
    return bool(mallopt(_M_TRIM_THRESHOLD, trim_threshold)) and fixed


class HeapTrimmer:
    """Calls glibc's malloc_trim at most every `TRIM_INTERVAL_S` (a few ms over every arena)."""

    def __init__(self, interval_s: float = TRIM_INTERVAL_S) -> None:
        self._trim = _glibc_function("malloc_trim")
        if self._trim is not None:
            self._trim.argtypes = (ctypes.c_size_t,)
            self._trim.restype = ctypes.c_int
        self._interval_s = interval_s
        self._last = time.monotonic()

    def maybe_trim(self) -> bool:
        """Trim when the interval has passed; True when it did."""
        now = time.monotonic()
        if self._trim is None or now - self._last < self._interval_s:
            return False
        self._last = now
        self._trim(0)
        return True
