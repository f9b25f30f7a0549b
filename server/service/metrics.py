"""Counters, gauges and histograms, exposed in the Prometheus text format (version 0.0.4).

Written here rather than taken from prometheus_client because the service needs only a few
metric kinds and a dozen lines of exposition; the tests parse the output with prometheus_client's
own parser, an independent check that the text is valid.

All updates take one lock per metric family; the render thread updates a handful of metrics per
frame, so contention is negligible.
"""

from __future__ import annotations

import bisect
import collections
import math
import threading
import time
from collections.abc import Callable, Iterable, Sequence

LabelValues = tuple[str, ...]

#: Latency buckets in seconds: 1 ms to 2 min, roughly x2.5 apart (llvmpipe frames are slow).
LATENCY_BUCKETS: tuple[float, ...] = (
    0.001,
    0.0025,
    0.005,
    0.01,
    0.025,
    0.05,
    0.1,
    0.25,
    0.5,
    1.0,
    2.5,
    5.0,
    10.0,
    30.0,
    60.0,
    120.0,
)


def _escape_label(value: str) -> str:
    return value.replace("\\", "\\\\").replace("\n", "\\n").replace('"', '\\"')


def _escape_help(text: str) -> str:
    return text.replace("\\", "\\\\").replace("\n", "\\n")


def _number(value: float) -> str:
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "+Inf" if value > 0 else "-Inf"
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(float(value))


def _labels(names: Sequence[str], values: Sequence[str], extra: str = "") -> str:
    parts = [f'{n}="{_escape_label(v)}"' for n, v in zip(names, values, strict=True)]
    if extra:
        parts.append(extra)
    return "{" + ",".join(parts) + "}" if parts else ""


class _Family:
    kind = "untyped"

    def __init__(self, name: str, help: str, labels: Sequence[str] = ()) -> None:
        self.name = name
        self.help = help
        self.label_names = tuple(labels)
        self._lock = threading.Lock()

    def _key(self, labels: Sequence[str]) -> LabelValues:
        if len(labels) != len(self.label_names):
            raise ValueError(f"{self.name} takes labels {self.label_names}, got {labels}")
        return tuple(str(v) for v in labels)

    def header(self) -> list[str]:
        return [f"# HELP {self.name} {_escape_help(self.help)}", f"# TYPE {self.name} {self.kind}"]

    def samples(self) -> list[str]:
        raise NotImplementedError


class Counter(_Family):
    """Monotonic count; the name must end in ``_total``."""

    kind = "counter"

    def __init__(self, name: str, help: str, labels: Sequence[str] = ()) -> None:
        if not name.endswith("_total"):
            raise ValueError(f"counter names end in _total: {name}")
        super().__init__(name, help, labels)
        self._values: dict[LabelValues, float] = {}

    def inc(self, *labels: str, amount: float = 1.0) -> None:
        if amount < 0:
            raise ValueError("counters only go up")
        key = self._key(labels)
        with self._lock:
            self._values[key] = self._values.get(key, 0.0) + amount

    def value(self, *labels: str) -> float:
        with self._lock:
            return self._values.get(self._key(labels), 0.0)

    def samples(self) -> list[str]:
        with self._lock:
            items = sorted(self._values.items())
        return [f"{self.name}{_labels(self.label_names, k)} {_number(v)}" for k, v in items]


class Gauge(_Family):
    """A value that goes up and down, set directly or read from a callback at scrape time."""

    kind = "gauge"

    def __init__(
        self,
        name: str,
        help: str,
        labels: Sequence[str] = (),
        callback: Callable[[], Iterable[tuple[LabelValues, float]]] | None = None,
    ) -> None:
        super().__init__(name, help, labels)
        self._values: dict[LabelValues, float] = {}
        self._callback = callback

    def set_callback(self, callback: Callable[[], Iterable[tuple[LabelValues, float]]]) -> None:
        """Read the samples from `callback` at scrape time instead of stored values."""
        self._callback = callback

    def set(self, value: float, *labels: str) -> None:
        key = self._key(labels)
        with self._lock:
            self._values[key] = float(value)

    def add(self, amount: float, *labels: str) -> None:
        key = self._key(labels)
        with self._lock:
            self._values[key] = self._values.get(key, 0.0) + amount

    def value(self, *labels: str) -> float:
        """The stored value (not the callback's)."""
        with self._lock:
            return self._values.get(self._key(labels), 0.0)

    def samples(self) -> list[str]:
        if self._callback is not None:
            items = sorted((self._key(k), v) for k, v in self._callback())
        else:
            with self._lock:
                items = sorted(self._values.items())
        return [f"{self.name}{_labels(self.label_names, k)} {_number(v)}" for k, v in items]


