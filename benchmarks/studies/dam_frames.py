"""The dam break's surface figures on every frame of the data set, not only the surface bench's
frame 5: whether what was chosen on one frame holds on the others (the calm start, the splash,
the settling pool).

Per frame and setting, against pysplashsurf's reconstruction of that frame (and of its
jittered copy for the flicker's floor): the mean normal error over the pixels both cover, the
1-px tolerant silhouette band error (the issue's band item), the flicker under the surface
bench's 2 %-of-r jitter, the reference's own flicker, and whether every output pixel is finite;
against the union of the frame's particle spheres (`sphere_union.py`): the edge alpha error
and the lone droplets' normal error, the spatter's two analytic figures.
`dam_frames_section` writes them into REPORT.md, with the band error's ratio to the pre-issue
default's on each frame. Needs ../shared/data and pysplashsurf (or the reference cache).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.studies.sphere_union import (
    SphereUnion,
    droplet_error_deg,
    edge_alpha,
    gap_coverage,
    sphere_union,
)
from sphrender.server.bench.mesh_reference import rasterise
from sphrender.server.bench.scenes import DAMBREAK_RADIUS, DAMBREAK_VTK
from sphrender.server.bench.surface_bench import (
    PLAIN_SMOOTHING,
    UNFILTERED,
    Case,
    cached_reconstruction,
    dam_case,
    render_case,
)
from sphrender.server.bench.surface_quality import (
    F64,
    band_error_deg,
    flicker_deg,
    shift_tolerant_band_error_deg,
    supersampled_coverage,
)
from sphrender.server.bench.sweep import Setting
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

BAND_LIMIT = 0.4  # the "at most 40 % of today's"
FLICKER_LIMIT_DEG = 0.3
EDGE_ALPHA_LIMIT = 0.1
DROPLET_LIMIT = 1.2  # "no worse than 1.2x the unfiltered splat's"
#: A lone droplet: no other particle within the SPH support (the engine's default, 4 r).
LONE_SUPPORT = 4.0 * DAMBREAK_RADIUS
NAN = float("nan")


@dataclass(frozen=True)
class DamFrameRow:
    frame: str  # the file's stem, e.g. ParticleData_Fluid_9
    setting: str
    mean_deg: float
    band_deg: float  # 1-px tolerant
    flicker_deg: float
    floor_deg: float  # the reference's own flicker
    finite: bool
    #: Against the union of the particle spheres (sphere_union.py): the edge alpha error over
    #: all its edge pixels and over its silhouettes against background, the share of the gaps
    #: between spheres among them, and the gaps' mean sphere coverage, alpha and reference
    #: coverage.
    edge_alpha: float = NAN
    edge_alpha_silhouettes: float = NAN
    gap_share: float = NAN
    gap_spheres: float = NAN
    gap_alpha: float = NAN
    gap_reference: float = NAN
    #: The lone droplets' normal error, and how many pixels it is over.
    droplet_deg: float = NAN
    droplet_px: int = 0


def frame_number(path: Path) -> int:
    return int(path.stem.rsplit("_", 1)[-1])


def dam_frame_paths(numbers: Sequence[int] | None = None) -> list[Path]:
    """The data set's VTK frames in time order (only `numbers` when given)."""
    paths = sorted(DAMBREAK_VTK.glob("ParticleData_Fluid_*.vtk"), key=frame_number)
    return [p for p in paths if numbers is None or frame_number(p) in numbers]


def all_finite(frame: RenderedFrame) -> bool:
    """No NaN or Inf in any output pixel: RGBA and normals everywhere, depth where covered
    (+inf is the depth AOV's "no surface")."""
    assert frame.depth is not None and frame.normals is not None
    depth_ok = not np.isnan(frame.depth).any() and not np.isneginf(frame.depth).any()
    return bool(np.isfinite(frame.rgba).all() and np.isfinite(frame.normals).all() and depth_ok)


