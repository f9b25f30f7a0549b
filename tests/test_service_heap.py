"""The service's and renderer's fixed mmap threshold (server/service/heap.py) keeps resident
memory flat under blocks of varying size freed between live small objects: the allocation
pattern of images and payloads in a long-running server, without the rendering."""

from __future__ import annotations

import json
import subprocess
import sys
import time

from sphrender.server.service.heap import HeapTrimmer

WORKLOAD = """
import json, random, sys, threading
from sphrender.server.service.heap import fix_mmap_threshold
fixed = fix_mmap_threshold() if sys.argv[1] == "fixed" else None
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


def run(mode: str) -> dict[str, float]:
    done = subprocess.run(
        [sys.executable, "-c", WORKLOAD, mode], capture_output=True, text=True, timeout=120
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


def test_the_trimmer_trims_once_per_interval() -> None:
    trimmer = HeapTrimmer(interval_s=0.2)
    assert not trimmer.maybe_trim()  # the interval starts at construction
    time.sleep(0.25)
    assert trimmer.maybe_trim() and not trimmer.maybe_trim()
