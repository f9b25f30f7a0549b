"""The solid pass: a solid workpiece's flat faces and sharp edges, composed with the fluid.

The solid particles' surfels (`geometry/solid_surfels.py`: one flat disc per face a surface
particle lies on, cut by its other faces' planes, and spheres under them) are built once per
shape and kept while the solid does not move; a frame moves them into view space (float64 eye
subtraction on the host), draws them depth-tested into a normal + eye depth target (+ kelvin),
and composes that with the fluid's normal target by depth: per pixel the nearer surface's normal,
eye depth, temperature and coverage, which the temperature blur and the shading then read as
they read the fluid's. Owns: its programs' uses, the instance buffers, the solid and composed
targets, the surfel cache. Which particles are solid: the frame's `solid` flags, or its
temperatures against the material's solidus (`[solids] source`); a frame with none is passed
on as it came (nothing copied).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.occlusion import sphere_bounds
from sphrender.server.engine.geometry.screen_box import ScreenBox, screen_box
from sphrender.server.engine.geometry.solid_surfels import (
    MAX_CLIP_PLANES,
    SolidSurfelCache,
    SolidSurfels,
)
from sphrender.server.engine.gpu.draw import Target, float_texture
from sphrender.server.engine.gpu.uniforms import set_if_used, write_matrix
from sphrender.server.engine.lighting.materials import resolve_material
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.prepare_stage import PreparedFrame
from sphrender.server.engine.passes.splat import SplatOutput
from sphrender.server.scene import Scene

F64 = npt.NDArray[np.float64]
_CORNERS = np.array([[-1, -1], [1, -1], [-1, 1], [1, 1]], dtype=np.float32)
_DISC_FLOATS = 3 + 3 + 3 + 4 * MAX_CLIP_PLANES + 2
_SPHERE_FLOATS = 4 + 2


@dataclass(frozen=True)
class SolidParticles:
    """The solid part of a frame: world positions (float64), radius, kelvin per particle and
    the peak kelvin the heat tint reads (None: the frame has none, or the material no tint)."""

    positions: F64
    radius: float
    temperatures: npt.NDArray[np.float32] | None
    peaks: npt.NDArray[np.float32] | None = None


@dataclass(frozen=True)
class ComposedSurface:
    """Fluid and solid composed by depth (the composed pass's textures, valid until its next
    run): normal + eye depth, eye depth alone, kelvin (None without), coverage."""

    normal_depth: Target  # attachment 0 of the composed framebuffer (read back as the fluid's)
    depth: moderngl.Texture
    temperature: moderngl.Texture | None
    coverage: moderngl.Texture


class _Targets:
    """The solid's targets and the composed ones for one image size."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.size = size
        self.solid = float_texture(ctx, size, 4)
        self.solid_temperature = float_texture(ctx, size, 2)  # kelvin, peak kelvin
        self.depth_buffer = ctx.depth_renderbuffer(size)
        self.solid_fbo = ctx.framebuffer([self.solid, self.solid_temperature], self.depth_buffer)
        self.composed = [float_texture(ctx, size, c) for c in (4, 1, 1, 1)]
        self.composed_fbo = ctx.framebuffer(self.composed)
        # The same with kelvin and peak kelvin, for frames whose heat tint reads peaks.
        self.composed_peak = float_texture(ctx, size, 2)
        normal_depth, depth, _kelvin, coverage = self.composed
        self.composed_peak_fbo = ctx.framebuffer(
            [normal_depth, depth, self.composed_peak, coverage]
        )

    def release(self) -> None:
        for obj in (self.solid_fbo, self.composed_fbo, self.composed_peak_fbo, self.depth_buffer):
            obj.release()
        self.solid.release()
        self.composed_peak.release()
        self.solid_temperature.release()
        for texture in self.composed:
            texture.release()


