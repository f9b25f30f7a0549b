"""The screen-space surface renderer: particles in, colour + depth + normals out.

One `SurfaceRenderer` belongs to one `GLContext` and is used only on that context's owner thread.
Per-scene and per-size resources (programs, render targets, the quad buffer) are built once and
reused; per frame it only uploads the visible particles and runs the passes the scene asks for:

    sph (OpenCL, optional)  only when the scene asks for adaptive radii (eq 29) or
                            surface-only splatting: per-particle radii and/or fewer particles
                            (see `sph.py`); the CL context is created on first need
    prepare (CPU, float64)  positions relative to the eye, rotated to view space, culled,
                            then converted to float32
    splat                   sphere impostors (two triangles each) -> eye depth (R32F,
                            0 = background), plus the front particle's temperature when the
                            frame has them; the front layer first, then only the particles its
                            depth does not hide (`occlusion.py`, exact)
    smooth                  gaussian | bilateral | narrow_range, 1-D x2 (on a packed image,
                            four pixels per texel) or 2-D, iterated
    normals                 one-sided differences of the smoothed depth -> world normals
    shade                   physically based metal: direct lights, SH + specular IBL, hot-metal
                            emission (`shading.ShadePass`)
    readback                colour always; depth and normals only when asked for
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.client.errors import InputError
from sphrender.client.frame import ParticleFrame
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry import occlusion
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.cl_context import CLContext
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.passes.shade import ShadePass
from sphrender.server.engine.sph.engine import (
    SphEngine,
    apply_to_frame,
    frame_particle_radius,
    needs_sph,
)
from sphrender.server.scene import QualityConfig, Scene

_FILTER_DEFINES = {"gaussian": 0, "bilateral": 1, "narrow_range": 2}
_KERNEL_SIZE_DEFINES = {"projected_radius": 0, "eq25": 1}


@dataclass
class RenderStats:
    """What one frame cost and did: milliseconds per stage (only stages that ran), counts."""

    stage_ms: dict[str, float] = field(default_factory=dict)
    particles_in: int = 0
    particles_drawn: int = 0  # visible: in front of the camera and inside the image
    particles_splatted: int = 0  # rasterised: the visible ones less those found hidden
    far: float = 0.0

    @property
    def total_ms(self) -> float:
        return sum(self.stage_ms.values())


@dataclass(frozen=True)
class PreparedParticles:
    """Visible particles in view space, float32, ready to upload: (N, 4) centre xyz + radius."""

    center_radius: npt.NDArray[np.float32]
    far: float
    reference_radius: float
    temperatures: npt.NDArray[np.float32] | None = None  # (N,) kelvin of the kept particles


def prepare_particles(
    frame: ParticleFrame, camera: Camera, scene: Scene, *, reference_radius: float | None = None
) -> PreparedParticles:
    """Float64 eye-relative view-space positions, culled, then float32 (see module docstring).

    `reference_radius` (the radius the smoothing kernel follows) defaults to the frame's median
    radius; the SPH stage passes the radius from before eq 29 so adaptive radii do not resize
    the filter."""
    radius = scene.particles.radius
    radii: npt.NDArray[np.floating] = (
        frame.radii if frame.radii is not None else np.full(frame.count, radius, np.float32)
    )
    view = camera.to_view(frame.positions)
    far_config = scene.camera.far
    keep = camera.visible_mask(view, radii, far_config)
    view = view[keep]
    kept_radii = np.asarray(radii, dtype=np.float64)[keep]
    if far_config is not None:
        far = far_config
    elif view.shape[0]:
        far = float(np.max(-view[:, 2] + kept_radii)) * 1.001
    else:
        far = camera.near * 2.0
    far = max(far, camera.near * 1.001)
    center_radius = np.empty((view.shape[0], 4), dtype=np.float32)
    center_radius[:, :3] = view
    center_radius[:, 3] = kept_radii
    if reference_radius is None:
        reference_radius = (
            float(np.median(frame.radii)) if frame.radii is not None and frame.count else radius
        )
    temperatures = (
        np.ascontiguousarray(frame.temperatures[keep], dtype=np.float32)
        if frame.temperatures is not None
        else None
    )
    return PreparedParticles(center_radius, far, reference_radius, temperatures)


ScreenBox = tuple[int, int, int, int]  # x, y (GL window coordinates, bottom-left), width, height


def screen_box(
    bounds: occlusion.SphereBounds, camera: Camera, margin_px: int = 2
) -> ScreenBox | None:
    """A pixel rectangle holding every splatted fragment (the union of the spheres' silhouette
    rectangles, see `occlusion.sphere_bounds`, plus `margin_px`), or None (whole image) when a
    sphere reaches the eye plane.

    The passes after the splat touch only pixels with a surface (or their direct neighbours),
    so running them inside this box, on targets cleared outside it, gives the same image while
    skipping the background: with a ball filling a quarter of a 1280x720 image that is 3/4 of
    the fragments of every full-screen pass."""
    if bounds.valid.size == 0 or not bounds.valid.all():
        return None
    x0 = int(np.clip(bounds.x0.min() - margin_px, 0, camera.width))
    x1 = int(np.clip(bounds.x1.max() + 1 + margin_px, 0, camera.width))
    y0 = int(np.clip(bounds.y0.min() - margin_px, 0, camera.height))
    y1 = int(np.clip(bounds.y1.max() + 1 + margin_px, 0, camera.height))
    if x1 <= x0 or y1 <= y0:
        return (0, 0, 1, 1)  # nothing on screen: a token box keeps the passes trivial
    return (x0, y0, x1 - x0, y1 - y0)


def _set_scissor(fbo: moderngl.Framebuffer, box: ScreenBox | None) -> None:
    """Restrict passes into `fbo` to `box`; None lifts the restriction (moderngl accepts None
    at run time, its type stub only lists the tuple)."""
    fbo.scissor = box  # type: ignore[assignment]


def _scissored(fbo: moderngl.Framebuffer, box: ScreenBox | None) -> None:
    """Clear the whole target, then restrict the next passes into it to `box` (None: all)."""
    _set_scissor(fbo, None)
    fbo.clear(0.0, 0.0, 0.0, 0.0)
    _set_scissor(fbo, box)


def _packed_box(box: ScreenBox) -> ScreenBox:
    """`box` in the texels of a packed image (four pixels per texel along x)."""
    x, y, width, height = box
    first = x // 4
    return (first, y, (x + width + 3) // 4 - first, height)


def _read_region(
    fbo: moderngl.Framebuffer, size: tuple[int, int], box: ScreenBox | None
) -> npt.NDArray[np.float32]:
    """The RGBA float target of `fbo` as (H, W, 4), rows top first, reading only `box` (the
    rest is known to be zero) or everything (None)."""
    width, height = size
    if box is None:
        data = np.frombuffer(fbo.read(components=4, dtype="f4"), dtype=np.float32)
        return np.ascontiguousarray(data.reshape(height, width, 4)[::-1])
    x, y, w, h = box
    part = np.frombuffer(fbo.read(viewport=box, components=4, dtype="f4"), dtype=np.float32)
    out = np.zeros((height, width, 4), dtype=np.float32)
    out[height - y - h : height - y, x : x + w] = part.reshape(h, w, 4)[::-1]
    return out


def _write_matrix(program: moderngl.Program, name: str, matrix: npt.NDArray[np.floating]) -> None:
    """Upload a row-major numpy matrix to a GLSL matN uniform (GLSL is column-major)."""
    uniform = program[name]
    assert isinstance(uniform, moderngl.Uniform), name
    uniform.write(np.ascontiguousarray(matrix.T, dtype=np.float32).tobytes())


class _Targets:
    """Render targets for one image size; rebuilt only when the size changes."""

    def __init__(self, ctx: moderngl.Context, width: int, height: int) -> None:
        size = (width, height)
        self.size = size

        def float_texture(components: int) -> moderngl.Texture:
            texture = ctx.texture(size, components, dtype="f4")
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            texture.repeat_x = texture.repeat_y = False
            return texture

        self.splat_depth = float_texture(1)
        self.depth_buffer = ctx.depth_renderbuffer(size)
        self.splat = ctx.framebuffer([self.splat_depth], self.depth_buffer)
        self.ping = [float_texture(1), float_texture(1)]
        self.ping_fbos = [ctx.framebuffer([t]) for t in self.ping]
        # Four pixels per texel along x, for the separable filters (see `_smooth`).
        packed_size = ((width + 3) // 4, height)
        self.packed = [ctx.texture(packed_size, 4, dtype="f4") for _ in range(2)]
        for texture in self.packed:
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            texture.repeat_x = texture.repeat_y = False
        self.packed_fbos = [ctx.framebuffer([t]) for t in self.packed]
        self.normal_depth = float_texture(4)
        self.normal_fbo = ctx.framebuffer([self.normal_depth])
        self.color = float_texture(4)
        self.color_fbo = ctx.framebuffer([self.color])
        # Built on the first frame that carries temperatures (most frames never need them).
        self._ctx = ctx
        self._float_texture = float_texture
        self.temperature: moderngl.Texture | None = None
        self.splat_with_temperature: moderngl.Framebuffer | None = None

    def temperature_targets(self) -> tuple[moderngl.Texture, moderngl.Framebuffer]:
        if self.temperature is None or self.splat_with_temperature is None:
            self.temperature = self._float_texture(1)
            self.splat_with_temperature = self._ctx.framebuffer(
                [self.splat_depth, self.temperature], self.depth_buffer
            )
        return self.temperature, self.splat_with_temperature

    def release(self) -> None:
        fbos = (self.splat, *self.ping_fbos, *self.packed_fbos, self.normal_fbo, self.color_fbo)
        for fbo in (*fbos, self.splat_with_temperature):
            if fbo is not None:
                fbo.release()
        for texture in (self.splat_depth, *self.ping, *self.packed, self.normal_depth, self.color):
            texture.release()
        if self.temperature is not None:
            self.temperature.release()
        self.depth_buffer.release()


class SurfaceRenderer:
    """Renders particle frames with one GL context; see the module docstring for the passes."""

    def __init__(
        self,
        gl: GLContext,
        *,
        stage_timings: bool = True,
        cl_device: str | None = None,
        environment_dirs: Sequence[str | Path] = (),
    ) -> None:
        """`cl_device`: OpenCL device for the SPH stage (None = probe); `environment_dirs`: the
        only directories `[environment] file` may name files in."""
        self._gl = gl
        # OpenCL is created on the first frame that needs SPH, on this (the owner) thread.
        self._cl_device = cl_device
        self._cl: CLContext | None = None
        self._sph: SphEngine | None = None
        ctx = gl.ctx
        self._programs = ProgramCache(gl)
        self._stage_timings = stage_timings
        # Sphere quads are drawn as plain indexed triangles, 4 vertices per particle, not as
        # instances: llvmpipe's draw module runs its vertex pipeline once per instance, which
        # made the splat of 90k particles cost ~70 ms of pure per-instance overhead. The corner
        # and index buffers depend only on the particle count and grow geometrically.
        self._quad_capacity = 0
        self._corner_buffer = ctx.buffer(reserve=4)
        self._index_buffer = ctx.buffer(reserve=4)
        self._instance_buffer = ctx.buffer(reserve=16 * 1024)
        self._temperature_buffer = ctx.buffer(reserve=4 * 1024)
        self._splat_vao: moderngl.VertexArray | None = None
        self._splat_temperature_vao: moderngl.VertexArray | None = None
        self._shade = ShadePass(gl, self._programs, environment_dirs)
        self._fullscreen_vaos: dict[int, moderngl.VertexArray] = {}
        self._targets: _Targets | None = None

    @property
    def gl(self) -> GLContext:
        return self._gl

    @property
    def shade_pass(self) -> ShadePass:
        """The shading pass and its caches (environments, IBL, BRDF tables)."""
        return self._shade

    def max_image_side(self) -> int:
        return self._gl.limits.max_image_side

    # -- resources -------------------------------------------------------------------------

    def sph_engine(self) -> SphEngine:
        """The SPH engine and its CL context, created on first use (owner thread)."""
        self._gl.check_owner()
        if self._sph is None:
            if self._cl is None:
                self._cl = CLContext(self._cl_device)
            self._sph = SphEngine(self._cl)
        return self._sph

    def _targets_for(self, width: int, height: int) -> _Targets:
        if self._targets is None or self._targets.size != (width, height):
            if self._targets is not None:
                self._targets.release()
            self._targets = _Targets(self._gl.ctx, width, height)
        return self._targets

    def _fullscreen(self, program: moderngl.Program) -> moderngl.VertexArray:
        vao = self._fullscreen_vaos.get(program.glo)
        if vao is None:
            vao = self._gl.ctx.vertex_array(program, [])
            self._fullscreen_vaos[program.glo] = vao
        return vao

    def _splat_vertex_array(self) -> tuple[moderngl.Program, moderngl.VertexArray]:
        program = self._programs.get("splat/splat_sphere.vert.glsl", "splat/splat_sphere.frag.glsl")
        if self._splat_vao is None:
            self._splat_vao = self._gl.ctx.vertex_array(
                program,
                [
                    (self._corner_buffer, "2f", "in_corner"),
                    (self._instance_buffer, "4f", "in_center_radius"),
                ],
                index_buffer=self._index_buffer,
                index_element_size=4,
            )
        return program, self._splat_vao

    def _splat_temperature_vertex_array(self) -> tuple[moderngl.Program, moderngl.VertexArray]:
        program = self._programs.get(
            "splat/splat_sphere.vert.glsl",
            "splat/splat_sphere.frag.glsl",
            {"HAS_TEMPERATURE": True},
        )
        if self._splat_temperature_vao is None:
            self._splat_temperature_vao = self._gl.ctx.vertex_array(
                program,
                [
                    (self._corner_buffer, "2f", "in_corner"),
                    (self._instance_buffer, "4f", "in_center_radius"),
                    (self._temperature_buffer, "1f", "in_temperature"),
                ],
                index_buffer=self._index_buffer,
                index_element_size=4,
            )
        return program, self._splat_temperature_vao

    @staticmethod
    def _reserve(buffer: moderngl.Buffer, nbytes: int) -> None:
        """Grow `buffer` geometrically to at least `nbytes`; orphan keeps the buffer object, so
        the VAOs stay valid (the contents are lost)."""
        if nbytes > buffer.size:
            buffer.orphan(max(nbytes, buffer.size * 2))

    def _ensure_quads(self, count: int) -> None:
        """Corner (+-1, +-1 per vertex) and index (two triangles per quad) buffers for at least
        `count` quads."""
        if count <= self._quad_capacity:
            return
        capacity = max(count, 2 * self._quad_capacity, 1024)
        corners = np.tile(np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32), capacity)
        first = np.arange(capacity, dtype=np.uint32)[:, None] * 4
        indices = first + np.array([0, 1, 2, 2, 1, 3], dtype=np.uint32)
        # orphan keeps the buffer objects, so the vertex arrays that use them stay valid
        self._corner_buffer.orphan(corners.nbytes)
        self._corner_buffer.write(corners.tobytes())
        self._index_buffer.orphan(indices.nbytes)
        self._index_buffer.write(indices.tobytes())
        self._quad_capacity = capacity

    # -- frame -----------------------------------------------------------------------------

    @contextmanager
    def _stage(self, stats: RenderStats, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        if self._stage_timings:
            self._gl.ctx.finish()
        stats.stage_ms[name] = (time.perf_counter() - start) * 1e3

    def check_image_size(self, scene: Scene) -> None:
        limit = self.max_image_side()
        for key in ("width", "height"):
            value = getattr(scene.image, key)
            if value > limit:
                raise InputError(f"image.{key}", f"must be at most {limit} (GL limit), got {value}")

    def render(
        self,
        frame: ParticleFrame,
        scene: Scene,
        *,
        depth: bool = False,
        normals: bool = False,
    ) -> tuple[RenderedFrame, RenderStats]:
        """Render one frame; `depth` / `normals` ask for those AOVs to be read back."""
        self._gl.check_owner()
        self.check_image_size(scene)
        width, height = scene.image.width, scene.image.height
        camera = Camera.from_config(scene.camera, width, height)
        stats = RenderStats(particles_in=frame.count)
        ctx = self._gl.ctx
        targets = self._targets_for(width, height)

        reference_radius = None
        if needs_sph(scene):
            reference_radius = frame_particle_radius(frame, scene)
            engine = self.sph_engine()  # outside the stage: first use builds the CL program
            with self._stage(stats, "sph"):
                frame, _ = apply_to_frame(engine, frame, scene)

        with self._stage(stats, "prepare"):
            prepared = prepare_particles(frame, camera, scene, reference_radius=reference_radius)
            stats.particles_drawn = int(prepared.center_radius.shape[0])
            stats.far = prepared.far
            bounds = occlusion.sphere_bounds(prepared.center_radius, camera)
            box = screen_box(bounds, camera)

        with self._stage(stats, "splat"):
            temperature = self._splat(
                ctx,
                targets,
                camera,
                prepared,
                bounds=bounds if scene.quality.occlusion_culling else None,
                box=box,
                stats=stats,
            )

        surface = targets.splat_depth
        if scene.quality.filter != "none" and stats.particles_drawn:
            with self._stage(stats, "smooth"):
                surface = self._smooth(
                    targets,
                    px_per_unit=camera.pixels_per_unit_at_unit_depth,
                    particle_radius=prepared.reference_radius,
                    quality=scene.quality,
                    box=box,
                )

        with self._stage(stats, "normals"):
            program = self._programs.get(
                "common/fullscreen.vert.glsl", "normals/surface_normals.frag.glsl"
            )
            surface.use(0)
            program["u_depth"] = 0
            program["u_tan_half_fov"] = (
                camera.tan_half_fov_y * camera.aspect,
                camera.tan_half_fov_y,
            )
            _write_matrix(program, "u_view_to_world", camera.rotation.T)
            _scissored(targets.normal_fbo, box)
            targets.normal_fbo.use()
            self._fullscreen(program).render(moderngl.TRIANGLES, vertices=3)
            _set_scissor(targets.normal_fbo, None)

        with self._stage(stats, "shade"):
            if temperature is not None and stats.particles_drawn:
                temperature = self._shade.smooth_temperature(
                    temperature,
                    surface,
                    camera.pixels_per_unit_at_unit_depth,
                    prepared.reference_radius,
                )
            # A transparent background is vec4(0) from the shader, so the box is exact; an
            # environment background covers every pixel.
            transparent = scene.shading.background == "transparent"
            _scissored(targets.color_fbo, box if transparent else None)
            self._shade.run(scene, camera, targets.normal_depth, temperature, targets.color_fbo)
            _set_scissor(targets.color_fbo, None)

        with self._stage(stats, "readback"):
            rendered = self._read_back(
                targets,
                want_depth=depth,
                want_normals=normals,
                color_box=box if transparent else None,
                surface_box=box,
            )
        return rendered, stats

    def _splat(
        self,
        ctx: moderngl.Context,
        targets: _Targets,
        camera: Camera,
        prepared: PreparedParticles,
        *,
        bounds: occlusion.SphereBounds | None,
        box: ScreenBox | None,
        stats: RenderStats,
    ) -> moderngl.Texture | None:
        """Splat the spheres; returns the temperature target when the frame has temperatures.

        With the spheres' `bounds` (occlusion culling on) and enough particles, the front layer
        is drawn first and only the particles its depth image does not hide follow (see
        `occlusion.py`)."""
        temperature: moderngl.Texture | None = None
        fbo = targets.splat
        if prepared.temperatures is not None:
            temperature, fbo = targets.temperature_targets()
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        count = int(prepared.center_radius.shape[0])
        stats.particles_splatted = count
        if count == 0:
            return temperature
        if prepared.temperatures is not None:
            program, vao = self._splat_temperature_vertex_array()
        else:
            program, vao = self._splat_vertex_array()
        self._ensure_quads(count)
        self._reserve(self._instance_buffer, count * 64)  # 4 corners x vec4
        if prepared.temperatures is not None:
            self._reserve(self._temperature_buffer, count * 16)  # 4 corners x float
        _write_matrix(program, "u_projection", camera.projection_matrix(prepared.far))
        program["u_near"] = camera.near
        program["u_far"] = prepared.far
        ctx.enable(moderngl.DEPTH_TEST)
        try:
            if bounds is None or count < occlusion.MIN_PARTICLES:
                self._draw_spheres(vao, prepared, None, first=0)
                return temperature
            radius = prepared.center_radius[:, 3].astype(np.float64)
            in_front = occlusion.front_layer(bounds, radius, (camera.width, camera.height))
            front = np.flatnonzero(in_front)
            self._draw_spheres(vao, prepared, front, first=0)
            others = np.flatnonzero(~in_front)
            if others.size:
                read_box = box if box is not None else (0, 0, camera.width, camera.height)
                x, y, w, h = read_box
                depth = np.frombuffer(
                    fbo.read(viewport=read_box, components=1, attachment=0, dtype="f4"),
                    np.float32,
                ).reshape(h, w)
                width_px = bounds.x1[others] - bounds.x0[others] + 1
                height_px = bounds.y1[others] - bounds.y0[others] + 1
                table = occlusion.DepthMaxTable(depth, (x, y), np.minimum(width_px, height_px))
                others = others[~table.occluded(bounds, others)]  # the ones that may show
                self._draw_spheres(vao, prepared, others, first=front.size)
            stats.particles_splatted = int(front.size + others.size)
        finally:
            ctx.disable(moderngl.DEPTH_TEST)
        return temperature

    def _draw_spheres(
        self,
        vao: moderngl.VertexArray,
        prepared: PreparedParticles,
        rows: npt.NDArray[np.intp] | None,
        *,
        first: int,
    ) -> None:
        """Upload particles `rows` (None: all) as quads number `first`, `first + 1`, ... and
        draw them. Quads already uploaded below `first` stay in the buffers untouched; the
        buffers must already hold every particle (`_reserve`)."""
        data = prepared.center_radius if rows is None else prepared.center_radius[rows]
        if data.shape[0] == 0:
            return
        self._instance_buffer.write(np.repeat(data, 4, axis=0).tobytes(), offset=first * 64)
        if prepared.temperatures is not None:
            kelvin = prepared.temperatures if rows is None else prepared.temperatures[rows]
            self._temperature_buffer.write(np.repeat(kelvin, 4).tobytes(), offset=first * 16)
        vao.render(moderngl.TRIANGLES, vertices=6 * data.shape[0], first=6 * first)

    def shade_normal_depth(
        self,
        normal_depth: npt.NDArray[np.float32],
        scene: Scene,
        temperatures: npt.NDArray[np.float32] | None = None,
    ) -> npt.NDArray[np.float32]:
        """Run only the shade pass on given world normals + eye depth (H, W, 4), rows top first
        (depth 0 = no surface), and optional per-pixel kelvin (H, W); returns straight RGBA.

        The same code path as `render` uses; exposed so shading can be compared with references
        on exact normals, without the splat and smoothing error in between."""
        self._gl.check_owner()
        height, width = normal_depth.shape[:2]
        if (width, height) != (scene.image.width, scene.image.height):
            raise ValueError("normal_depth must have the scene's image size")
        targets = self._targets_for(width, height)
        targets.normal_depth.write(np.ascontiguousarray(normal_depth[::-1], np.float32).tobytes())
        temperature = None
        if temperatures is not None:
            temperature, _ = targets.temperature_targets()
            temperature.write(np.ascontiguousarray(temperatures[::-1], np.float32).tobytes())
        camera = Camera.from_config(scene.camera, width, height)
        self._shade.run(scene, camera, targets.normal_depth, temperature, targets.color_fbo)
        rgba = np.frombuffer(targets.color.read(), dtype=np.float32).reshape(height, width, 4)
        return np.ascontiguousarray(rgba[::-1])

    def filter_depth_image(
        self,
        depth: npt.NDArray[np.float32],
        *,
        particle_radius: float,
        px_per_unit: float,
        quality: QualityConfig,
    ) -> npt.NDArray[np.float32]:
        """Run only the smoothing pass on an eye-depth image (rows top first, 0 = background).

        The same code path as `render` uses; exposed so the filters can be compared with a numpy
        reference on synthetic images."""
        self._gl.check_owner()
        height, width = depth.shape
        targets = self._targets_for(width, height)
        targets.splat_depth.write(np.ascontiguousarray(depth[::-1], dtype=np.float32).tobytes())
        result = self._smooth(
            targets, px_per_unit=px_per_unit, particle_radius=particle_radius, quality=quality
        )
        out = np.frombuffer(result.read(), dtype=np.float32).reshape(height, width)
        return np.ascontiguousarray(out[::-1])

    def blur_temperature_image(
        self,
        temperature: npt.NDArray[np.float32],
        depth: npt.NDArray[np.float32],
        *,
        particle_radius: float,
        px_per_unit: float,
    ) -> npt.NDArray[np.float32]:
        """Run only the temperature blur on a kelvin image guided by an eye-depth image (both
        rows top first, depth 0 = background). The same code path as `render` uses; exposed so
        the blur can be compared with a numpy reference."""
        self._gl.check_owner()
        height, width = depth.shape
        targets = self._targets_for(width, height)
        kelvin, _ = targets.temperature_targets()
        kelvin.write(np.ascontiguousarray(temperature[::-1], dtype=np.float32).tobytes())
        targets.ping[0].write(np.ascontiguousarray(depth[::-1], dtype=np.float32).tobytes())
        result = self._shade.smooth_temperature(
            kelvin, targets.ping[0], px_per_unit, particle_radius
        )
        out = np.frombuffer(result.read(), dtype=np.float32).reshape(height, width)
        return np.ascontiguousarray(out[::-1])

    def _smooth(
        self,
        targets: _Targets,
        *,
        px_per_unit: float,
        particle_radius: float,
        quality: QualityConfig,
        box: ScreenBox | None = None,
    ) -> moderngl.Texture:
        """Smooth `targets.splat_depth`; returns the texture holding the result. With a `box`
        (see `screen_box`) the passes run only inside it, on targets cleared outside it.

        Separable filters run on a packed image (four pixels per texel, see
        `common/packed_image.glsl`): pack, the 1-D passes, unpack; the 2-D kernels on the plain
        image (`smooth_depth.frag.glsl`)."""
        if quality.filter == "none":
            return targets.splat_depth
        filter_define = _FILTER_DEFINES[quality.filter]
        kernel_define = _KERNEL_SIZE_DEFINES[quality.kernel_size]
        if not quality.separable:
            program = self._programs.get(
                "common/fullscreen.vert.glsl",
                "smooth/smooth_depth.frag.glsl",
                {"FILTER": filter_define, "KERNEL_SIZE": kernel_define},
            )
            self._set_filter_uniforms(program, px_per_unit, particle_radius, quality)
            program["u_depth"] = 0
            vao = self._fullscreen(program)
            for fbo in targets.ping_fbos:
                _scissored(fbo, box)
            source = targets.splat_depth
            write_index = 0
            for _ in range(quality.iterations):
                source.use(0)
                targets.ping_fbos[write_index].use()
                vao.render(moderngl.TRIANGLES, vertices=3)
                source = targets.ping[write_index]
                write_index = 1 - write_index
            for fbo in targets.ping_fbos:
                _set_scissor(fbo, None)
            return source

        packed_box = None if box is None else _packed_box(box)
        for fbo in targets.packed_fbos:
            _scissored(fbo, packed_box)
        pack = self._programs.get("common/fullscreen.vert.glsl", "common/image_pack.frag.glsl")
        pack["u_image"] = 0
        targets.splat_depth.use(0)
        targets.packed_fbos[0].use()
        self._fullscreen(pack).render(moderngl.TRIANGLES, vertices=3)
        passes = {
            axis: self._programs.get(
                "common/fullscreen.vert.glsl",
                "smooth/smooth_depth_separable.frag.glsl",
                {"FILTER": filter_define, "KERNEL_SIZE": kernel_define, "AXIS": axis},
            )
            for axis in (0, 1)
        }
        for program in passes.values():
            self._set_filter_uniforms(program, px_per_unit, particle_radius, quality)
            program["u_packed_depth"] = 0
        read_index = 0
        for iteration in range(quality.iterations):
            # The passes alternate their order (x y, y x, ...): the nonlinear filters leave
            # streaks along the axis filtered last, and alternating keeps them from piling up.
            for axis in (0, 1) if iteration % 2 == 0 else (1, 0):
                targets.packed[read_index].use(0)
                targets.packed_fbos[1 - read_index].use()
                self._fullscreen(passes[axis]).render(moderngl.TRIANGLES, vertices=3)
                read_index = 1 - read_index
        for fbo in targets.packed_fbos:
            _set_scissor(fbo, None)
        unpack = self._programs.get("common/fullscreen.vert.glsl", "common/image_unpack.frag.glsl")
        unpack["u_packed"] = 0
        targets.packed[read_index].use(0)
        _scissored(targets.ping_fbos[0], box)
        targets.ping_fbos[0].use()
        self._fullscreen(unpack).render(moderngl.TRIANGLES, vertices=3)
        _set_scissor(targets.ping_fbos[0], None)
        return targets.ping[0]

    @staticmethod
    def _set_filter_uniforms(
        program: moderngl.Program,
        px_per_unit: float,
        particle_radius: float,
        quality: QualityConfig,
    ) -> None:
        r = particle_radius
        for name, value in (
            ("u_kernel_min_px", quality.kernel_min_px),
            ("u_kernel_max_px", quality.kernel_max_px),
            ("u_particle_radius", r),
            ("u_px_per_unit", px_per_unit),
            ("u_kernel_scale", quality.kernel_scale),
            ("u_eq25_sigma_px", quality.eq25_sigma_px),
            ("u_eq25_threshold", quality.eq25_threshold),
            ("u_eq25_decline", quality.eq25_decline),
            ("u_range_sigma", quality.bilateral_depth_sigma * r),
            ("u_nr_threshold", quality.narrow_range_threshold * r),
            ("u_nr_clamp", quality.narrow_range_clamp * r),
        ):
            if name in program:  # the GLSL compiler drops uniforms the chosen filter never reads
                program[name] = value

    def _read_back(
        self,
        targets: _Targets,
        *,
        want_depth: bool,
        want_normals: bool,
        color_box: ScreenBox | None,
        surface_box: ScreenBox | None,
    ) -> RenderedFrame:
        """Colour, and depth / normals when asked, rows top first. `color_box` / `surface_box`:
        where those targets can be non-zero (None: anywhere); only that part is read."""
        rgba = _read_region(targets.color_fbo, targets.size, color_box)
        depth_out = normals_out = None
        if want_depth or want_normals:
            nd = _read_region(targets.normal_fbo, targets.size, surface_box)
            if want_depth:
                z = nd[:, :, 3]
                depth_out = np.where(z > 0.0, z, np.float32(np.inf)).astype(np.float32)
            if want_normals:
                normals_out = np.ascontiguousarray(nd[:, :, :3])
        return RenderedFrame(rgba=rgba, depth=depth_out, normals=normals_out)

    def release(self) -> None:
        """Release every GPU object this renderer owns (on the owner thread)."""
        self._gl.check_owner()
        if self._targets is not None:
            self._targets.release()
            self._targets = None
        for vao in self._fullscreen_vaos.values():
            vao.release()
        self._fullscreen_vaos.clear()
        for splat_vao in (self._splat_vao, self._splat_temperature_vao):
            if splat_vao is not None:
                splat_vao.release()
        self._splat_vao = self._splat_temperature_vao = None
        self._shade.release()
        self._programs.release()
        if self._sph is not None:
            self._sph.release()
            self._sph = None
        if self._cl is not None:
            self._cl.release()
            self._cl = None
        self._corner_buffer.release()
        self._index_buffer.release()
        self._instance_buffer.release()
        self._temperature_buffer.release()
