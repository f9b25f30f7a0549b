"""The batch submitter: render a whole sequence, one output per input frame.

Backend-agnostic: a `FrameRenderer` turns a `ParticleFrame` into encoded image bytes (the local
engine, or a server). This module owns what a simulation engineer relies on:

* outputs written atomically (``.NAME.PID.partial`` next to the target, then renamed), so a
  killed run never leaves a truncated image under a final name; stale partials are removed;
* ``resume``: frames whose output exists and is a complete image are skipped;
* one bad frame (unreadable file, invalid arrays, a render error) is reported and the rest still
  render; the summary lists every failure with its reason;
* progress: a bar (frames, fps, ETA) on a terminal, plain log lines otherwise;
* transient failures (`TransientError`) retried with exponential backoff.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, TextIO

from sphrender.client.api import Client, ServerError, ServerUnavailable
from sphrender.client.sequences import FrameJob
from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.core.image_check import is_complete_image
from sphrender.core.protocol import ImageFormat
from sphrender.core.readers import read_particles

PARTIAL_SUFFIX = ".partial"

log = logging.getLogger("sphrender.submit")


class TransientError(RuntimeError):
    """A failure worth retrying (connection refused or reset, server busy)."""


class FrameFailed(RuntimeError):
    """This frame cannot be rendered and retrying it here would not help (a backend already
    retried it, e.g. on several cluster workers); reported like bad input."""


class FrameRenderer(Protocol):
    def render(self, frame: ParticleFrame) -> bytes:
        """Encoded image bytes for one frame; raises InputError for bad input,
        TransientError for failures worth retrying, FrameFailed for a frame that failed
        after the backend's own retries."""
        ...


@dataclass
class Summary:
    rendered: list[FrameJob] = field(default_factory=list)
    skipped: list[FrameJob] = field(default_factory=list)
    failed: list[tuple[FrameJob, str]] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return not self.failed

    def report(self) -> str:
        lines = [
            f"{len(self.rendered)} rendered, {len(self.skipped)} skipped (already complete), "
            f"{len(self.failed)} failed in {self.seconds:.1f} s"
        ]
        lines += [f"  FAILED {job.input}: {reason}" for job, reason in self.failed]
        return "\n".join(lines)


