"""The screen-space surface renderer: particles in, colour (+ depth, normals, 8-bit codes) out.

`SurfaceRenderer` orchestrates a frame and holds no GL code; each pass owns its programs,
targets and uniforms (`passes/`): sph (OpenCL, only when the scene asks) -> prepare (host or
device, `passes/prepare_stage.py`) -> splat (+ occlusion culling, coverage) -> smooth ->
droplets -> normals (+ field normals near rims) -> shadow (maps of the lights that cast them)
-> solids (a frame's solid particles, flat faces composed by depth) -> shade (temperature blur,
PBR + IBL + emission) [-> sub-frames averaged, with a shutter open] [-> glare] -> readback (+
display codes). ARCHITECTURE.md "Data flow of one frame" has each step. `RenderStats.host_ms`
is the frame's work outside GL calls (`gpu/gl_clock.py`).

One renderer belongs to one `GLContext` and is used only on that context's owner thread. It owns
the passes and what they share (`PassContext`: program cache, full-screen triangle) and releases
them in `release`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.frame_output import (
    DisplayRequest,
    InputNote,
    RenderedFrame,
    RenderStats,
)
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.motion import plan_motion
from sphrender.server.engine.gpu.cl_context import CLDeviceInfo
from sphrender.server.engine.gpu.draw import FullscreenTriangle, Target
from sphrender.server.engine.gpu.gl_clock import StageTimer
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.input_notes import InputNotes
from sphrender.server.engine.passes.accumulate import AccumulatePass
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.normals import NormalsPass
from sphrender.server.engine.passes.output_stage import OutputStage
from sphrender.server.engine.passes.prepare_stage import PreparedFrame, PrepareMode, PrepareStage
from sphrender.server.engine.passes.shade import ShadePass
from sphrender.server.engine.passes.shadow import ShadowMaps, ShadowPass, shadowed
from sphrender.server.engine.passes.smooth import SmoothPass
from sphrender.server.engine.passes.solid_surface import (
    SolidParticles,
    SolidSurfacePass,
    shadow_casters,
)
from sphrender.server.engine.passes.splat import SplatOutput, SplatPass
from sphrender.server.engine.passes.temperature import TemperaturePass
from sphrender.server.engine.sph.engine import SphEngine
from sphrender.server.engine.sph.frame import SphOutcome, SphStage
from sphrender.server.scene import Scene


class SurfaceRenderer:
    """Renders particle frames with one GL context; see the module docstring for the passes."""

    def __init__(
        self,
        gl: GLContext,
        *,
        stage_timings: bool = True,
        cl_device: str | None = None,
        environment_dirs: Sequence[str | Path] = (),
        prepare: PrepareMode = "auto",
    ) -> None:
        """`stage_timings`: wait for the GPU after each stage so `RenderStats` holds true stage
        times; `cl_device`: OpenCL device for the SPH stage (None = probe);
        `environment_dirs`: the only directories `[environment] file` may name files in;
        `prepare`: where particles are culled and transformed (passes/prepare_stage.py)."""
        self._gl = gl
        self._stage_timings = stage_timings
        self._context = PassContext(gl, ProgramCache(gl), FullscreenTriangle(gl))
        self._sph = SphStage(cl_device)  # OpenCL is created on the first frame that needs it
        self._input_notes = InputNotes()
        self._splat = SplatPass(self._context)
        self._prepare = PrepareStage(self._context, self._splat, prepare)
        self._smooth = SmoothPass(self._context)
        self._normals = NormalsPass(self._context)
        self._temperature = TemperaturePass(self._context)
        self._peak_temperature = TemperaturePass(self._context, channel=1)
        self._shade = ShadePass(self._context, environment_dirs)
        self._shadow = ShadowPass(self._context)
        self._solids = SolidSurfacePass(self._context)  # frames with solid particles only
        self._output = OutputStage(self._context)
        self._accumulate = AccumulatePass(self._context)

    @property
    def gl(self) -> GLContext:
        return self._gl

    @property
    def programs(self) -> ProgramCache:
        """The compiled-program cache the passes share."""
        return self._context.programs

    @property
    def splat_pass(self) -> SplatPass:
        """The splat pass and its targets (tests read the splatted temperature from them)."""
        return self._splat

    @property
    def image_passes(self) -> tuple[SplatPass, SmoothPass, NormalsPass, TemperaturePass, ShadePass]:
        """The passes that work on images, in frame order (tests run one on given images)."""
        return self._splat, self._smooth, self._normals, self._temperature, self._shade

    @property
    def shade_pass(self) -> ShadePass:
        """The shading pass and its caches (environments, IBL, BRDF tables)."""
        return self._shade

    def max_image_side(self) -> int:
        return self._gl.limits.max_image_side

    def sph_engine(self) -> SphEngine:
        """The SPH engine and its CL context, created on first use (owner thread)."""
        self._gl.check_owner()
        return self._sph.engine()

    def opencl_device(self) -> CLDeviceInfo:
        """The SPH stages' OpenCL device, its context made now if need be (owner thread)."""
        self._gl.check_owner()
        return self._sph.device()

    def check_image_size(self, scene: Scene) -> None:
        limit = self.max_image_side()
        for key in ("width", "height"):
            value = getattr(scene.image, key)
            if value > limit:
                raise InputError(f"image.{key}", f"must be at most {limit} (GL limit), got {value}")

    def _stage(self, stats: RenderStats, name: str) -> StageTimer:
        """``with self._stage(stats, name):`` times one stage into `stats.stage_ms` (waiting for
        the GPU at its end when true stage times were asked for)."""
        finish = self._gl.ctx.finish if self._stage_timings else None
        return StageTimer(self._gl.clock, finish, stats.stage_ms, name)

    # -- frame -----------------------------------------------------------------------------

    def render(
        self,
        frame: ParticleFrame,
        scene: Scene,
        *,
        depth: bool = False,
        normals: bool = False,
        display: DisplayRequest | None = None,
        linear: bool = False,
    ) -> tuple[RenderedFrame, RenderStats]:
        """Render one frame; `depth` / `normals` ask for those AOVs to be read back, `display`
        for the 8-bit display codes an encoder would compute (passes/display.py); `linear`: the
        colour read back feeds a scene-linear output (EXR, raw float), glared only when
        `[glare] exr` says so."""
        self._gl.check_owner()
        start, in_gl = time.perf_counter(), self._gl.clock.seconds
        self.check_image_size(scene)
        camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
        stats = RenderStats(particles_in=frame.count)
        stats.notes += [InputNote(note.field, note.message) for note in scene.notes]
        frame, solid = self._solids.split(frame, scene)
        motion = plan_motion(frame, camera, scene.camera.shutter)
        if motion is None:
            color, normal_depth, prepared, count = self._render_color(
                frame, solid, scene, camera, stats
            )
            box = prepared.box
        else:  # sub-frames averaged; the last, nearest the shutter's middle, gives Z, N, notes
            notes = len(stats.notes)
            for index, offset in enumerate(motion.times):
                del stats.notes[notes:]
                stats.particles_splatted = 0
                sub = motion.subframe(frame, offset)
                color, normal_depth, prepared, count = self._render_color(
                    sub, solid, scene, camera, stats
                )
                with self._stage(stats, "motion"):
                    average = self._accumulate.add(color, index, len(motion.times))
            assert average is not None
            color, box = average, None
        glared = color
        if scene.glare.enabled:  # the halo reaches past the surface: no box
            with self._stage(stats, "glare"):
                glared, box = self._output.glare(color, camera, scene), None
        with self._stage(stats, "readback"):
            rendered = self._output.read(  # a GPU (device prepare) copies whole images faster
                color, glared, normal_depth, scene, box, whole=self._prepare.mode == "device",
                depth=depth, normals=normals, display=display, linear=linear,
            )  # fmt: skip
        # After the read-back, so a count the device kept waits for nothing.
        stats.particles_splatted += self._splat.splatted(count, prepared.visible)
        wall_ms = (time.perf_counter() - start) * 1e3
        device_ms = (self._gl.clock.seconds - in_gl) * 1e3
        stats.host_ms = max(wall_ms - device_ms - stats.stage_ms.get("sph", 0.0), 0.0)
        return rendered, stats

    def _render_color(
        self,
        frame: ParticleFrame,
        solid: SolidParticles | None,
        scene: Scene,
        camera: Camera,
        stats: RenderStats,
    ) -> tuple[Target, Target, PreparedFrame, int]:
        """SPH to shade of one (sub-)frame, with the frame's solid part (it does not move) and the
        finish's detail on both: colour, normal + depth (the N AOV), prepared frame, splat count."""
        sph = self._run_sph(frame, scene, stats)
        with self._stage(stats, "prepare"):
            prepared = self._prepare.run(sph, camera, scene)
            stats.particles_drawn = prepared.visible
            stats.far = prepared.far
        stats.notes += self._input_notes.of(frame, scene, prepared.visible)
        surface, bulk_splatted = self._draw_surface(prepared, camera, scene, stats)
        with self._stage(stats, "normals"):
            normal_depth = self._surface_normals(surface, prepared, camera, scene)
        shadows = None
        if shadowed(scene):
            with self._stage(stats, "shadow"):
                casters = shadow_casters(sph.frame, solid, scene.particles.radius)
                shadows = self._shadow.run(casters, scene, camera, prepared.reference_radius)
        if solid is not None:  # composed by depth; the shading and read-back cover it too
            with self._stage(stats, "solids"):
                surface, normal_depth, prepared = self._solids.add(
                    solid, surface, normal_depth, prepared, camera
                )
        with self._stage(stats, "shade"):  # the finish's detail first: the N AOV has it too
            normal_depth = self._shade.detail.run(scene.finish, camera, normal_depth, prepared.box)
            color = self._shade_surface(surface, normal_depth, camera, scene, prepared, shadows)
        return color, normal_depth, prepared, bulk_splatted

    # -- the stages of `render` ------------------------------------------------------------

    def _run_sph(self, frame: ParticleFrame, scene: Scene, stats: RenderStats) -> SphOutcome:
        """The SPH stage's outcome: the frame itself when the scene needs no SPH quantity."""
        if not self._sph.wanted(scene, frame):
            return SphOutcome(frame)
        self._sph.warm(frame, scene)  # outside the stage: first use builds the CL program
        with self._stage(stats, "sph"):
            outcome = self._sph.run(frame, scene)
        stats.notes.extend(outcome.notes)
        return outcome

    def _draw_surface(
        self, prepared: PreparedFrame, camera: Camera, scene: Scene, stats: RenderStats
    ) -> tuple[SplatOutput, int]:
        """Splat the bulk, smooth it, draw the exact droplets over it: the surface's eye depth
        (+ temperature and coverage) and the bulk's splat count (-1: counted on the device,
        read after the frame)."""
        with self._stage(stats, "splat"):
            splat = self._splat.run(
                camera,
                prepared.bulk,
                bounds=prepared.bounds,
                box=prepared.box,
                antialias=scene.quality.antialias,
                device_cull=prepared.device_cull,
            )
        bulk_splatted = splat.splatted
        if scene.quality.filter != "none" and prepared.visible:
            with self._stage(stats, "smooth"):
                smoothed = self._smooth.run(
                    splat.depth,
                    px_per_unit=camera.pixels_per_unit_at_unit_depth,
                    particle_radius=prepared.reference_radius,
                    quality=scene.quality,
                    box=prepared.box,
                    temperature=splat.temperature,  # filled where gaps close
                )
            splat = replace(splat, depth=smoothed)
        if prepared.droplets is not None:
            with self._stage(stats, "droplets"):
                drops = self._prepare.droplets(prepared)
                if drops is not None:
                    splat = self._splat.run_droplets(
                        camera, drops, splat.depth, splat.temperature, splat.coverage
                    )
                    stats.particles_splatted += max(splat.splatted, 0)  # host prepare
        return splat, bulk_splatted

    def _surface_normals(
        self, surface: SplatOutput, prepared: PreparedFrame, camera: Camera, scene: Scene
    ) -> Target:
        """World normals + eye depth of the surface (field normals near rims)."""
        quality = scene.quality
        field = self._prepare.field_particles(prepared) if quality.field_normals else None
        support = quality.field_normals_support * prepared.reference_radius
        return self._normals.run(
            surface.depth,
            camera,
            prepared.box,
            prepared.reference_radius,
            quality,
            field,
            support,
            bulk=surface.bulk_depth,
        )

    def _shade_surface(
        self,
        surface: SplatOutput,
        normal_depth: Target,
        camera: Camera,
        scene: Scene,
        prepared: PreparedFrame,
        maps: ShadowMaps | None = None,
    ) -> Target:
        """The shaded colour target (the temperature blurred along the surface first; `maps`:
        the lights' shadow maps)."""
        temperature, peak = surface.temperature, None
        if temperature is not None and prepared.visible:
            blur = (surface.depth, camera.pixels_per_unit_at_unit_depth, prepared.reference_radius)
            if temperature.components == 2:
                peak = self._peak_temperature.run(temperature, *blur)
            temperature = self._temperature.run(temperature, *blur)
        return self._shade.run(
            scene,
            camera,
            normal_depth.texture,
            temperature,
            prepared.box,
            surface.coverage,
            peak,
            maps,
        )

    def release(self) -> None:
        """Release every GPU object this renderer owns (on the owner thread)."""
        self._gl.check_owner()
        passes = (self._splat, self._smooth, self._normals, self._temperature, self._shade)
        others = (self._peak_temperature, self._shadow, self._solids)
        for gpu_pass in (*passes, *others, self._output, self._accumulate):
            gpu_pass.release()
        self._context.fullscreen.release()
        self._context.programs.release()
        self._sph.release()
