"""What one `sphrender bench` run measured: the sweep rows, the peers and the scaling series,
filled by `run.py` and written out by `report.py`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sphrender.server.bench import peers
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
    #: Words a study (`run_bench`'s `studies`) appends to the surface section's target lines,
    #: by line: "droplets", "edge_alpha", "band".
    surface_notes: dict[str, str] = field(default_factory=dict)
    #: Markdown lines a study adds after the surface section.
    extra_sections: list[str] = field(default_factory=list)
    #: How the report is regenerated (its first paragraph names it).
    command: str = "`sphrender bench --out DIR` (after `pip install '.[bench]'`)"


def growth_exponent(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of log y against log x (time ~ x^slope)."""
    if len(xs) < 2:
        return float("nan")
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def ratio(slow: float | None, fast: float | None) -> str:
    if slow is None or fast is None or fast <= 0 or not math.isfinite(slow):
        return "-"
    return f"{slow / fast:.1f}x"
