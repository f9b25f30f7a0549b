"""The service's and renderer's malloc settings (server/service/heap.py): the fixed mmap threshold
keeps resident memory flat under blocks of varying size freed between live small objects (the
allocation pattern of images and payloads in a long-running server, without the rendering), and
the raised trim threshold lets a frame's blocks reuse the last frame's pages without faulting."""

from __future__ import annotations

import json
import subprocess
import sys
import time

from sphrender.server.service.heap import HeapTrimmer

WORKLOAD = """
import json, random, sys, threading
from sphrender.server.service.heap import configure_malloc
fixed = configure_malloc() if sys.argv[1] == "fixed" else None
def rss_mib():
    with open("/proc/self/statm") as handle:
        return int(handle.read().split()[1]) * 4096 / 2**20
def session(seed):
    rng, keep = random.Random(seed), []
    for _ in range(60):
        image = bytearray(rng.choice((4, 8, 16, 30)) << 20)  # an image or a payload
        keep.append([bytes(rng.randrange(100, 5000)) for _ in range(200)][::20])
        del image
        if len(keep) > 50:
            keep.pop(0)
start = rss_mib()
for round in range(2):
    threads = [threading.Thread(target=session, args=(4 * round + i,)) for i in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
print(json.dumps({"fixed": fixed, "growth_mib": rss_mib() - start}))
"""


#: Frames of blocks under the mmap threshold (96 KiB, 3 MiB a frame), allocated and freed on the
#: main thread and on another; the minor page faults of the second half. The control fixes only
#: the mmap threshold (glibc's default trim threshold, 128 KiB).
REUSE = """
import ctypes, json, resource, sys, threading
from sphrender.server.service import heap
if sys.argv[1] == "fixed":
    configured = heap.configure_malloc()
else:
    mallopt = heap._glibc_function("mallopt")
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    configured = bool(mallopt(heap._M_MMAP_THRESHOLD, heap.MMAP_THRESHOLD_BYTES))
def frames():
    for _ in range(50):
        blocks = [bytearray(96 << 10) for _ in range(32)]
        del blocks
def on_a_thread():
    thread = threading.Thread(target=frames)
    thread.start()
    thread.join()
frames()
on_a_thread()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
frames()
on_a_thread()
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(json.dumps({"fixed": configured, "faults": faults}))
"""


def run(mode: str, workload: str = WORKLOAD) -> dict[str, float]:
    done = subprocess.run(
        [sys.executable, "-c", workload, mode], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    result: dict[str, float] = json.loads(done.stdout)
    return result


def test_a_fixed_threshold_returns_large_blocks_to_the_system() -> None:
    """Four threads free 4-30 MB blocks between small objects they keep: with glibc's dynamic
    threshold the heaps keep tens of MB each (the control shows the pattern is real); with the
    fixed one the growth is the small objects kept (about 4 x 50 x 10 x 2.5 kB = 5 MB)."""
    dynamic, fixed = run("dynamic"), run("fixed")
    assert fixed["fixed"] is True
    assert dynamic["growth_mib"] > 60, dynamic
    assert fixed["growth_mib"] < 20, fixed


def test_a_frame_reuses_the_last_frames_heap_pages() -> None:
    """100 frames of 32 blocks of 96 KiB: with glibc's trim threshold every frame gives its
    3 MiB back and faults its 768 pages in again (about 77,000 faults; the control shows it);
    with the raised one the pages stay mapped (a few faults for Python's own objects)."""
    control, fixed = run("control", REUSE), run("fixed", REUSE)
    assert control["fixed"] is True and fixed["fixed"] is True
    assert control["faults"] > 20_000, control
    assert fixed["faults"] < 1_000, fixed


def test_the_trimmer_trims_once_per_interval() -> None:
    trimmer = HeapTrimmer(interval_s=0.2)
    assert not trimmer.maybe_trim()  # the interval starts at construction
    time.sleep(0.25)
    assert trimmer.maybe_trim() and not trimmer.maybe_trim()