class SolidSurfacePass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self.cache = SolidSurfelCache()
        self._targets: _Targets | None = None
        ctx = context.gl.ctx
        self._corners = ctx.buffer(_CORNERS.tobytes())
        self._discs: moderngl.Buffer | None = None
        self._spheres: moderngl.Buffer | None = None
        self._vaos: dict[tuple[str, bool], moderngl.VertexArray] = {}

    def targets(self, size: tuple[int, int]) -> _Targets:
        if self._targets is None or self._targets.size != size:
            if self._targets is not None:
                self._targets.release()
            self._targets = _Targets(self._context.gl.ctx, size)
        return self._targets

    def _program(self, name: str, temperature: bool) -> moderngl.Program:
        return self._context.programs.get(
            f"solid/{name}.vert.glsl",
            f"solid/{name}.frag.glsl",
            {"HAS_TEMPERATURE": temperature},
        )

    def _upload(self, name: str, data: npt.NDArray[np.float32]) -> moderngl.Buffer:
        """The instance buffer `name`, grown when the data outgrows it (its VAOs rebuilt)."""
        current: moderngl.Buffer | None = getattr(self, f"_{name}")
        raw = data.tobytes()
        if current is None or current.size < max(len(raw), 4):
            if current is not None:
                current.release()
            for key in [k for k in self._vaos if k[0] == name]:
                self._vaos.pop(key).release()
            current = self._context.gl.ctx.buffer(reserve=max(len(raw), 4))
            setattr(self, f"_{name}", current)
        if raw:
            current.write(raw)
        return current

    def _vao(self, name: str, temperature: bool) -> moderngl.VertexArray:
        key = (name, temperature)
        vao = self._vaos.get(key)
        if vao is None:
            program = self._program("surfel" if name == "discs" else "core_sphere", temperature)
            layout: tuple[str, ...]
            if name == "discs":
                layout = (
                    "3f 3f 3f 4f 4f 4f 2f/i",
                    "in_center",
                    "in_normal",
                    "in_world_normal",
                    "in_clip0",
                    "in_clip1",
                    "in_clip2",
                    "in_temperature",
                )
            else:
                layout = ("4f 2f/i", "in_sphere", "in_temperature")
            instance = self._discs if name == "discs" else self._spheres
            assert instance is not None
            content = [(self._corners, "2f", "in_corner"), (instance, *layout)]
            vao = self._context.gl.ctx.vertex_array(program, content, skip_errors=True)
            self._vaos[key] = vao
        return vao

    def run(self, solid: SolidParticles, camera: Camera) -> ScreenBox | None:
        """Draw the solid into its normal + eye depth target (w = 0 where there is none);
        returns the screen box that holds it (None: the whole image)."""
        surfels = self.cache.get(solid.positions, solid.radius)
        targets = self.targets((camera.width, camera.height))
        temperature = solid.temperatures is not None
        discs, spheres, far = _view_instances(surfels, solid, camera)
        box = _solid_box(discs, spheres, surfels.disc_radius, camera)
        self._upload("discs", discs)
        self._upload("spheres", spheres)
        ctx = self._context.gl.ctx
        targets.solid_fbo.use()
        targets.solid_fbo.viewport = (0, 0, camera.width, camera.height)
        targets.solid_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        projection = camera.projection_matrix(far)
        ctx.enable(moderngl.DEPTH_TEST)
        try:
            for name, count in (("discs", len(discs)), ("spheres", len(spheres))):
                if count == 0:
                    continue
                program = self._program("surfel" if name == "discs" else "core_sphere", temperature)
                write_matrix(program, "u_projection", projection.astype(np.float64), (camera, far))
                set_if_used(program, "u_near", float(camera.near))
                set_if_used(program, "u_far", float(far))
                set_if_used(program, "u_disc_radius", float(surfels.disc_radius))
                if name == "spheres":
                    write_matrix(program, "u_view_to_world", lambda: camera.rotation.T, camera)
                self._vao(name, temperature).render(
                    moderngl.TRIANGLE_STRIP, vertices=4, instances=count
                )
        finally:
            ctx.disable(moderngl.DEPTH_TEST)
        return box

    def split(
        self, frame: ParticleFrame, scene: Scene
    ) -> tuple[ParticleFrame, SolidParticles | None]:
        """The fluid part of `frame` and its solid part (None: nothing is solid, and `frame`
        comes back as it came)."""
        return split_solid(frame, scene)

    def add(
        self,
        solid: SolidParticles,
        surface: SplatOutput,
        normal_depth: Target,
        prepared: PreparedFrame,
        camera: Camera,
    ) -> tuple[SplatOutput, Target, PreparedFrame]:
        """The solid drawn and composed with the fluid by depth: the surface and the normal
        target the temperature blur, the shading and the read-back use from here on, and the
        prepared frame with its screen box grown over the solid."""
        box = self.run(solid, camera)
        fluid = surface.temperature
        composed = self.compose(
            normal_depth.texture,
            fluid,
            surface.coverage,
            has_temperature=solid.temperatures is not None,
            has_peak=solid.peaks is not None or (fluid is not None and fluid.components == 2),
        )
        merged = replace(
            surface,
            depth=composed.depth,
            temperature=composed.temperature,
            coverage=composed.coverage if surface.coverage is not None else None,
        )
        if prepared.visible:
            box = _union(prepared.box, box)
        return merged, composed.normal_depth, replace(prepared, box=box, visible=1)

    def compose(
        self,
        fluid_normal_depth: moderngl.Texture,
        fluid_temperature: moderngl.Texture | None,
        fluid_coverage: moderngl.Texture | None,
        has_temperature: bool,
        has_peak: bool = False,
    ) -> ComposedSurface:
        """The nearer of the fluid and the solid (drawn by `run` this frame) per pixel; with
        `has_peak` the kelvin carries the peak kelvin beside it, as the fluid's splat does."""
        assert self._targets is not None
        targets = self._targets
        program = self._context.programs.get(
            FULLSCREEN_VERT,
            "solid/compose.frag.glsl",
            {
                "HAS_TEMPERATURE": has_temperature,
                "HAS_PEAK": has_temperature and has_peak,
                "HAS_COVERAGE": fluid_coverage is not None,
            },
        )
        bindings = [
            ("u_fluid_normal_depth", fluid_normal_depth),
            ("u_solid_normal_depth", targets.solid),
        ]
        if has_temperature:
            bindings += [
                ("u_fluid_temperature", fluid_temperature or targets.solid_temperature),
                ("u_solid_temperature", targets.solid_temperature),
            ]
        if fluid_coverage is not None:
            bindings.append(("u_fluid_coverage", fluid_coverage))
        for unit, (name, texture) in enumerate(bindings):
            texture.use(unit)
            set_if_used(program, name, unit)
        peak = has_temperature and has_peak
        fbo = targets.composed_peak_fbo if peak else targets.composed_fbo
        fbo.use()
        fbo.viewport = (0, 0, *targets.size)
        self._context.fullscreen.draw(program)
        normal_depth, depth, temperature, coverage = targets.composed
        if peak:
            temperature = targets.composed_peak
        return ComposedSurface(
            Target(normal_depth, fbo),
            depth,
            temperature if has_temperature else None,
            coverage,
        )

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        for buffer in (self._discs, self._spheres, self._corners):
            if buffer is not None:
                buffer.release()
        self._discs = self._spheres = None
        if self._targets is not None:
            self._targets.release()
            self._targets = None


