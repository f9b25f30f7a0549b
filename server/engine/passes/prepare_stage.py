"""The prepare stage: a frame's particles into the splat's buffers, on the host or the device.

Two implementations give the same depth image (tested, up to depth-buffer ties):

* host (`geometry/prepare.py`): the CPU culls and rotates to view space in float64, computes each
  sphere's screen rectangle (`geometry/occlusion.py`) and the screen box, and uploads the visible
  spheres once. Its rectangles let the splat cull hidden particles exactly (front layer + range
  maximum), which is what pays on llvmpipe, where rasterising is the cost.
* device (`passes/device_prepare.py`): the client's arrays are uploaded as they are and a compute
  shader does the same per-particle work; the host's share is the upload. What pays on a GPU,
  whose rasteriser makes hidden quads nearly free while every millisecond of Python is frame time.

`PREPARE_MODES`: "host", "device", or "auto" = device on a hardware GPU, host on a software
rasteriser (measured: `benchmarks/bench_host.py`; ARCHITECTURE.md has the numbers). The
environment variable SPHRENDER_PREPARE (one of the modes) overrides "auto", so an operator can
switch a server without a code change.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.geometry import occlusion
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.prepare import PreparedParticles, prepare_particles
from sphrender.server.engine.geometry.screen_box import ScreenBox, screen_box
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.device_culling import DeviceCullInput
from sphrender.server.engine.passes.device_prepare import DevicePrepare
from sphrender.server.engine.passes.field_grid import FieldParticles
from sphrender.server.engine.passes.splat import SplatBatch, SplatPass
from sphrender.server.engine.passes.splat_buffers import SPHERES
from sphrender.server.engine.sph.frame import SphOutcome
from sphrender.server.scene import Scene

PrepareMode = Literal["auto", "host", "device"]
PREPARE_MODES: tuple[PrepareMode, ...] = ("auto", "host", "device")


@dataclass(frozen=True)
class PreparedFrame:
    """A frame ready to splat: the bulk in the splat's buffers, the droplets to follow."""

    bulk: SplatBatch
    #: The exact droplets: already in the buffers (device) or still on the host (uploaded by
    #: `PrepareStage.droplets` once the bulk is drawn); None when there are none.
    droplets: SplatBatch | PreparedParticles | None
    bounds: occlusion.SphereBounds | None  # host prepare: the bulk's rectangles (culling)
    device_cull: DeviceCullInput | None  # device prepare with occlusion culling
    box: ScreenBox | None
    visible: int
    far: float
    reference_radius: float
    #: Host prepare: every visible particle (bulk and droplets), view space, on the CPU.
    centres: npt.NDArray[np.float32] | None = None


def resolve_mode(mode: str, software: bool) -> PrepareMode:
    """ "host" or "device" for `mode` on a software (llvmpipe) or hardware GL."""
    if mode == "auto":
        mode = os.environ.get("SPHRENDER_PREPARE", "auto") or "auto"
        where = "SPHRENDER_PREPARE"
    else:
        where = "prepare"
    if mode not in PREPARE_MODES:
        raise ValueError(f"{where} must be one of {', '.join(PREPARE_MODES)}, got {mode!r}")
    if mode == "auto":
        return "host" if software else "device"
    return "device" if mode == "device" else "host"


class PrepareStage:
    def __init__(self, context: PassContext, splat: SplatPass, mode: PrepareMode) -> None:
        self._splat = splat
        self._device = DevicePrepare(context, splat.buffers)
        self.mode: PrepareMode = resolve_mode(mode, context.gl.is_software)

    def run(self, sph: SphOutcome, camera: Camera, scene: Scene) -> PreparedFrame:
        if self.mode == "device":
            return self._run_device(sph, camera, scene)
        return self._run_host(sph, camera, scene)

    def droplets(self, prepared: PreparedFrame) -> SplatBatch | None:
        """The droplets' batch, uploaded now when they are on the host (the bulk's draws,
        already issued, keep reading what they read: GL orders buffer writes after them)."""
        drops = prepared.droplets
        if isinstance(drops, PreparedParticles):
            return self._splat.upload(drops)
        return drops

    def field_particles(self, prepared: PreparedFrame) -> FieldParticles:
        """Every visible particle's centre for the field grid (passes/field_grid.py): the
        spheres in the splat's buffers (the device prepare's: its droplets are marked there,
        not uploaded over them; the host prepare's when the frame has no droplets), else the
        host's arrays (the droplets' upload replaced the bulk's in those buffers)."""
        if prepared.centres is not None and prepared.droplets is not None:
            return FieldParticles(arrays=(prepared.centres,))
        return FieldParticles(buffer=self._splat.buffers.buffer(SPHERES), count=prepared.bulk.count)

    def _run_device(self, sph: SphOutcome, camera: Camera, scene: Scene) -> PreparedFrame:
        device = self._device.run(
            sph.frame,
            camera,
            scene,
            reference_radius=sph.reference_radius,
            droplets=sph.droplets,
            ellipsoids=sph.ellipsoids,
        )
        cull = None
        if scene.quality.occlusion_culling and device.visible:
            cull = DeviceCullInput(
                device.bulk.count, device.nearest, device.bulk.far, device.reference_radius
            )
        return PreparedFrame(
            device.bulk,
            device.droplets,
            None,
            cull,
            device.box,
            device.visible,
            device.bulk.far,
            device.reference_radius,
        )

    def _run_host(self, sph: SphOutcome, camera: Camera, scene: Scene) -> PreparedFrame:
        frame: ParticleFrame = sph.frame
        prepared = prepare_particles(
            frame,
            camera,
            scene,
            reference_radius=sph.reference_radius,
            droplets=sph.droplets,
            ellipsoids=sph.ellipsoids,
        )
        bounds = occlusion.sphere_bounds(prepared.center_radius, camera)
        box = screen_box(bounds, camera)
        bulk: PreparedParticles = prepared
        drops: PreparedParticles | None = None
        if prepared.droplets is not None and prepared.droplets.any():
            bulk, drops = prepared.subset(~prepared.droplets), prepared.subset(prepared.droplets)
            bounds = bounds.subset(~prepared.droplets)
        return PreparedFrame(
            self._splat.upload(bulk),
            drops,
            bounds if scene.quality.occlusion_culling else None,
            None,
            box,
            int(prepared.center_radius.shape[0]),
            prepared.far,
            prepared.reference_radius,
            prepared.center_radius,
        )
