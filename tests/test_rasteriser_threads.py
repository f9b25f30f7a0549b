"""llvmpipe's rasteriser threads run under SCHED_BATCH once a software context exists
(`gpu/rasteriser_threads.py`), as the kernel reports it, and stay as they were when the
operator turns it off. Real EGL context, real Mesa threads, real `sphrender` processes."""

from __future__ import annotations

import json
import os
import threading

from cli_harness import run_sphrender

from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.rasteriser_threads import ENV, rasteriser_threads


def may_set_batch() -> bool:
    """Whether this process may put a thread under SCHED_BATCH (a throwaway thread tries)."""
    allowed: list[bool] = []

    def probe() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))  # 0: this thread
            allowed.append(True)
        except OSError:
            allowed.append(False)

    thread = threading.Thread(target=probe)
    thread.start()
    thread.join()
    return allowed == [True]


def test_the_rasteriser_threads_of_this_process_are_batch(gl_context: GLContext) -> None:
    threads = rasteriser_threads()
    if os.environ.get(ENV, "").strip() == "0":  # the operator turned it off for this run
        assert gl_context.batch_rasteriser_threads == 0
        return
    if not gl_context.is_software:  # a GPU: no llvmpipe, nothing to change
        assert gl_context.batch_rasteriser_threads == 0
        return
    if os.environ.get("LP_NUM_THREADS") == "0":  # rasterising inside the GL calls: no workers
        assert threads == []
        return
    assert threads, "llvmpipe runs its rasteriser on worker threads named llvmpipe-N"
    batch = [tid for tid in threads if os.sched_getscheduler(tid) == os.SCHED_BATCH]
    assert gl_context.batch_rasteriser_threads == len(batch)  # it reports what it did
    if may_set_batch():  # a sandbox may forbid the call: then the renderer runs as before
        assert batch == threads


def test_the_operator_can_turn_it_off() -> None:
    """`SPHRENDER_LLVMPIPE_BATCH=0`: the new process's threads keep the default policy. (In
    other processes: a second context in this one would leave the session's not current.)"""
    default = json.loads(run_sphrender("info").stdout)
    off = run_sphrender("info", env={ENV: "0"})
    assert off.returncode == 0, off.stderr
    assert json.loads(off.stdout)["batch_rasteriser_threads"] == 0
    if default["software"] and os.environ.get("LP_NUM_THREADS") != "0":
        assert default["batch_rasteriser_threads"] >= 1