def _solid_box(
    discs: npt.NDArray[np.float32],
    spheres: npt.NDArray[np.float32],
    disc_radius: float,
    camera: Camera,
) -> ScreenBox | None:
    """The pixels the discs (each inside a sphere of the disc radius) and spheres can touch."""
    bounding = np.concatenate(
        [
            np.concatenate([discs[:, :3], np.full((len(discs), 1), disc_radius, np.float32)], 1),
            spheres[:, :4],
        ]
    )
    if len(bounding) == 0:
        return (0, 0, 1, 1)
    return screen_box(sphere_bounds(bounding, camera), camera)


def _union(a: ScreenBox | None, b: ScreenBox | None) -> ScreenBox | None:
    if a is None or b is None:
        return None
    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
    x1, y1 = max(a[0] + a[2], b[0] + b[2]), max(a[1] + a[3], b[1] + b[3])
    return (x0, y0, x1 - x0, y1 - y0)


def _view_instances(
    surfels: SolidSurfels, solid: SolidParticles, camera: Camera
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], float]:
    """The discs' and spheres' instance data in view space, and a far plane behind them all."""
    rotation = camera.rotation
    kelvin = solid.temperatures
    centers = camera.to_view(surfels.disc_centers)
    discs = np.zeros((len(centers), _DISC_FLOATS), np.float32)
    discs[:, 0:3] = centers
    discs[:, 3:6] = surfels.disc_normals @ rotation.T
    discs[:, 6:9] = surfels.disc_normals
    planes = surfels.clip_normals.reshape(-1, 3)
    view_normals = planes @ rotation.T
    offsets = surfels.clip_offsets.reshape(-1) - planes @ camera.eye
    clip = np.concatenate([view_normals, offsets[:, None]], axis=1)
    discs[:, 9:21] = clip.reshape(len(centers), 4 * MAX_CLIP_PLANES)
    peaks = solid.peaks if solid.peaks is not None else kelvin
    if kelvin is not None and peaks is not None:
        discs[:, 21] = kelvin[surfels.disc_source]
        discs[:, 22] = peaks[surfels.disc_source]
    sphere_view = camera.to_view(surfels.sphere_centers)
    # A sphere the near plane cuts has no impostor quad; the discs (clipped by GL) stay.
    front = -sphere_view[:, 2] - surfels.sphere_radii > camera.near
    spheres = np.zeros((int(front.sum()), _SPHERE_FLOATS), np.float32)
    spheres[:, 0:3] = sphere_view[front]
    spheres[:, 3] = surfels.sphere_radii[front]
    if kelvin is not None and peaks is not None:
        spheres[:, 4] = kelvin[surfels.sphere_source[front]]
        spheres[:, 5] = peaks[surfels.sphere_source[front]]
    reach = max(surfels.disc_radius, float(surfels.sphere_radii.max(initial=0.0)))
    depths = np.concatenate([-centers[:, 2], -sphere_view[:, 2]])
    far = float(depths.max(initial=camera.near)) + 2.0 * reach
    return discs, spheres, max(far, camera.near * 2.0)