class Histogram(_Family):
    """Cumulative buckets, sum and count per label set (seconds for latencies)."""

    kind = "histogram"

    def __init__(
        self,
        name: str,
        help: str,
        labels: Sequence[str] = (),
        buckets: Sequence[float] = LATENCY_BUCKETS,
    ) -> None:
        super().__init__(name, help, labels)
        self.buckets = tuple(sorted(buckets))
        self._series: dict[LabelValues, tuple[list[int], list[float]]] = {}

    def observe(self, value: float, *labels: str) -> None:
        key = self._key(labels)
        index = bisect.bisect_left(self.buckets, value)  # first bucket with bound >= value
        with self._lock:
            counts, total = self._series.setdefault(key, ([0] * (len(self.buckets) + 1), [0.0]))
            counts[index] += 1
            total[0] += value

    def count(self, *labels: str) -> int:
        with self._lock:
            series = self._series.get(self._key(labels))
            return sum(series[0]) if series else 0

    def samples(self) -> list[str]:
        with self._lock:
            items = sorted((k, (list(c), s[0])) for k, (c, s) in self._series.items())
        lines: list[str] = []
        for key, (counts, total) in items:
            cumulative = 0
            for bound, count in zip((*self.buckets, math.inf), counts, strict=True):
                cumulative += count
                # Bounds as Prometheus clients write them ("1.0", "+Inf"): dashboards match on them.
                le = f'le="{"+Inf" if math.isinf(bound) else repr(float(bound))}"'
                lines.append(f"{self.name}_bucket{_labels(self.label_names, key, le)} {cumulative}")
            lines.append(f"{self.name}_sum{_labels(self.label_names, key)} {_number(total)}")
            lines.append(f"{self.name}_count{_labels(self.label_names, key)} {cumulative}")
        return lines


class Registry:
    """The metric families of one service, in registration order."""

    def __init__(self) -> None:
        self._families: list[_Family] = []

    def register(self, family: _Family) -> None:
        if any(f.name == family.name for f in self._families):
            raise ValueError(f"duplicate metric {family.name}")
        self._families.append(family)

    def counter(self, name: str, help: str, labels: Sequence[str] = ()) -> Counter:
        family = Counter(name, help, labels)
        self.register(family)
        return family

    def gauge(
        self,
        name: str,
        help: str,
        labels: Sequence[str] = (),
        callback: Callable[[], Iterable[tuple[LabelValues, float]]] | None = None,
    ) -> Gauge:
        family = Gauge(name, help, labels, callback)
        self.register(family)
        return family

    def histogram(
        self,
        name: str,
        help: str,
        labels: Sequence[str] = (),
        buckets: Sequence[float] = LATENCY_BUCKETS,
    ) -> Histogram:
        family = Histogram(name, help, labels, buckets)
        self.register(family)
        return family

    def exposition(self) -> str:
        """The whole registry as Prometheus text (``text/plain; version=0.0.4``)."""
        lines: list[str] = []
        for family in self._families:
            lines.extend(family.header())
            lines.extend(family.samples())
        return "\n".join(lines) + "\n"


CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


class RecentFrames:
    """Finish times and latencies of the last images answered, for ``GET /v1/status``.

    The histograms above answer "how many frames were slower than a bucket"; a status page wants
    percentiles and a frame rate now, so the last `size` images are kept exactly. Both numbers
    depend only on the recorded frames (not on when they are read), except that frames older
    than `window_s` no longer count towards the rate, so an idle service reads 0 frames/s."""

    def __init__(self, size: int = 256, window_s: float = 10.0) -> None:
        self.window_s = window_s
        self._lock = threading.Lock()
        self._frames: collections.deque[tuple[float, float]] = collections.deque(maxlen=size)

    def add(self, latency_s: float, now: float | None = None) -> None:
        with self._lock:
            self._frames.append((time.monotonic() if now is None else now, latency_s))

    def summary(self, now: float | None = None) -> dict[str, float | int]:
        """frames_per_s: (n - 1) / (last - first finish) over the images of the last window_s
        (0 with fewer than two); p50/p90/p99_ms: nearest-rank percentiles of the latencies of
        the last `size` images (0 with none), milliseconds rounded to 0.1; frames: their count."""
        now = time.monotonic() if now is None else now
        with self._lock:
            frames = list(self._frames)
        recent = [t for t, _latency in frames if now - t <= self.window_s]
        span = recent[-1] - recent[0] if len(recent) >= 2 else 0.0
        rate = (len(recent) - 1) / span if span > 0 else 0.0
        latencies = sorted(latency for _t, latency in frames)

        def percentile(q: float) -> float:
            if not latencies:
                return 0.0
            rank = max(1, math.ceil(q * len(latencies)))  # nearest rank
            return round(latencies[rank - 1] * 1e3, 1)

        return {
            "frames_per_s": round(rate, 2),
            "p50_ms": percentile(0.50),
            "p90_ms": percentile(0.90),
            "p99_ms": percentile(0.99),
            "frames": len(latencies),
        }


