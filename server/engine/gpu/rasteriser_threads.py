"""llvmpipe's rasteriser threads under SCHED_BATCH, so they never preempt the render thread.

On a software GL the rasteriser's worker threads (Mesa names them ``llvmpipe-N``, one per core,
created with the first context of the process and shared by every later one) run beside the
render thread on the same cores. A GL call hands them work and returns; they wake and, under
Linux's default policy, preempt the thread running on that core, often the render thread in
the middle of the Python between two GL calls, and for a whole time slice: per-segment timing
of the render thread (100k ball, 1280x720, 2 cores) found single host segments of 2.2-2.4 ms
that take 0.01-0.1 ms in the median frame. That is noise in every host-work figure and, on a
service, latency for work that only the render thread can do.

SCHED_BATCH leaves a thread's share of the CPU as it is (same nice level) and gives up wakeup
preemption: the workers still get their cores whenever the render thread waits in a GL call,
they just do not take its core mid-statement. Measured on that frame, the two policies
interleaved frame by frame in one process (`benchmarks/bench_rasteriser_sched.py`): render
thread host work 1.64 -> 1.32 ms (3.05 -> 2.05 ms with cProfile), frame time 0.95x with the
host prepare, 0.99x with the device prepare. (Renicing the threads instead, tried
earlier, lowered their share of the CPU and slowed the frame by 10 % at nice 10.)

Any process may move its own threads to SCHED_BATCH (no privilege: it lowers their claim).
Nothing happens on a hardware GL, off Linux, or with ``SPHRENDER_LLVMPIPE_BATCH=0``.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)

#: The environment variable that turns this off ("0"); anything else or unset: on.
ENV = "SPHRENDER_LLVMPIPE_BATCH"
THREAD_PREFIX = "llvmpipe-"
_TASKS = Path("/proc/self/task")


def rasteriser_threads() -> list[int]:
    """The thread ids of this process's llvmpipe workers (empty off Linux)."""
    try:
        tasks = list(_TASKS.iterdir())
    except OSError:
        return []
    found = []
    for task in tasks:
        try:
            name = (task / "comm").read_text().strip()
        except OSError:  # the thread ended meanwhile
            continue
        if name.startswith(THREAD_PREFIX):
            found.append(int(task.name))
    return found


def batch_rasteriser_threads() -> int:
    """Put the llvmpipe workers under SCHED_BATCH (unless `ENV` is "0"); how many now are.
    Call after creating a software context (the workers exist from then on)."""
    if os.environ.get(ENV, "1").strip() == "0" or not hasattr(os, "sched_setscheduler"):
        return 0
    switched = 0
    for tid in rasteriser_threads():
        try:
            if os.sched_getscheduler(tid) != os.SCHED_BATCH:
                os.sched_setscheduler(tid, os.SCHED_BATCH, os.sched_param(0))
            switched += 1
        except OSError as exc:  # a sandbox that forbids it: run as before
            log.debug("llvmpipe thread %d left at its policy: %s", tid, exc)
    return switched
