"""Keep a long-running process's resident memory flat under images and payloads of varying size.

glibc's malloc serves a block above its mmap threshold with its own mapping, returned to the
system when freed, but raises the threshold to the size of each such block freed (up to 32 MiB).
A service that handles a 30 MB image once then takes every later image and payload from its
heaps, where freed space between live small objects is seldom returned: resident memory climbs
with the variety of sizes seen. A fixed threshold keeps large blocks in their own mappings.
"""

from __future__ import annotations

import ctypes
import ctypes.util

#: mallopt's parameter number for the mmap threshold (glibc's malloc.h).
_M_MMAP_THRESHOLD = -3
#: glibc's initial threshold: blocks from 128 KiB up get their own mapping, always.
MMAP_THRESHOLD_BYTES = 128 << 10


def fix_mmap_threshold(threshold: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Fix glibc's mmap threshold (no dynamic raise); False where the C library is not glibc."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, threshold))