def write_atomically(path: Path, data: bytes) -> None:
    partial = path.with_name(f".{path.name}.{os.getpid()}{PARTIAL_SUFFIX}")
    try:
        with open(partial, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def remove_stale_partials(jobs: Sequence[FrameJob]) -> int:
    """Delete partial files an interrupted run left next to this sequence's outputs."""
    removed = 0
    for directory in {job.output.parent for job in jobs}:
        names = {job.output.name for job in jobs}
        if not directory.is_dir():
            continue
        for entry in directory.iterdir():
            if entry.name.startswith(".") and entry.name.endswith(PARTIAL_SUFFIX):
                target = entry.name[1:].rsplit(".", 2)[0]
                if target in names:
                    entry.unlink(missing_ok=True)
                    removed += 1
    return removed


class Progress:
    """A one-line bar on a terminal; one log line per frame otherwise."""

    def __init__(self, total: int, stream: TextIO | None = None) -> None:
        self.total = total
        self.done = 0
        self.stream = stream or sys.stderr
        self.interactive = self.stream.isatty()
        self.start = time.monotonic()
        self._lock = threading.Lock()

    def update(self, job: FrameJob, status: str) -> None:
        with self._lock:
            self._update(job, status)

    def _update(self, job: FrameJob, status: str) -> None:
        self.done += 1
        elapsed = max(time.monotonic() - self.start, 1e-9)
        fps = self.done / elapsed
        eta = (self.total - self.done) / fps if fps > 0 else float("inf")
        if self.interactive:
            width = 30
            filled = int(width * self.done / max(self.total, 1))
            self.stream.write(
                f"\r[{'#' * filled}{' ' * (width - filled)}] {self.done}/{self.total} frames "
                f"{fps:5.2f} fps ETA {eta:5.0f}s"
            )
            if self.done == self.total:
                self.stream.write("\n")
        else:
            self.stream.write(
                f"[{self.done}/{self.total}] {job.input.name} -> {job.output.name}: {status} "
                f"({fps:.2f} fps, ETA {eta:.0f} s)\n"
            )
        self.stream.flush()


#: Longest wait between two attempts at one frame.
MAX_RETRY_DELAY_S = 8.0


def _with_retries(action: Callable[[], bytes], attempts: int, base_delay: float) -> bytes:
    for attempt in range(attempts):
        try:
            return action()
        except TransientError:
            if attempt == attempts - 1:
                raise
            time.sleep(min(base_delay * 2**attempt, MAX_RETRY_DELAY_S))
    raise AssertionError("unreachable")


class RemoteFrameRenderer:
    """A `FrameRenderer` that renders on a server over HTTP (thread-safe: one connection per
    request). Input errors fail the frame; an unreachable or busy server is a `TransientError`,
    which the submitter retries with backoff (the client itself does not retry, so the two
    do not multiply)."""

    def __init__(
        self,
        url: str,
        scene: Mapping[str, object] | None,
        fmt: ImageFormat,
        token: str | None = None,
        timeout: float = 300.0,
    ) -> None:
        self.client = Client(url, token=token, timeout=timeout, retries=0)
        self.scene = scene
        self.format: ImageFormat = fmt
        self._noted: set[str] = set()  # the fields the server has noted once already
        self._lock = threading.Lock()

    def render(self, frame: ParticleFrame) -> bytes:
        try:
            data, notes = self.client.render_frame_noted(frame, self.scene, format=self.format)
        except ServerUnavailable as exc:
            raise TransientError(str(exc)) from None
        except ServerError as exc:
            if exc.retryable or exc.code == "render_failed":
                raise TransientError(str(exc)) from None
            raise InputError(exc.field or "server", exc.message) from None
        self._log_notes(notes)
        return data

    def _log_notes(self, notes: list[dict[str, str]]) -> None:
        """The server's notes on a frame (what it changed about the input to render it),
        logged the first time each field is noted in this submission."""
        for note in notes:
            field_name = str(note.get("field", "?"))
            with self._lock:
                if field_name in self._noted:
                    continue
                self._noted.add(field_name)
            log.warning("the server noted %s: %s", field_name, note.get("message", ""))


def run_submission(
    jobs: Sequence[FrameJob],
    renderer: FrameRenderer,
    *,
    resume: bool = False,
    attribute_map: Mapping[str, str] | None = None,
    read_ahead: int = 2,
    concurrency: int = 1,
    retry_attempts: int = 8,
    retry_delay: float = 0.5,
    progress: Progress | None = None,
) -> Summary:
    """Render every job. With `concurrency` 1 frames render in order on the calling thread
    (required by the local engine, whose GL context belongs to this thread) while input files
    are read `read_ahead` frames ahead; with more, that many frames are in flight at once on
    worker threads (a thread-safe renderer such as `RemoteFrameRenderer`)."""
    summary = Summary()
    start = time.monotonic()
    remove_stale_partials(jobs)
    todo: list[FrameJob] = []
    for job in jobs:
        if resume and is_complete_image(job.output):
            summary.skipped.append(job)
        else:
            todo.append(job)
    progress = progress or Progress(len(todo))

    def load(job: FrameJob) -> ParticleFrame:
        return read_particles(job.input, attribute_map=attribute_map)

    if concurrency > 1:
        # Each worker reads, renders and writes one frame at a time, so at most `concurrency`
        # frames are in memory whatever the length of the sequence.
        def process(job: FrameJob) -> None:
            loaded: Future[ParticleFrame] = Future()
            try:
                loaded.set_result(load(job))
            except Exception as exc:
                loaded.set_exception(exc)
            _finish((job, loaded), renderer, summary, progress, retry_attempts, retry_delay)

        with ThreadPoolExecutor(max_workers=concurrency) as pool:
            futures = [pool.submit(process, job) for job in todo]
            try:
                for future in futures:
                    future.result()
            except BaseException:  # Ctrl-C: finish the frames in flight, start no other
                pool.shutdown(wait=True, cancel_futures=True)
                raise
        summary.seconds = time.monotonic() - start
        return summary

    with ThreadPoolExecutor(max_workers=max(1, read_ahead)) as pool:
        pending: Iterator[tuple[FrameJob, Future[ParticleFrame]]] = (
            (job, pool.submit(load, job)) for job in todo
        )
        window: list[tuple[FrameJob, Future[ParticleFrame]]] = []
        for item in pending:
            window.append(item)
            if len(window) <= read_ahead:
                continue
            _finish(window.pop(0), renderer, summary, progress, retry_attempts, retry_delay)
        for item in window:
            _finish(item, renderer, summary, progress, retry_attempts, retry_delay)
    summary.seconds = time.monotonic() - start
    return summary


def _finish(
    item: tuple[FrameJob, Future[ParticleFrame]],
    renderer: FrameRenderer,
    summary: Summary,
    progress: Progress,
    retry_attempts: int,
    retry_delay: float,
) -> None:
    job, future = item
    try:
        frame = future.result()
        data = _with_retries(lambda: renderer.render(frame), retry_attempts, retry_delay)
        write_atomically(job.output, data)
    except InputError as exc:
        summary.failed.append((job, str(exc)))
        progress.update(job, f"failed: {exc}")
        return
    except FrameFailed as exc:
        summary.failed.append((job, str(exc)))
        progress.update(job, "failed")
        return
    except TransientError as exc:
        summary.failed.append((job, f"gave up after {retry_attempts} attempts: {exc}"))
        progress.update(job, "failed")
        return
    except OSError as exc:
        summary.failed.append((job, f"cannot write {job.output}: {exc.strerror or exc}"))
        progress.update(job, "failed")
        return
    summary.rendered.append(job)
    progress.update(job, "ok")
