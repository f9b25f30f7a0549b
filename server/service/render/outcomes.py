"""Answers of the render process -> the outcomes of the jobs they answer, and failing jobs."""

from __future__ import annotations

from sphrender.core.errors import InputError
from sphrender.core.protocol import ErrorCode
from sphrender.server.service.metrics import ServiceMetrics
from sphrender.server.service.render.jobs import ErrorOutcome, FrameJob, ImageOutcome, WarmJob
from sphrender.server.service.render.messages import ErrorAnswer, ImageAnswer, WarmAnswer


def warm_result(answer: WarmAnswer) -> BaseException | None:
    """What a `WarmJob`'s future is resolved with."""
    error = answer.error
    if error is None:
        return None
    if error.input:
        return InputError(error.field or "", error.message)
    return RuntimeError(error.message)


def image_outcome(
    job: FrameJob, answer: ImageAnswer, data: bytes, ipc_ms: float, metrics: ServiceMetrics
) -> ImageOutcome:
    """The image and its timings (queue, the renderer's stages, encode, ipc), observed into
    the stage histograms."""
    stage_ms = answer.timings_ms
    timings = {"queue": (job.started_at - job.queued_at) * 1e3, **stage_ms, "ipc": ipc_ms}
    for stage, ms in stage_ms.items():
        metrics.render.stage_seconds.observe(ms / 1e3, stage)
    metrics.render.stage_seconds.observe(ipc_ms / 1e3, "ipc")
    metrics.render.host_seconds.observe(answer.host_ms / 1e3)
    arrays = None
    if answer.arrays is not None:
        arrays = [{"name": a.name, "dtype": a.dtype, "shape": list(a.shape)} for a in answer.arrays]
    return ImageOutcome(
        data=data,
        format=job.format,
        width=answer.width,
        height=answer.height,
        particles=answer.particles,
        drawn=answer.drawn,
        timings_ms={k: round(v, 3) for k, v in timings.items()},
        arrays=arrays,
        notes=tuple({"field": n.field, "message": n.message} for n in answer.notes),
    )


def error_outcome(answer: ErrorAnswer) -> ErrorOutcome:
    """bad_input or render_failed (any other code the process sent reads as render_failed)."""
    code = answer.code
    if code not in (ErrorCode.BAD_INPUT, ErrorCode.RENDER_FAILED):
        code = ErrorCode.RENDER_FAILED
    return ErrorOutcome(code, answer.message, answer.field)


def fail(job: FrameJob | WarmJob, message: str) -> None:
    """Answer `job` render_failed (a warm-up: with a RuntimeError), unless it already is."""
    if isinstance(job, WarmJob):
        if not job.future.done():
            job.future.set_result(RuntimeError(message))
    else:
        job.resolve(ErrorOutcome(ErrorCode.RENDER_FAILED, message))
