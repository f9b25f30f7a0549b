"""What one `sphrender bench` run measured: the sweep rows, the peers and the scaling series,
filled by `run.py` and written out by `report.py`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sphrender.server.bench import peers
from sphrender.server.bench.dam_frames import DamFrameRow
from sphrender.server.bench.jitter_readings import JitterReadingRow
from sphrender.server.bench.surface_bench import SurfaceResults
from sphrender.server.bench.sweep import SweepRow


@dataclass
class BenchResults:
    machine: list[str] = field(default_factory=list)
    rows: list[SweepRow] = field(default_factory=list)
    headline: list[peers.PeerResult] = field(default_factory=list)
    headline_scene: str = ""
    cpu_peers: list[tuple[str, float | None, str]] = field(default_factory=list)
    scaling_particles: list[tuple[int, float]] = field(default_factory=list)
    scaling_resolution: list[tuple[int, int, float]] = field(default_factory=list)
    surfaces: SurfaceResults | None = None
    #: The dam break's figures on every frame of the data set (empty without it).
    dam_frames: list[DamFrameRow] = field(default_factory=list)
    #: The flicker under both readings of the issue's jitter (empty in quick runs).
    jitter_readings: list[JitterReadingRow] = field(default_factory=list)


def growth_exponent(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of log y against log x (time ~ x^slope)."""
    if len(xs) < 2:
        return float("nan")
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def ratio(slow: float | None, fast: float | None) -> str:
    if slow is None or fast is None or fast <= 0 or not math.isfinite(slow):
        return "-"
    return f"{slow / fast:.1f}x"
