"""`sphrender sph INPUT -o OUT.npz`: the SPH quantities the renderer uses, computed on OpenCL."""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from sphrender.core.errors import InputError
from sphrender.server.cli.options import Subcommands, add_cl_device

log = logging.getLogger("sphrender")


def add_parser(commands: Subcommands, common: argparse.ArgumentParser) -> None:
    """Add this subcommand (its options and `run`) to `sphrender`'s parser."""
    sph = commands.add_parser(
        "sph",
        parents=[common],
        help="compute the SPH quantities the renderer uses and write them to .npz",
        description="Compute per-particle density, colour field (eq 26), its gradient (eq 27), "
        "surface flags (eq 28, |n| > t) and radius (eq 29 when [sph] adaptive_radius is on) on "
        "OpenCL, as the renderer sees them, and write them to an .npz: density, color_field, "
        "color_gradient (N x 3), surface (bool), radius, splat (bool: drawn by surface-only "
        "splatting), support_radius, mass and surface_density (absent without surface).",
    )
    sph.add_argument("input", metavar="INPUT", help="particle file (as for render)")
    sph.add_argument("--scene", type=Path, help="scene TOML (default: built-in defaults)")
    sph.add_argument("-o", "--output", type=Path, required=True, help="output .npz file")
    sph.add_argument(
        "--densities",
        choices=["input", "compute"],
        default="input",
        help="input: use the file's densities when it has them, they fit sph.rest_density "
        "(peak within 0.5-1.5x of it) and they are not all one value, as the renderer does "
        "(default); compute: always compute them (eq 2)",
    )
    add_cl_device(sph)
    sph.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    import io

    import numpy as np

    from sphrender.client.submit import write_atomically
    from sphrender.core.readers import read_particles
    from sphrender.server.engine.gpu.cl_context import CLContext
    from sphrender.server.engine.sph.engine import SphEngine, SphParameters
    from sphrender.server.engine.sph.frame import frame_adaptive_radii
    from sphrender.server.engine.sph.frame_densities import unfit_reason
    from sphrender.server.engine.sph.radii import frame_particle_radius, surface_density
    from sphrender.server.scene import Scene, load_scene

    scene = load_scene(args.scene) if args.scene else Scene()
    frame = read_particles(args.input)
    start = time.perf_counter()
    radius = frame_particle_radius(frame, scene)
    params = SphParameters.from_scene(scene, radius)
    reason = unfit_reason(frame, scene) if args.densities == "input" else None
    use_input = args.densities == "input" and reason is None
    if reason is not None:
        log.warning("%s: %s; computing them instead", args.input, reason)
    with CLContext(args.cl_device) as cl:
        log.info("OpenCL device: %s", cl.device_info.label)
        engine = SphEngine(cl)
        try:
            result = engine.compute(
                frame.positions,
                params,
                frame.densities if use_input else None,
                gradient=True,
                splat_mask=True,
            )
        finally:
            engine.release()
    d_surface = surface_density(result.density, result.surface)
    if scene.sph.adaptive_radius:
        radii = frame_adaptive_radii(result, frame, scene)
    elif frame.radii is not None:
        radii = frame.radii
    else:
        radii = np.full(frame.count, scene.particles.radius, dtype=np.float32)
    assert result.splat_keep is not None and result.color_gradient is not None
    arrays = {
        "density": result.density,
        "color_field": result.color_field,
        "color_gradient": result.color_gradient,
        "surface": result.surface,
        "radius": radii,
        "splat": result.splat_keep if scene.sph.surface_only else np.ones(frame.count, bool),
        "support_radius": np.float64(params.support_radius),
        "mass": np.float64(params.mass),
    }
    if d_surface is not None:
        arrays["surface_density"] = np.float64(d_surface)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # type: ignore[arg-type]
    try:
        write_atomically(args.output, buffer.getvalue())
    except OSError as exc:
        raise InputError("output", f"cannot write {args.output}: {exc.strerror or exc}") from None
    surface_share = float(result.surface.mean()) if frame.count else 0.0
    print(
        f"wrote {args.output}: {frame.count} particles, densities "
        f"{'computed' if result.density_computed else 'from input'}, "
        f"{surface_share:.1%} on the surface, {(time.perf_counter() - start) * 1e3:.0f} ms"
    )
    return 0