def solid_mask(frame: ParticleFrame, scene: Scene) -> npt.NDArray[np.bool_] | None:
    """True where a particle is solid, None when the scene and frame say nothing is."""
    source = scene.solids.source
    if source == "flag":
        return frame.solid
    if source == "temperature" and frame.temperatures is not None:
        solidus = resolve_material(scene.material).solidus_k
        return frame.temperatures < np.float32(solidus)
    return None


def shadow_casters(
    fluid: ParticleFrame, solid: SolidParticles | None, radius: float
) -> ParticleFrame:
    """Every particle that casts a shadow: the fluid (`radius` where it has no radii) and the
    solid (its own radius)."""
    if solid is None:
        return fluid
    fluid_radii = fluid.radii if fluid.radii is not None else np.full(fluid.count, radius)
    solid_radii = np.full(len(solid.positions), solid.radius)
    return ParticleFrame(
        positions=np.concatenate([np.asarray(fluid.positions, np.float64), solid.positions]),
        radii=np.concatenate([fluid_radii, solid_radii]).astype(np.float32),
    )


def split_solid(frame: ParticleFrame, scene: Scene) -> tuple[ParticleFrame, SolidParticles | None]:
    """The fluid part of `frame` and its solid part (None: no particle is solid)."""
    mask = solid_mask(frame, scene)
    if mask is None or not mask.any():
        return frame, None
    keep = ~mask
    radius = scene.particles.radius
    if frame.radii is not None:
        radius = float(np.median(frame.radii[mask]))

    def part(array: np.ndarray | None) -> np.ndarray | None:
        return None if array is None else np.ascontiguousarray(array[keep])

    # Every per-particle array of the frame, whichever it carries, keeps the fluid's rows.
    arrays: dict[str, Any] = {
        f.name: part(getattr(frame, f.name)) for f in fields(frame) if f.name != "solid"
    }
    fluid = replace(frame, **arrays, solid=None)
    temperatures = None if frame.temperatures is None else frame.temperatures[mask]
    peaks = None
    tinted = scene.material.heat_tint  # the only reader of peaks
    if tinted and temperatures is not None and frame.peak_temperatures is not None:
        peaks = np.maximum(frame.peak_temperatures[mask], temperatures)
    solid = SolidParticles(np.ascontiguousarray(frame.positions[mask]), radius, temperatures, peaks)
    return fluid, solid
