"""Surface quality on splashy frames per quality setting, for exploring settings beyond the
bench's: droplet error (spatter over a pool), edge alpha error, silhouette bands, flicker and the
lattice ball. The measurements are `sphrender bench`'s own (server/bench/surface_bench.py
`run_surface_bench`); this script only offers more settings to run them on.

Usage: python benchmarks/bench_surfaces.py [--width 960 --height 540] [--setting NAME ...]
       [--preset balanced --set sph.anisotropy=true --set quality.close_gaps=3 ...]
(`--set` runs one more setting: the preset with those overrides, values parsed as TOML.)
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

from sphrender.server.bench.surface_bench import run_surface_bench
from sphrender.server.bench.sweep import Setting
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer

SETTINGS = {
    "unfiltered": Setting(
        "unfiltered",
        overrides={"quality": {"filter": "none", "exact_droplets": False, "field_normals": 0.0}},
    ),
    "previous_default": Setting(
        "previous_default",
        preset="balanced",
        overrides={
            "quality": {
                "exact_droplets": False,
                "antialias": False,
                "kernel_max_px": 32,
                "kernel_max_stride": 1,
                "normal_stencil": 0.0,
                "last_pass_sigma": 1.0,
                "normal_rules": "hard",
                "narrow_range_pairs": 0.0,
                "close_gaps": 0.0,
                "field_normals": 0.0,
            }
        },
    ),
    "fast": Setting("fast", preset="fast"),
    "balanced": Setting("balanced", preset="balanced"),
    "best": Setting("best", preset="best"),
}
SETTINGS["balanced_aa"] = Setting(
    "balanced_aa",
    preset="balanced",
    overrides={"quality": {"exact_droplets": True, "antialias": True}},
)
SETTINGS["balanced_aniso"] = Setting(
    "balanced_aniso",
    preset="balanced",
    overrides={
        "quality": {"exact_droplets": True, "antialias": True},
        "sph": {"anisotropy": True},
    },
)
for _gap in (0.0, 1.0, 2.0, 3.0):
    SETTINGS[f"balanced_gaps{_gap:g}"] = Setting(
        f"balanced_gaps{_gap:g}", preset="balanced", overrides={"quality": {"close_gaps": _gap}}
    )
for _rim in (1.0, 2.0, 3.0):
    SETTINGS[f"balanced_rim{_rim:g}"] = Setting(
        f"balanced_rim{_rim:g}",
        preset="balanced",
        overrides={"quality": {"silhouette_normals": _rim}},
    )
    SETTINGS[f"balanced_gaps2_rim{_rim:g}"] = Setting(
        f"balanced_gaps2_rim{_rim:g}",
        preset="balanced",
        overrides={"quality": {"close_gaps": 2.0, "silhouette_normals": _rim}},
    )
SETTINGS["balanced_stencil0"] = Setting(
    "balanced_stencil0", preset="balanced", overrides={"quality": {"normal_stencil": 0.0}}
)
SETTINGS["best_gaps2_rim2"] = Setting(
    "best_gaps2_rim2",
    preset="best",
    overrides={"quality": {"close_gaps": 2.0, "silhouette_normals": 2.0}},
)
SETTINGS["best_no_gaps_rim"] = Setting(
    "best_no_gaps_rim",
    preset="best",
    overrides={"quality": {"close_gaps": 0.0, "silhouette_normals": 0.0}},
)
SETTINGS["balanced_droplets"] = Setting(
    "balanced_droplets", preset="balanced", overrides={"quality": {"exact_droplets": True}}
)
for _lam in (2.0, 3.0, 4.0, 6.0):
    SETTINGS[f"balanced_nr{_lam:g}"] = Setting(
        f"balanced_nr{_lam:g}",
        preset="balanced",
        overrides={"quality": {"narrow_range_threshold": _lam}},
    )


def custom_setting(preset: str, assignments: list[str]) -> Setting:
    """`preset` with `section.key=value` overrides (value in TOML syntax: 3, 0.5, true, "x")."""
    overrides: dict[str, dict[str, object]] = {}
    for assignment in assignments:
        key, sep, value = assignment.partition("=")
        section, dot, name = key.partition(".")
        if not sep or not dot:
            raise SystemExit(f"--set {assignment!r}: expected section.key=value")
        overrides.setdefault(section, {})[name] = tomllib.loads(f"v = {value}")["v"]
    return Setting(f"{preset} " + " ".join(assignments), preset=preset, overrides=overrides)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=960)
    parser.add_argument("--height", type=int, default=540)
    parser.add_argument("--setting", action="append", choices=sorted(SETTINGS))
    parser.add_argument("--preset", default="balanced", help="the preset --set starts from")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument(
        "--cache",
        type=Path,
        default=Path("benchmarks/.reference-cache"),
        help="where the pysplashsurf reference meshes are kept",
    )
    args = parser.parse_args()
    chosen = [SETTINGS[name] for name in args.setting or ([] if args.set else list(SETTINGS))]
    if args.set:
        chosen.append(custom_setting(args.preset, args.set))
    settings = tuple(chosen)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            run_surface_bench(
                gl, renderer, settings, width=args.width, height=args.height, cache=args.cache
            )
        finally:
            renderer.release()


if __name__ == "__main__":
    main()
