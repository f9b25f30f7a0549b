"""The SPH stage of a frame: whether a scene needs it, and what it changes in the frame the splat
draws (eq 29 radii, surface-only splatting, anisotropic ellipsoids) and which particles skip the
smoothing (`droplets.py`). `SphStage` owns the OpenCL context and engine, created on the first
frame that needs them, on the GL owner thread."""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.frame_output import InputNote
from sphrender.server.engine.gpu.cl_context import CLContext, CLDeviceInfo, CLUnavailableError
from sphrender.server.engine.sph.anisotropy import AnisotropyParameters, AnisotropyResult
from sphrender.server.engine.sph.droplets import (
    computes_droplet_densities,
    droplet_mask,
    lone_particles,
    splits_droplets,
)
from sphrender.server.engine.sph.engine import SphEngine, SphParameters, SphResult
from sphrender.server.engine.sph.frame_densities import unfit_note, without_unfit_densities
from sphrender.server.engine.sph.radii import (
    F32,
    adaptive_radii,
    frame_particle_radius,
    surface_density,
)
from sphrender.server.scene import Scene

log = logging.getLogger("sphrender.sph")


def needs_sph(scene: Scene) -> bool:
    """Whether a frame of this scene needs the SPH pass at all (compute only what is needed).

    Densities alone are needed by no feature yet, so a client that sends none costs nothing
    unless adaptive radii, surface-only splatting or anisotropy are on."""
    sph = scene.sph
    return sph.adaptive_radius or sph.surface_only or sph.anisotropy


def frame_adaptive_radii(result: SphResult, frame: ParticleFrame, scene: Scene) -> F32:
    """The adaptive radii (thesis eq 29) for this frame: the body radius (the frame's radii,
    else the scene's) shrunk for particles less dense than the surface average."""
    body: float | F32 = frame.radii if frame.radii is not None else scene.particles.radius
    return adaptive_radii(
        result.density,
        body,
        surface_density(result.density, result.surface),
        min_fraction=scene.sph.min_radius,
        decline=scene.sph.radius_decline,
    )


@dataclass(frozen=True)
class SphFrame:
    """What the SPH stage made of one frame."""

    #: What the splat draws: eq 29 radii and/or only the particles to splat (positions are the
    #: client's, not the smoothed centres).
    frame: ParticleFrame
    #: Density, colour field, surface flags of the INPUT frame's particles; None when neither
    #: adaptive radii nor surface-only splatting asked for them.
    sph: SphResult | None
    #: Ellipsoids of `frame`'s particles (same order and subset; axes scaled by the radii the
    #: splat uses, eq 29's when on); None when `sph.anisotropy` is off or was not asked for.
    anisotropy: AnisotropyResult | None


def apply_sph(
    engine: SphEngine, frame: ParticleFrame, scene: Scene, *, anisotropy: bool = True
) -> SphFrame:
    """Everything the scene's [sph] asks for: eq 29 radii, the surface-only subset and (when
    `anisotropy` and ``scene.sph.anisotropy``) the ellipsoids. Anisotropy is computed over all
    particles (hidden interior ones shape the surface's neighbourhoods), then subset."""
    particle_radius = frame_particle_radius(frame, scene)
    params = SphParameters.from_scene(scene, particle_radius)
    sph = scene.sph
    result = None
    radii = frame.radii
    if sph.adaptive_radius or sph.surface_only:
        result = engine.compute(
            frame.positions,
            params,
            frame.densities,
            gradient=False,
            splat_mask=sph.surface_only,
        )
        if sph.adaptive_radius:
            radii = frame_adaptive_radii(result, frame, scene)
    ellipsoids = None
    if anisotropy and sph.anisotropy:
        ellipsoids = engine.anisotropy(
            frame.positions,
            AnisotropyParameters.from_scene(scene, params.support_radius),
            radii if radii is not None else scene.particles.radius,
        )
    densities = frame.densities if result is None else result.density
    out = replace(frame, radii=radii, densities=densities)
    if result is not None and result.splat_keep is not None:
        keep = result.splat_keep
        out = ParticleFrame(
            positions=out.positions[keep],
            densities=None if out.densities is None else out.densities[keep],
            radii=None if out.radii is None else out.radii[keep],
            temperatures=None if out.temperatures is None else out.temperatures[keep],
            peak_temperatures=None
            if out.peak_temperatures is None
            else out.peak_temperatures[keep],
        )
        ellipsoids = None if ellipsoids is None else ellipsoids.subset(keep)
    return SphFrame(out, result, ellipsoids)


def apply_to_frame(
    engine: SphEngine, frame: ParticleFrame, scene: Scene
) -> tuple[ParticleFrame, SphResult | None]:
    """The sphere path: the frame the splat pass should draw (eq 29 radii and/or only the
    particles to splat) and the SPH result (None when no feature needed it). Computes no
    anisotropy; the ellipsoid splat takes `apply_sph`'s `SphFrame.anisotropy`."""
    out = apply_sph(engine, frame, scene, anisotropy=False)
    return out.frame, out.sph


@dataclass(frozen=True)
class SphOutcome:
    """What the SPH stage changes in a frame, for the renderer."""

    frame: ParticleFrame  # eq 29 radii, surface-only subset (or the frame as it came)
    reference_radius: float | None = None  # the radius the smoothing follows (None: frame's)
    droplets: npt.NDArray[np.bool_] | None = None  # which particles skip smoothing
    ellipsoids: tuple[npt.NDArray[np.float64], F32] | None = None  # (centres, semi-axes)
    notes: tuple[InputNote, ...] = ()  # what was changed about the frame's input


