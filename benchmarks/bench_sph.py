"""SPH pass timings against peers measured in the same run, and surface-only splatting's
error and speed (not run by CI).

Part 1, for 100k and 500k particles (a jittered lattice ball, r = 0.015, h = 4 r, m = 1000 (2r)^3):
  * OpenCL pass: `SphEngine.compute` (host split into cells, counting sort, prefix sum, density,
    colour field + gradient + surface flags, read-back of everything), median of 3 warm runs;
  * OpenCL neighbour lists alone (`SphEngine.neighbour_lists`, CSR read back);
  * scipy reference: `tests/sph_reference.py` (cKDTree pairs + float64 numpy sums), one run;
  * pysplashsurf's `neighborhood_search_spatial_hashing_parallel` (Rust, rayon), median of 3,
    if it is installed (`pip install '.[bench]'`).
Ratios are printed as "x faster" of the OpenCL pass.

Part 3 (`--anisotropy`, instead of parts 1 and 2): `SphEngine.anisotropy` (Yu & Turk ellipsoids,
R = 1.0 h and the default 1.5 h, N_eps = 25, k_r = 4) against the density + colour field pass
(`SphEngine.compute`, no gradient read-back, as the renderer calls it) on the same balls, median
of 3 warm runs each, host work and read-back included.

Part 4 (`--below`, instead of parts 1 and 2): `SphEngine.density_below` (the droplet split's
and the lone rule's question, shaders/sph/density_below.cl) against `SphEngine.density` and a
comparison with the limit, at 0.36 and 0.45 rest density, on the balls, the balls with 3 %
spray over them, and every dam-break frame of ../shared/data (when present): median of 5
warm runs each, host work and read-back included, and the particles whose answers differ.

Part 2: the renderer at 1280x720 with and without `[sph] surface_only`, on the 500k ball and a
dam-break frame: stage times, particles drawn, and the error (coverage must be identical; share
of covered pixels whose depth moves by more than 1%).

    .venv/bin/python benchmarks/bench_sph.py [--sizes 100000 500000] [--no-render]
        [--anisotropy | --below]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from sphrender.core.frame import make_frame  # noqa: E402
from sphrender.core.readers import read_particles  # noqa: E402
from sphrender.server.content.lattice import jittered_lattice_ball  # noqa: E402
from sphrender.server.engine.gpu.cl_context import CLContext  # noqa: E402
from sphrender.server.engine.sph.anisotropy import AnisotropyParameters  # noqa: E402
from sphrender.server.engine.sph.engine import SphEngine, SphParameters  # noqa: E402
from sphrender.server.scene import Scene, scene_from_dict  # noqa: E402

R = 0.015
H = 4 * R
MASS = 1000.0 * (2 * R) ** 3
DAMBREAK = REPO.parent / "shared" / "data" / "dambreak-splishsplash" / "vtk"


def ball(count: int) -> np.ndarray:
    radius = (count * (2 * R) ** 3 * 3 / (4 * np.pi)) ** (1 / 3)
    return jittered_lattice_ball(radius, R, jitter=0.3, seed=1)


def timed(function: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    times = []
    result = None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result


def bench_pass(engine: SphEngine, count: int) -> None:
    from sph_reference import reference_sph  # scipy: not needed by --below (gpu_check.sh)

    positions = ball(count)
    params = SphParameters(H, MASS, 1000.0, 0.5 / H, 750.0, 0.9 * H)
    engine.compute(positions, params)  # warm-up: buffers
    t_cl, result = timed(lambda: engine.compute(positions, params), 3)
    engine.neighbour_lists(positions, H)
    t_nl, _ = timed(lambda: engine.neighbour_lists(positions, H), 3)
    t_ref, ref = timed(lambda: reference_sph(positions, H, MASS), 1)
    err = float(np.median(np.abs(result.density / ref.density - 1)))
    print(f"\n{len(positions)} particles (ball), h = {H}, {result.surface.mean():.1%} surface")
    print(f"  OpenCL pass (density+colour+gradient+flags): {t_cl * 1e3:8.1f} ms")
    print(f"  OpenCL neighbour lists (CSR):                {t_nl * 1e3:8.1f} ms")
    print(
        f"  scipy cKDTree reference (float64):           {t_ref * 1e3:8.1f} ms"
        f"   -> OpenCL pass {t_ref / t_cl:5.1f}x faster (median density rel. err {err:.1e})"
    )
    try:
        import pysplashsurf
    except ImportError:
        print("  pysplashsurf: not installed (pip install '.[bench]')")
        return
    domain = pysplashsurf.Aabb3d.from_points(positions)
    search = pysplashsurf.neighborhood_search_spatial_hashing_parallel
    search(positions, domain, H)
    t_ss, _ = timed(lambda: search(positions, domain, H), 3)
    print(
        f"  pysplashsurf neighbourhood search (rayon):   {t_ss * 1e3:8.1f} ms"
        f"   -> OpenCL pass / pysplashsurf search = {t_cl / t_ss:4.2f}, "
        f"OpenCL lists / pysplashsurf search = {t_nl / t_ss:4.2f}"
    )


def bench_anisotropy(engine: SphEngine, count: int) -> None:
    positions = ball(count)
    params = SphParameters(H, MASS, 1000.0, 0.5 / H, 750.0, 0.9 * H)
    engine.compute(positions, params, gradient=False)  # warm-up: buffers
    t_sph, _ = timed(lambda: engine.compute(positions, params, gradient=False), 3)
    print(f"\n{len(positions)} particles (ball), h = {H}")
    print(f"  density + colour field pass (compute):       {t_sph * 1e3:8.1f} ms")
    for factor in (1.0, 1.5):
        aniso = AnisotropyParameters(factor * H, 4.0, 25, 0.5)
        engine.anisotropy(positions, aniso, R)  # warm-up: program, buffers
        t_an, result = timed(lambda a=aniso: engine.anisotropy(positions, a, R), 3)
        print(
            f"  anisotropy, R = {factor:.1f} h (median {np.median(result.neighbour_count):5.0f} "
            f"neighbours, {result.is_sphere.mean():5.1%} spheres): {t_an * 1e3:8.1f} ms"
            f"   = {t_an / t_sph:4.2f}x the density + colour pass"
        )


def bench_below(engine: SphEngine, name: str, positions: np.ndarray) -> None:
    """density_below against density + comparison, at the lone rule's and the split's limits."""
    params = SphParameters(H, MASS, 1000.0, 0.5 / H, 750.0, 0.9 * H)
    engine.density(positions, params)  # warm-up: buffers, programs
    t_density, density = timed(lambda: engine.density(positions, params), 5)
    print(f"\n{name}: {len(positions)} particles, h = {H}")
    print(f"  density pass, then < limit:                  {t_density * 1e3:8.1f} ms")
    for fraction in (0.36, 0.45):
        below = fraction * 1000.0
        engine.density_below(positions, params, below)
        t_below, answer = timed(lambda b=below: engine.density_below(positions, params, b), 5)
        differ = int((answer != (density < below)).sum())
        print(
            f"  density_below({fraction:.2f} rest): {int(answer.sum()):6d} below  "
            f"{t_below * 1e3:8.1f} ms   = {t_density / t_below:4.1f}x faster, "
            f"{differ} answers differ"
        )


def bench_below_all(engine: SphEngine, sizes: list[int]) -> None:
    rng = np.random.default_rng(2)
    for count in sizes:
        positions = ball(count)
        bench_below(engine, "ball", positions)
        extent = float(np.abs(positions).max())
        spray = rng.uniform(-1.5 * extent, 1.5 * extent, (count * 3 // 100, 3))
        bench_below(engine, "ball + 3 % spray", np.concatenate([positions, spray]))
    frames = sorted(DAMBREAK.glob("*.vtk"), key=lambda p: int(p.stem.rsplit("_", 1)[1]))
    for path in frames:
        bench_below(engine, f"dam break {path.stem}", read_particles(path).positions)


def render_scene(radius: float, eye: list[float], target: list[float], **sph: Any) -> Scene:
    return scene_from_dict(
        {
            "image": {"width": 1280, "height": 720},
            "camera": {"eye": eye, "target": target, "fov_y": 40.0},
            "particles": {"radius": radius},
            "sph": sph,
        }
    )


def bench_surface_only(name: str, positions: np.ndarray, scene: Scene) -> None:
    from sphrender.server.engine.gpu.gl_context import GLContext
    from sphrender.server.engine.renderer import SurfaceRenderer

    frame = make_frame(positions)
    only = scene.with_overrides(sph=scene_from_dict({"sph": {"surface_only": True}}).sph)
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)
        try:
            results = {}
            for label, s in (("full", scene), ("surface_only", only)):
                renderer.render(frame, s, depth=True)  # warm-up
                runs = [renderer.render(frame, s, depth=True) for _ in range(3)]
                totals = [stats.total_ms for _, stats in runs]
                best = runs[int(np.argsort(totals)[1])]
                results[label] = best
            (full, full_stats), (part, part_stats) = results["full"], results["surface_only"]
            assert full.depth is not None and part.depth is not None
            covered = np.isfinite(full.depth)
            holes = int((covered != np.isfinite(part.depth)).sum())
            moved = np.abs(part.depth[covered] - full.depth[covered]) > 1e-2 * full.depth[covered]
            print(f"\nsurface-only splatting, {name}, 1280x720 (median of 3):")
            for label, stats in (("full", full_stats), ("surface_only", part_stats)):
                stages = " ".join(f"{k}={v:.0f}" for k, v in stats.stage_ms.items())
                print(
                    f"  {label:13s} drawn {stats.particles_drawn:7d}  total {stats.total_ms:7.1f}"
                    f" ms  ({stages})"
                )
            splat_gain = full_stats.stage_ms["splat"] / part_stats.stage_ms["splat"]
            print(
                f"  splat {splat_gain:.2f}x faster; whole frame "
                f"{full_stats.total_ms / part_stats.total_ms:.2f}x; "
                f"coverage differs in {holes} px; depth moved >1% in "
                f"{moved.mean():.3%} of {covered.sum()} covered px"
            )
        finally:
            renderer.release()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100_000, 500_000])
    parser.add_argument("--no-render", action="store_true", help="skip part 2")
    parser.add_argument("--anisotropy", action="store_true", help="part 3 only")
    parser.add_argument("--below", action="store_true", help="part 4 only")
    args = parser.parse_args()
    with CLContext() as cl:
        print(f"OpenCL device: {cl.device_info.label}")
        engine = SphEngine(cl)
        try:
            if args.below:
                bench_below_all(engine, args.sizes)
            else:
                for count in args.sizes:
                    (bench_anisotropy if args.anisotropy else bench_pass)(engine, count)
        finally:
            engine.release()
    if args.no_render or args.anisotropy or args.below:
        return
    big = ball(max(args.sizes))
    extent = float(np.abs(big).max())
    bench_surface_only(
        f"{len(big)}-particle ball",
        big,
        render_scene(R, [1.3 * extent, 1.0 * extent, 1.7 * extent], [0.0, 0.0, 0.0]),
    )
    frame_path = DAMBREAK / "ParticleData_Fluid_5.vtk"
    if frame_path.exists():
        bench_surface_only(
            "dam-break frame 5 (32k)",
            read_particles(frame_path).positions,
            render_scene(R, [0.5, 2.5, 4.0], [-0.5, 0.4, 0.0]),
        )


if __name__ == "__main__":
    main()