class RenderMetrics:
    """The render side's families: stages, the render process's health, the queue."""

    def __init__(self, registry: Registry) -> None:
        self.stage_seconds = registry.histogram(
            "sphrender_stage_seconds",
            "Time per stage of a frame: queue wait, render passes, encode",
            ("stage",),
        )
        self.host_seconds = registry.histogram(
            "sphrender_frame_host_seconds",
            "Render-thread work outside GL calls per frame (Python, numpy): a GPU frame's floor",
        )
        self.context_rebuilds = registry.counter(
            "sphrender_gl_context_rebuilds_total",
            "GL contexts rebuilt after a GL error while rendering",
        )
        self.worker_restarts = registry.counter(
            "sphrender_worker_restarts_total",
            "Renderer processes replaced, by reason: crash (a native fault or other death), hung "
            "(over limits.render_timeout_s), rss (over worker.max_rss_bytes)",
            ("reason",),
        )
        self.worker_rss = registry.gauge(
            "sphrender_worker_rss_bytes", "Resident memory of the renderer process"
        )
        self.queue_depth = registry.gauge("sphrender_queue_depth", "Frames waiting for the GPU")
        self.context_rebuilds.inc(amount=0)
        for reason in ("crash", "hung", "rss"):
            self.worker_restarts.inc(reason, amount=0)


class TransportMetrics:
    """The transports' families: bytes, HTTP requests, stream connections, sessions."""

    def __init__(self, registry: Registry) -> None:
        self.bytes_in = registry.counter(
            "sphrender_received_bytes_total", "Request bytes received", ("transport",)
        )
        self.bytes_out = registry.counter(
            "sphrender_sent_bytes_total", "Answer bytes sent", ("transport",)
        )
        self.http_requests = registry.counter(
            "sphrender_http_requests_total",
            "HTTP requests by method, route and status code",
            ("method", "route", "code"),
        )
        self.open_connections = registry.gauge(
            "sphrender_stream_connections_open", "Stream connections currently open"
        )
        self.connections = registry.counter(
            "sphrender_stream_connections_total",
            "Stream connections by how they ended (bye, eof, timeout, protocol, ...)",
            ("end",),
        )
        self.sessions = registry.gauge("sphrender_sessions", "Open sessions", ("transport",))
        self.memory_reserved = registry.gauge(
            "sphrender_memory_reserved_bytes",
            "Estimated memory held by frames in progress (limits.memory_budget_bytes)",
        )


class ServiceMetrics:
    """The service's metric families, named once here so every part records the same names."""

    def __init__(self) -> None:
        self.registry = registry = Registry()
        self.build_info = registry.gauge(
            "sphrender_build_info",
            "Build and GL renderer of this process (value is always 1)",
            ("version", "gl_renderer"),
        )
        self.frames = registry.counter(
            "sphrender_frames_total",
            "Frames answered, by transport and outcome (image, error, dropped, rejected)",
            ("transport", "outcome"),
        )
        self.errors = registry.counter(
            "sphrender_errors_total", "Error answers by error code", ("transport", "code")
        )
        self.frame_seconds = registry.histogram(
            "sphrender_frame_latency_seconds",
            "From the frame fully received to its answer ready, by transport",
            ("transport",),
        )
        self.in_flight = registry.gauge(
            "sphrender_frames_in_flight",
            "Frames accepted and not yet answered (queued, rendering or encoding)",
        )
        self.render = RenderMetrics(registry)
        self.transport = TransportMetrics(registry)
        #: Not exposed in /metrics: the exact recent latencies behind /v1/status.
        self.recent = RecentFrames()
        self.in_flight.set(0)

    def exposition(self) -> str:
        return self.registry.exposition()