class SphStage:
    """The renderer's SPH stage: a lazily created `CLContext` + `SphEngine` (device from
    `cl_device`, None = probe), released with the renderer."""

    def __init__(self, cl_device: str | None = None) -> None:
        self._cl_device = cl_device
        self._warned = False
        self._warned_densities = False
        self._warned_lone = False
        self._cl: CLContext | None = None
        self._engine: SphEngine | None = None

    def device(self) -> CLDeviceInfo:
        """The OpenCL device the stage uses, its context created now if it was not yet (raises
        `CLUnavailableError` without one)."""
        if self._cl is None:
            self._cl = CLContext(self._cl_device)
        return self._cl.device_info

    def engine(self) -> SphEngine:
        """The engine and its CL context, created on first use (the caller's thread owns it)."""
        if self._engine is None:
            if self._cl is None:
                self._cl = CLContext(self._cl_device)
            self._engine = SphEngine(self._cl)
        return self._engine

    @staticmethod
    def wanted(scene: Scene, frame: ParticleFrame) -> bool:
        """Whether this frame needs the stage: an [sph] feature, or exact droplets with the
        frame's densities or with leave to compute them (`quality.droplet_density_pass`)."""
        return needs_sph(scene) or splits_droplets(scene, frame)

    def warm(self, frame: ParticleFrame, scene: Scene) -> None:
        """Build the CL context and program now if this frame will need them (so the first
        frame's stage time is the pass's, not LLVM's)."""
        frame, scene = without_unfit_densities(frame, scene)
        own = computes_droplet_densities(scene, frame)
        if needs_sph(scene) or own:
            try:
                engine = self.engine()
                if own:
                    engine.density_below_kernels()
            except CLUnavailableError:
                if needs_sph(scene):
                    raise

    def run(self, frame: ParticleFrame, scene: Scene) -> SphOutcome:
        """Everything the scene asks of SPH for this frame (on the owner thread). Exact droplets
        without OpenCL (and without client densities) are skipped with one warning: the frame
        still renders, its droplets smoothed as without the option. Densities the stage cannot
        use (other units, one value for all: frame_densities.py) are replaced by computed ones,
        with a note for the client."""
        given = frame
        frame, scene = without_unfit_densities(frame, scene)
        reference_radius = frame_particle_radius(frame, scene)
        ellipsoids = droplets = computed = None
        drawn = frame
        if needs_sph(scene):
            result = apply_sph(self.engine(), frame, scene)
            drawn, computed = result.frame, result.sph
            if result.anisotropy is not None:
                ellipsoids = (result.anisotropy.centers, result.anisotropy.axes)
        skipped: CLUnavailableError | None = None
        lone_skipped: CLUnavailableError | None = None
        if splits_droplets(scene, drawn):
            try:
                droplets = droplet_mask(frame, scene, self.engine, computed)
            except CLUnavailableError as exc:
                skipped = exc
                if not self._warned:
                    log.warning(
                        "exact droplets need densities or OpenCL, rendering without: %s", exc
                    )
                    self._warned = True
            if droplets is not None:
                droplets, lone_skipped = self._with_lone(droplets, frame, scene, computed)
                if computed is not None and computed.splat_keep is not None:
                    droplets = droplets[computed.splat_keep]
        notes = self._notes(given, frame, scene, skipped)
        if lone_skipped is not None:
            message = f"skipped: no OpenCL device to find the lone particles ({lone_skipped})"
            notes += (InputNote("quality.droplet_lone_density", message),)
        return SphOutcome(drawn, reference_radius, droplets, ellipsoids, notes)

    def _with_lone(
        self,
        droplets: npt.NDArray[np.bool_],
        frame: ParticleFrame,
        scene: Scene,
        computed: SphResult | None,
    ) -> tuple[npt.NDArray[np.bool_], CLUnavailableError | None]:
        """`droplets` and the frame's lone particles (`lone_particles`); without OpenCL the
        frame's densities' droplets alone, and why (warned once)."""
        try:
            lone = lone_particles(frame, scene, self.engine, computed)
        except CLUnavailableError as exc:
            if not self._warned_lone:
                log.warning(
                    "lone droplets need OpenCL, splitting on the frame's densities: %s", exc
                )
                self._warned_lone = True
            return droplets, exc
        return (droplets if lone is None else droplets | lone), None

    def _notes(
        self,
        given: ParticleFrame,
        used: ParticleFrame,
        scene: Scene,
        skipped: CLUnavailableError | None,
    ) -> tuple[InputNote, ...]:
        """What the client is told: the frame's densities replaced (`used` is not `given`;
        logged the first time), or exact droplets skipped for want of OpenCL."""
        if used is not given:
            note = unfit_note(given, scene, computed=skipped is None)
            if not self._warned_densities:
                log.warning("%s: %s", note.field, note.message)
                self._warned_densities = True
            return (note,)
        if skipped is not None:
            message = f"skipped: no OpenCL device to compute the frame's densities ({skipped})"
            return (InputNote("quality.exact_droplets", message),)
        return ()

    def release(self) -> None:
        if self._engine is not None:
            self._engine.release()
            self._engine = None
        if self._cl is not None:
            self._cl.release()
            self._cl = None