def run_dam_frames(
    gl: GLContext,
    renderer: SurfaceRenderer,
    settings: Sequence[Setting],
    paths: Sequence[Path],
    *,
    width: int,
    height: int,
    cache: Path,
    log: Callable[[str], None] = print,
) -> list[DamFrameRow]:
    """One row per frame and setting (ImportError when pysplashsurf is missing and the cache
    does not hold a frame's reference)."""
    rows: list[DamFrameRow] = []
    for path in paths:
        case, floor, note = dam_case(gl, renderer, width, height, cache, path)
        if case is None:
            raise ImportError(note)
        union, reference = _analytic_truths(gl, renderer, case, cache)
        for setting in settings:
            frame = render_case(renderer, case.frame, setting, case)
            moved = render_case(renderer, case.moved, setting, case)
            row = _row(path.stem, setting.name, case, floor, (frame, moved), (union, reference))
            rows.append(row)
            log(
                f"  {row.frame} {row.setting}: mean {row.mean_deg:.2f} band {row.band_deg:.2f} "
                f"flicker {row.flicker_deg:.3f} (floor {row.floor_deg:.3f}) finite {row.finite} "
                f"edge alpha {row.edge_alpha:.3f} (silhouettes {row.edge_alpha_silhouettes:.3f}) "
                f"droplets {row.droplet_deg:.2f} ({row.droplet_px} px)"
            )
    return rows


def _row(
    frame_name: str,
    setting: str,
    case: Case,
    floor: float,
    renders: tuple[RenderedFrame, RenderedFrame],
    truths: tuple[SphereUnion, F64],
) -> DamFrameRow:
    """One frame's figures for one setting: its `renders` of the frame and of the jittered
    copy against the case's reference, and against `truths` (`_analytic_truths`)."""
    frame, moved = renders
    union, reference = truths
    alpha = frame.rgba[..., 3].astype(np.float64)
    edges = edge_alpha(alpha, union.coverage, reference)
    gaps = gap_coverage(alpha, union.coverage, reference)
    return DamFrameRow(
        frame_name,
        setting,
        mean_deg=band_error_deg(frame, case.truth, case.truth.hit),  # every covered pixel
        band_deg=shift_tolerant_band_error_deg(frame, case.truth, case.band),
        flicker_deg=flicker_deg(frame, moved)[0],
        floor_deg=floor,
        finite=all_finite(frame) and all_finite(moved),
        edge_alpha=edges.all,
        edge_alpha_silhouettes=edges.silhouettes,
        gap_share=edges.gap_share,
        gap_spheres=gaps.spheres,
        gap_alpha=gaps.alpha,
        gap_reference=gaps.reference,
        droplet_deg=droplet_error_deg(frame, union),
        droplet_px=int(union.droplet.sum()),
    )


def _analytic_truths(
    gl: GLContext, renderer: SurfaceRenderer, case: Case, cache: Path
) -> tuple[SphereUnion, F64]:
    """The frame's sphere union and the reference reconstruction's 4 x 4 supersampled
    coverage, both through the case's camera."""
    config, (width, height) = case.scene.camera_config(), (case.camera.width, case.camera.height)
    positions = case.frame.positions
    union = sphere_union(config, width, height, positions, DAMBREAK_RADIUS, LONE_SUPPORT)
    mesh = cached_reconstruction(positions, DAMBREAK_RADIUS, cache)
    reference = supersampled_coverage(
        lambda camera: rasterise(gl, renderer.programs, mesh, camera), config, width, height
    )
    return union, reference


def band_ratios(rows: Sequence[DamFrameRow], setting: str) -> dict[str, float]:
    """Per frame: `setting`'s tolerant band error over the pre-issue default's."""
    before = {r.frame: r.band_deg for r in rows if r.setting == PLAIN_SMOOTHING.name}
    return {
        r.frame: r.band_deg / before[r.frame]
        for r in rows
        if r.setting == setting and r.frame in before
    }


