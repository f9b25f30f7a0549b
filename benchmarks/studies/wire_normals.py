"""How rendered normals respond to the position error bound, against the impostor law.

A sphere impostor's normal at a fixed pixel turns by d/r radians when its centre moves d across
the view; a uniform error in [-b, b] per axis moves it by E|d| = 0.765 b (the mean length of
the 2-D projection of a uniform cube's offset), so the predicted mean change is 0.765 b / r
radians. This renders one dam-break frame (as bench_wire's image table: 32,768 particles,
preset balanced, 256x160) decoded at several bounds against its float32 input, fits
mean = a * (b / r)^p over the bounds, solves for the bound that gives `TARGET_DEG`, and
interpolates the session's positions bytes a particle (98,304 particles, bench_wire's
sequence) at that bound. Beside it, the truth's own change: the bench's reference surface for
the dam break (splashsurf's reconstruction, server/bench/mesh_reference.py) of the decoded
positions against that of the float32 input, rasterised with the same camera; a renderer that
follows the truth changes by as much.

    .venv/bin/python -m benchmarks.studies.wire_normals   (from the repository root)
"""

from __future__ import annotations

import math

import numpy as np

from benchmarks.studies.wire import (
    DAM_RADIUS,
    codec_rows,
    dam_sequence,
    image_change,
    truth_change,
)
from benchmarks.studies.wire_report import DAM_CAMERA

FRACTIONS = (1 / 100, 1 / 200, 1 / 400, 1 / 800)
TARGET_DEG = 0.1
#: Mean |d| / b for an error uniform in [-b, b] on each of the two axes across the view.
PROJECTED_MEAN = 0.765


def main() -> None:
    dam = dam_sequence(3)
    assert dam is not None, "needs ../shared/data"
    one = [{k: v[: len(v) // 3] for k, v in frame.items()} for frame in dam]
    changes = image_change(one, DAM_RADIUS, DAM_CAMERA, FRACTIONS)
    truth = truth_change(one[len(one) // 2], DAM_RADIUS, DAM_CAMERA, FRACTIONS)
    rows = {r.fraction: r for r in codec_rows("dam break", dam, DAM_RADIUS, FRACTIONS, 1)}
    print("| bound | predicted mean° | measured mean° | p99° | truth's own mean° | truth p99° | "
          "positions B/particle | frame B/particle |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for change, (t_mean, t_p99) in zip(changes, truth, strict=True):
        fraction, mean, p99 = change[:3]
        predicted = math.degrees(PROJECTED_MEAN * fraction)
        row = rows[fraction]
        print(f"| r/{round(1 / fraction)} | {predicted:.3f} | {mean:.3f} | {p99:.2f} | "
              f"{t_mean:.3f} | {t_p99:.2f} | {row.positions_bpp:.2f} | "
              f"{row.frame_bpp:.2f} |")  # fmt: skip
    x = np.log([c[0] for c in changes])
    slope, intercept = np.polyfit(x, np.log([c[1] for c in changes]), 1)
    bound = math.exp((math.log(TARGET_DEG) - intercept) / slope)
    size = np.interp(math.log(bound), x[::-1], [rows[f].positions_bpp for f in FRACTIONS][::-1])
    frame = np.interp(math.log(bound), x[::-1], [rows[f].frame_bpp for f in FRACTIONS][::-1])
    print(f"\nfit: mean° = {math.exp(intercept):.1f} x (b/r)^{slope:.2f}; {TARGET_DEG}° at "
          f"b = r/{1 / bound:.0f}; positions {size:.2f} B/particle, frame {frame:.2f} "
          f"(interpolated in log b)")  # fmt: skip


if __name__ == "__main__":
    main()
