"""The flicker item under both readings of its jitter. Issue 12 asks for flicker <= 0.3 deg
"for a 2 %-of-r jitter", and describes it as "moving every particle of a frame by 2 % of r".
The surface bench jitters by a Gaussian of 2 % r per axis, which moves a particle by 3.2 % r
on average; read literally, every particle moves by exactly 2 % r. The issue's own figure
for the pre-issue default (1.0 deg mean) lies below both, on a scene it does not name.

Per reading and setting, on the spatter and on the bench's dam-break frame: the renderer's
flicker, the truth's own (its floor), and the mean displacement the jitter gave, measured.
`jitter_readings_section` writes them into REPORT.md. The dam break needs ../shared/data and
pysplashsurf (or the reference cache); without them its columns are NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.studies.dam_frames import FLICKER_LIMIT_DEG
from sphrender.server.bench.surface_bench import (
    JITTER,
    Case,
    dam_case,
    render_case,
    spatter_case,
)
from sphrender.server.bench.surface_quality import flicker_deg
from sphrender.server.bench.sweep import Setting
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

#: (name in the report, surface_quality.jittered's fixed_length)
READINGS = (
    (f"Gaussian, {100 * JITTER:g} % r per axis (the bench's)", False),
    (f"every particle moved by exactly {100 * JITTER:g} % r", True),
)


@dataclass(frozen=True)
class JitterReadingRow:
    reading: str
    setting: str
    mean_move_r: float  # the mean displacement, in particle radii
    spatter_deg: float
    spatter_floor_deg: float
    dam_deg: float = math.nan
    dam_floor_deg: float = math.nan


def mean_move_r(case: Case) -> float:
    """The mean distance the case's jitter moved its particles, in particle radii."""
    moved = np.linalg.norm(case.moved.positions - case.frame.positions, axis=-1)
    return float(moved.mean() / case.scene.radius)


def case_flicker_deg(renderer: SurfaceRenderer, case: Case, setting: Setting) -> float:
    frame = render_case(renderer, case.frame, setting, case)
    moved = render_case(renderer, case.moved, setting, case)
    return flicker_deg(frame, moved)[0]


def run_jitter_readings(
    gl: GLContext,
    renderer: SurfaceRenderer,
    settings: Sequence[Setting],
    *,
    width: int,
    height: int,
    cache: Path,
    log: Callable[[str], None] = print,
) -> list[JitterReadingRow]:
    """One row per reading and setting."""
    rows: list[JitterReadingRow] = []
    for reading, fixed_length in READINGS:
        spatter, spatter_floor, _ = spatter_case(renderer, width, height, fixed_length=fixed_length)
        dam, dam_floor, note = dam_case(
            gl, renderer, width, height, cache, fixed_length=fixed_length
        )
        if dam is None:
            log(f"  {note}")
        for setting in settings:
            row = JitterReadingRow(
                reading,
                setting.name,
                mean_move_r(spatter),
                case_flicker_deg(renderer, spatter, setting),
                spatter_floor,
                math.nan if dam is None else case_flicker_deg(renderer, dam, setting),
                dam_floor,
            )
            rows.append(row)
            log(
                f"  {reading}, {setting.name}: moved {row.mean_move_r:.4f} r, spatter "
                f"{row.spatter_deg:.3f} (floor {row.spatter_floor_deg:.3f}), dam "
                f"{row.dam_deg:.3f} (floor {row.dam_floor_deg:.3f})"
            )
    return rows


def jitter_readings_section(rows: Sequence[JitterReadingRow]) -> list[str]:
    """REPORT.md's table of the flicker under both readings (empty without rows)."""
    if not rows:
        return []
    head = ["jitter", "mean move", "setting", "spatter flicker°", "its truth's°"]
    head += ["dam flicker°", "its truth's°"]
    lines = [
        "## Flicker under both readings of the jitter",
        "",
        'The issue\'s flicker item asks for a "2 %-of-r jitter" and describes it as "moving '
        "every particle of a frame by 2 % of r\". The bench's Gaussian of 2 % r per axis moves "
        "a particle farther than that; here both readings, on the spatter and on the bench's "
        "dam-break frame, with the truth's own flicker under the same jitter.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for r in rows:
        cells = [r.reading, f"{r.mean_move_r:.4f} r", r.setting, f"{r.spatter_deg:.2f}"]
        cells += [f"{r.spatter_floor_deg:.2f}", f"{r.dam_deg:.2f}", f"{r.dam_floor_deg:.2f}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    for reading, _ in READINGS:
        mine = [r for r in rows if r.reading == reading]
        if mine:
            lines.append(_verdict_line(reading, mine))
    return lines


def _verdict_line(reading: str, rows: Sequence[JitterReadingRow]) -> str:
    """Whether each setting meets the item under `reading`, and whether the truth does."""
    limit = FLICKER_LIMIT_DEG

    def meets(*values: float) -> bool:
        return all(v <= limit for v in values if not math.isnan(v))

    verdicts = ", ".join(
        f"{r.setting} {'meets' if meets(r.spatter_deg, r.dam_deg) else 'does not meet'} it"
        for r in rows
    )
    floor = rows[0]
    truth = "meets" if meets(floor.spatter_floor_deg, floor.dam_floor_deg) else "does not meet"
    return f"* {reading}: flicker <= {limit}°: {verdicts}; the truth itself {truth} it"