def dam_frames_section(rows: Sequence[DamFrameRow], setting: str = "preset balanced") -> list[str]:
    """REPORT.md's per-frame table for `setting` beside the pre-issue default (and the
    unfiltered splat's droplet error, when it was run), and how many frames meet each of the
    issue's items (empty without rows for both)."""
    ratios = band_ratios(rows, setting)
    if not ratios:
        return []
    before = {r.frame: r for r in rows if r.setting == PLAIN_SMOOTHING.name}
    after = {r.frame: r for r in rows if r.setting == setting}
    raw = {r.frame: r for r in rows if r.setting == UNFILTERED.name}
    head = ["frame", "pre-issue band°", f"{setting} band°", "ratio", "mean°", "flicker°"]
    head += ["truth's flicker°", "edge alpha (all / silhouettes)", "droplet° (unfiltered)"]
    head += ["finite"]
    lines = [
        "## The dam break, every frame",
        "",
        "The figures above are of one frame. Here every frame of the data set at the same "
        "size, camera and jitter, each against its own pysplashsurf reference (band: 1 px "
        "tolerant; mean: all pixels both cover; finite: no NaN or Inf in any output pixel of "
        "the frame or its jittered copy, every setting), and against the union of its particle "
        "spheres, the spatter's analytic truth (`sphere_union.py`): edge alpha over all the "
        "union's edge pixels / over its silhouettes against background (next to a pixel that "
        "both it and the pysplashsurf reference leave empty); droplet: the normal error over "
        "the pixels of lone particles (none other within 4 r).",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for frame, ratio in ratios.items():
        a, b = after[frame], before[frame]
        unfiltered = f" ({_cell(raw[frame].droplet_deg, 2)})" if frame in raw else ""
        cells = [frame.rsplit("_", 1)[-1], f"{b.band_deg:.2f}", f"{a.band_deg:.2f}"]
        # One decimal: a frame just past the limit must not read as on it (40.3 % is not 40).
        cells += [f"{100 * ratio:.1f} %", f"{a.mean_deg:.2f}", f"{a.flicker_deg:.3f}"]
        alpha = f"{_cell(a.edge_alpha, 3)} / {_cell(a.edge_alpha_silhouettes, 3)}"
        cells += [f"{a.floor_deg:.3f}", alpha, f"{_cell(a.droplet_deg, 2)}{unfiltered}"]
        cells += ["yes" if a.finite else "NO"]
        lines.append("| " + " | ".join(cells) + " |")
    counts = dam_frame_counts(rows, setting)
    assert counts is not None  # the same rows as `ratios`
    return [*lines, "", *_verdicts(counts, [after[f] for f in ratios])]


def _cell(value: float, digits: int) -> str:
    """A table cell: '-' for a figure not measured on the frame (no lone particle in view)."""
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def _worst(values: Iterable[float]) -> float:
    """The largest of `values` that is a number (nan: none is; a frame without edge pixels
    has nothing to be worst at)."""
    numbers = [v for v in values if not math.isnan(v)]
    return max(numbers) if numbers else math.nan


@dataclass(frozen=True)
class DamCounts:
    """On how many of the `frames` each of the issue's items holds for one setting, and the
    worst value of each; droplets count only the frames with lone particles in view and an
    unfiltered row to compare with (`droplet_frames`)."""

    frames: int
    band_ok: int
    worst_band_ratio: float
    flicker_ok: int
    floor_low: int  # the truth's own flicker within the limit
    alpha_ok: int
    worst_alpha: float
    silhouettes_ok: int
    worst_silhouettes: float
    droplet_frames: int
    droplets_ok: int
    finite: bool


def dam_frame_counts(rows: Sequence[DamFrameRow], setting: str) -> DamCounts | None:
    """`DamCounts` of `setting` (None without rows for it and the pre-issue default)."""
    ratios = band_ratios(rows, setting)
    if not ratios:
        return None
    after = {r.frame: r for r in rows if r.setting == setting}
    raw = {r.frame: r for r in rows if r.setting == UNFILTERED.name}
    mine = [after[f] for f in ratios]
    with_drops = [f for f in ratios if after[f].droplet_px > 0 and f in raw]
    return DamCounts(
        frames=len(ratios),
        band_ok=sum(r <= BAND_LIMIT for r in ratios.values()),
        worst_band_ratio=max(ratios.values()),
        flicker_ok=sum(r.flicker_deg <= FLICKER_LIMIT_DEG for r in mine),
        floor_low=sum(r.floor_deg <= FLICKER_LIMIT_DEG for r in mine),
        alpha_ok=sum(r.edge_alpha <= EDGE_ALPHA_LIMIT for r in mine),
        worst_alpha=_worst(r.edge_alpha for r in mine),
        silhouettes_ok=sum(r.edge_alpha_silhouettes <= EDGE_ALPHA_LIMIT for r in mine),
        worst_silhouettes=_worst(r.edge_alpha_silhouettes for r in mine),
        droplet_frames=len(with_drops),
        droplets_ok=sum(
            after[f].droplet_deg <= DROPLET_LIMIT * raw[f].droplet_deg for f in with_drops
        ),
        finite=all(r.finite for r in rows),
    )


def surface_notes(counts: DamCounts | None) -> dict[str, str]:
    """What the report's surface targets add for the dam-break frames, by target line
    (`BenchResults.surface_notes`); empty without counts."""
    if counts is None:
        return {}
    notes = {
        "edge_alpha": (
            f"; on the dam-break frames (below), against the union of their particle spheres, "
            f"on {counts.alpha_ok} of {counts.frames} over all its edge pixels (worst "
            f"{_cell(counts.worst_alpha, 3)}), on {counts.silhouettes_ok} of {counts.frames} "
            f"over its silhouettes against background (worst "
            f"{_cell(counts.worst_silhouettes, 3)})"
        ),
        "band": (
            f"; every frame (below): on {counts.band_ok} of {counts.frames} (worst "
            f"{100 * counts.worst_band_ratio:.1f} %)"
        ),
    }
    if counts.droplet_frames:
        notes["droplets"] = (
            f"; on the dam-break frames (below) on {counts.droplets_ok} of the "
            f"{counts.droplet_frames} with lone particles in view"
        )
    return notes


def _verdicts(counts: DamCounts, mine: Sequence[DamFrameRow]) -> list[str]:
    """The per-frame section's bullets: on how many frames each item holds (`counts`), and
    what the gaps hold on the setting's own rows (`mine`)."""
    n = counts.frames
    lines = [
        f"* band <= {100 * BAND_LIMIT:.0f} % of the pre-issue default's on {counts.band_ok} of "
        f"{n} frames (worst {100 * counts.worst_band_ratio:.1f} %)",
        f"* flicker <= {FLICKER_LIMIT_DEG}° on {counts.flicker_ok} of {n} frames; the "
        f"truth's own flicker is <= {FLICKER_LIMIT_DEG}° on {counts.floor_low} of them",
        f"* edge alpha <= {EDGE_ALPHA_LIMIT} over all the union's edge pixels on "
        f"{counts.alpha_ok} of {n} frames (worst {counts.worst_alpha:.3f}); over its "
        f"silhouettes against background on {counts.silhouettes_ok} of {n} (worst "
        f"{counts.worst_silhouettes:.3f})",
    ]
    gaps = [r for r in mine if np.isfinite(r.gap_spheres)]
    if gaps:
        share = np.mean([g.gap_share for g in gaps])
        lines.append(
            f"  * the others are gaps between the spheres of sparse sheets "
            f"({100 * share:.0f} % of the edge pixels, mean over the frames): there the spheres "
            f"cover {np.mean([g.gap_spheres for g in gaps]):.2f} of a pixel, the pysplashsurf "
            f"reference {np.mean([g.gap_reference for g in gaps]):.2f} and the render's alpha "
            f"is {np.mean([g.gap_alpha for g in gaps]):.2f} (gap closing draws the sheet whole)"
        )
    if counts.droplet_frames:
        lines.append(
            f"* droplet error <= {DROPLET_LIMIT}x the unfiltered splat's on "
            f"{counts.droplets_ok} of the {counts.droplet_frames} frames with lone particles "
            f"in view"
        )
    lines.append(
        f"* every output pixel finite on every frame and setting: "
        f"{'yes' if counts.finite else 'NO'}"
    )
    return lines
