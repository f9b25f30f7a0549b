"""Splat pass: sphere impostors -> eye depth (and the front sphere's temperature).

Shaders: `shaders/splat/splat_sphere.{vert,frag}.glsl`. Per particle one quad perpendicular to
the eye ray, sized to the silhouette cone; per fragment a ray-sphere hit writes the eye depth to
an R32F target (0 = background) and a linear `gl_FragDepth` for the depth test. Frames with
temperatures also write the front sphere's kelvin to a second R32F target.

With the spheres' screen bounds (occlusion culling on) and enough particles, the front layer is
drawn first and only the particles its depth image does not hide follow
(`geometry/occlusion.py`, exact): the same image from a fraction of the quads.

Owns: the corner, index, instance and temperature buffers, both vertex arrays, and the splat
targets (depth texture, depth renderbuffer, temperature texture, their framebuffers).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.geometry import occlusion
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.prepare import PreparedParticles
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import (
    PerSize,
    Target,
    float_texture,
    set_if_used,
    write_matrix,
)
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

VERTEX_SHADER = "splat/splat_sphere.vert.glsl"
FRAGMENT_SHADER = "splat/splat_sphere.frag.glsl"
SEED_SHADER = "splat/depth_seed.frag.glsl"
ELLIPSOID_VERTEX_SHADER = "splat/splat_ellipsoid.vert.glsl"
ELLIPSOID_FRAGMENT_SHADER = "splat/splat_ellipsoid.frag.glsl"
COVERAGE_VERTEX_SHADER = "splat/splat_coverage.vert.glsl"
COVERAGE_FRAGMENT_SHADER = "splat/splat_coverage.frag.glsl"
#: How far past a silhouette the coverage quads reach, in pixels.
COVERAGE_MARGIN_PX = 1.5
#: Whole pixels a coverage quad reaches past its sphere's bounds rectangle.
COVERAGE_REACH_PX = 2
#: A particle whose rectangle grown by this many pixels is covered all over needs no coverage:
#: its quads reach COVERAGE_REACH_PX past it, and the shade pass looks 1 pixel further.
INTERIOR_REACH_PX = COVERAGE_REACH_PX + 1


@dataclass(frozen=True)
class SplatOutput:
    depth: moderngl.Texture  # eye depth, R32F, 0 = background
    temperature: moderngl.Texture | None  # kelvin of the front sphere, when the frame has them
    splatted: int  # particles rasterised (visible less those found hidden)
    coverage: moderngl.Texture | None = None  # sub-pixel coverage (R32F), when anti-aliasing


class SplatTargets:
    """The splat's render targets for one image size; the temperature target is built on the
    first frame that carries temperatures (most frames never need it)."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.size = size
        self._ctx = ctx
        self.depth = float_texture(ctx, size, 1)
        self.depth_buffer = ctx.depth_renderbuffer(size)
        self.fbo = ctx.framebuffer([self.depth], self.depth_buffer)
        self.temperature: moderngl.Texture | None = None
        self.fbo_with_temperature: moderngl.Framebuffer | None = None
        self.coverage: Target | None = None  # built on the first anti-aliased frame
        # The smoothed surface with the exact droplets drawn over it (built on first use).
        self.composite: moderngl.Texture | None = None
        self.composite_fbo: moderngl.Framebuffer | None = None
        self.composite_with_temperature: moderngl.Framebuffer | None = None

    def composite_targets(
        self, with_temperature: bool
    ) -> tuple[moderngl.Texture, moderngl.Framebuffer, moderngl.Framebuffer]:
        """(composite texture, its seed framebuffer, the framebuffer the droplets draw into:
        composite + temperature when `with_temperature`), all on the splat's depth buffer."""
        if self.composite is None or self.composite_fbo is None:
            self.composite = float_texture(self._ctx, self.size, 1)
            self.composite_fbo = self._ctx.framebuffer([self.composite], self.depth_buffer)
        if not with_temperature:
            return self.composite, self.composite_fbo, self.composite_fbo
        temperature, _ = self.temperature_targets()
        if self.composite_with_temperature is None:
            self.composite_with_temperature = self._ctx.framebuffer(
                [self.composite, temperature], self.depth_buffer
            )
        return self.composite, self.composite_fbo, self.composite_with_temperature

    def coverage_target(self) -> Target:
        if self.coverage is None:
            self.coverage = Target.float(self._ctx, self.size, 1)
        return self.coverage

    def temperature_targets(self) -> tuple[moderngl.Texture, moderngl.Framebuffer]:
        if self.temperature is None or self.fbo_with_temperature is None:
            self.temperature = float_texture(self._ctx, self.size, 1)
            self.fbo_with_temperature = self._ctx.framebuffer(
                [self.depth, self.temperature], self.depth_buffer
            )
        return self.temperature, self.fbo_with_temperature

    def release(self) -> None:
        fbos = (self.fbo, self.fbo_with_temperature, self.composite_fbo)
        for fbo in (*fbos, self.composite_with_temperature):
            if fbo is not None:
                fbo.release()
        for texture in (self.depth, self.temperature, self.composite):
            if texture is not None:
                texture.release()
        if self.coverage is not None:
            self.coverage.release()
        self.depth_buffer.release()


class SplatPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        ctx = context.gl.ctx
        # Sphere quads are drawn as plain indexed triangles, 4 vertices per particle, not as
        # instances: llvmpipe's draw module runs its vertex pipeline once per instance, which
        # made the splat of 90k particles cost ~70 ms of pure per-instance overhead. The corner
        # and index buffers depend only on the particle count and grow geometrically.
        self._quad_capacity = 0
        self._corner_buffer = ctx.buffer(reserve=4)
        self._index_buffer = ctx.buffer(reserve=4)
        self._instance_buffer = ctx.buffer(reserve=16 * 1024)
        self._temperature_buffer = ctx.buffer(reserve=4 * 1024)
        self._axes_buffer = ctx.buffer(reserve=36 * 1024)  # ellipsoids: 3 semi-axes per vertex
        # Keyed by (ellipsoid, has temperature, coverage).
        self._vaos: dict[tuple[bool, bool, bool], moderngl.VertexArray] = {}
        self._targets = PerSize(lambda size: SplatTargets(context.gl.ctx, size))

    def targets(self, size: tuple[int, int]) -> SplatTargets:
        """The targets for `size` (rebuilt only when the size changes)."""
        return self._targets.get(size)

    def run(
        self,
        camera: Camera,
        prepared: PreparedParticles,
        *,
        bounds: occlusion.SphereBounds | None,
        box: ScreenBox | None,
        antialias: bool = False,
    ) -> SplatOutput:
        """Splat `prepared`; `bounds` (None: no occlusion culling) are the spheres' screen
        rectangles, `box` the screen box holding them (where the front layer is read back).
        `antialias`: also draw the splatted spheres' sub-pixel coverage (`coverage`)."""
        targets = self.targets((camera.width, camera.height))
        temperature: moderngl.Texture | None = None
        fbo = targets.fbo
        if prepared.temperatures is not None:
            temperature, fbo = targets.temperature_targets()
        fbo.use()
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        count = int(prepared.center_radius.shape[0])
        coverage = None
        if antialias:
            coverage = targets.coverage_target()
            coverage.fbo.clear(0.0, 0.0, 0.0, 0.0)
            fbo.use()
        if count == 0:
            return SplatOutput(targets.depth, temperature, 0, _texture(coverage))
        program, vao = self._vertex_array(
            prepared.axes is not None, prepared.temperatures is not None
        )
        self._reserve_for(prepared, count)
        self._set_depth_uniforms(program, camera, prepared.far)
        ctx = self._context.gl.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        try:
            coverage_rows = None  # None: every quad drawn needs its coverage
            if bounds is None or count < occlusion.MIN_PARTICLES:
                self._draw_spheres(vao, prepared, None, first=0)
                splatted = count
            else:
                splatted, coverage_rows = self._draw_culled(
                    fbo, vao, camera, prepared, bounds, box, antialias
                )
        finally:
            ctx.disable(moderngl.DEPTH_TEST)
        if coverage is not None:
            if coverage_rows is None:
                self._draw_coverage(coverage, camera, prepared, 0, splatted)
            elif coverage_rows.size:
                # Only the particles near an edge, uploaded after the splatted ones (whose
                # contents the depth pass no longer needs, so growing may drop them).
                self._reserve_for(prepared, splatted + coverage_rows.size)
                self._draw_spheres(None, prepared, coverage_rows, first=splatted)
                self._draw_coverage(coverage, camera, prepared, splatted, coverage_rows.size)
        return SplatOutput(targets.depth, temperature, splatted, _texture(coverage))

    def run_droplets(
        self,
        camera: Camera,
        droplets: PreparedParticles,
        surface: moderngl.Texture,
        temperature: moderngl.Texture | None,
        coverage: moderngl.Texture | None = None,
    ) -> SplatOutput:
        """Draw `droplets` as exact spheres over the (smoothed) eye depth `surface`: the depth
        is copied into the composite target with its depth-buffer value, then the droplets are
        depth-tested against it. Returns the composite (and the temperature target, into which
        the droplets that show write their kelvin); with `coverage` (the bulk splat's) the
        droplets' coverage is added to it."""
        targets = self.targets((camera.width, camera.height))
        with_temperature = temperature is not None and droplets.temperatures is not None
        composite, seed_fbo, draw_fbo = targets.composite_targets(with_temperature)
        ctx = self._context.gl.ctx
        seed_fbo.use()
        seed_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        seed = self._context.programs.get(FULLSCREEN_VERT, SEED_SHADER)
        seed["u_depth"] = 0
        seed["u_far"] = droplets.far
        surface.use(0)
        count = int(droplets.center_radius.shape[0])
        ctx.enable(moderngl.DEPTH_TEST)
        try:
            self._context.fullscreen.draw(seed)
            if count:
                program, vao = self._vertex_array(droplets.axes is not None, with_temperature)
                self._reserve_for(droplets, count)
                self._set_depth_uniforms(program, camera, droplets.far)
                draw_fbo.use()
                self._draw_spheres(vao, droplets, None, first=0)
        finally:
            ctx.disable(moderngl.DEPTH_TEST)
        if coverage is not None and count:
            self._draw_coverage(targets.coverage_target(), camera, droplets, 0, count)
        return SplatOutput(composite, temperature, count, coverage)

    def _draw_coverage(
        self, target: Target, camera: Camera, prepared: PreparedParticles, first: int, count: int
    ) -> None:
        """Coverage of quads `first` .. `first + count` in the buffers, into `target` with
        blending MAX and no depth test (see splat_coverage.frag.glsl)."""
        if count == 0:
            return
        ctx = self._context.gl.ctx
        program, vao = self._vertex_array(prepared.axes is not None, False, coverage=True)
        focal_px = camera.pixels_per_unit_at_unit_depth
        write_matrix(program, "u_projection", camera.projection_matrix(prepared.far))
        program["u_margin"] = COVERAGE_MARGIN_PX / focal_px
        program["u_near"] = camera.near
        set_if_used(program, "u_focal_px", focal_px)
        set_if_used(program, "u_far", prepared.far)
        target.fbo.use()
        ctx.enable(moderngl.BLEND)
        ctx.blend_equation = moderngl.MAX  # type: ignore[assignment]  # the stub wants a pair
        try:
            vao.render(moderngl.TRIANGLES, vertices=6 * count, first=6 * first)
        finally:
            ctx.blend_equation = moderngl.FUNC_ADD  # type: ignore[assignment]
            ctx.disable(moderngl.BLEND)

    def _set_depth_uniforms(self, program: moderngl.Program, camera: Camera, far: float) -> None:
        write_matrix(program, "u_projection", camera.projection_matrix(far))
        program["u_near"] = camera.near
        program["u_far"] = far
        set_if_used(program, "u_margin", 0.0)

    def _reserve_for(self, prepared: PreparedParticles, count: int) -> None:
        """Quads and per-vertex buffers for `count` particles of `prepared`'s kind."""
        self._ensure_quads(count)
        self._reserve(self._instance_buffer, count * 64)  # 4 corners x vec4
        if prepared.temperatures is not None:
            self._reserve(self._temperature_buffer, count * 16)  # 4 corners x float
        if prepared.axes is not None:
            self._reserve(self._axes_buffer, count * 144)  # 4 corners x 3 x vec3

    def _draw_culled(
        self,
        fbo: moderngl.Framebuffer,
        vao: moderngl.VertexArray,
        camera: Camera,
        prepared: PreparedParticles,
        bounds: occlusion.SphereBounds,
        box: ScreenBox | None,
        antialias: bool = False,
    ) -> tuple[int, npt.NDArray[np.intp] | None]:
        """Front layer, read its depth back, then only the particles it does not hide. Returns
        how many were drawn and, with `antialias`, which of them can reach a silhouette (None:
        all): a particle whose surroundings the front layer covers entirely within
        INTERIOR_REACH_PX adds nothing to the coverage that the shade pass keeps."""
        radius = prepared.center_radius[:, 3].astype(np.float64)
        in_front = occlusion.front_layer(bounds, radius, (camera.width, camera.height))
        front = np.flatnonzero(in_front)
        self._draw_spheres(vao, prepared, front, first=0)
        others = np.flatnonzero(~in_front)
        if not others.size and not antialias:
            return int(front.size), None
        read_box = box if box is not None else (0, 0, camera.width, camera.height)
        x, y, w, h = read_box
        depth = np.frombuffer(
            fbo.read(viewport=read_box, components=1, attachment=0, dtype="f4"), np.float32
        ).reshape(h, w)
        sides = np.minimum(bounds.x1 - bounds.x0, bounds.y1 - bounds.y0) + 1
        if antialias:
            sides = np.concatenate(
                [sides, sides + 2 * COVERAGE_REACH_PX, sides + 2 * INTERIOR_REACH_PX]
            )
        table = occlusion.DepthMaxTable(depth, (x, y), sides)
        # "Covered all over within k pixels": the front layer's largest depth there is finite.
        infinitely_far = np.full_like(radius, np.inf)

        def covered_around(rows: npt.NDArray[np.intp], pixels: int) -> npt.NDArray[np.bool_]:
            grown = replace(bounds.grown(pixels), near_depth=infinitely_far)
            return table.occluded(grown, rows)

        if others.size:
            hidden = table.occluded(bounds, others)
            if antialias:  # a silhouette within the coverage reach still shows
                hidden[hidden] = covered_around(others[hidden], COVERAGE_REACH_PX)
            others = others[~hidden]
            self._draw_spheres(vao, prepared, others, first=front.size)
        drawn = np.concatenate([front, others])
        if not antialias:
            return int(drawn.size), None
        return int(drawn.size), drawn[~covered_around(drawn, INTERIOR_REACH_PX)]

    def _vertex_array(
        self, ellipsoid: bool, has_temperature: bool, *, coverage: bool = False
    ) -> tuple[moderngl.Program, moderngl.VertexArray]:
        """The program and vertex array of one kind of splat draw (spheres or ellipsoids,
        with or without temperatures, depth or coverage)."""
        programs = self._context.programs
        if ellipsoid:
            program = programs.get(
                ELLIPSOID_VERTEX_SHADER,
                ELLIPSOID_FRAGMENT_SHADER,
                {"HAS_TEMPERATURE": has_temperature, "COVERAGE": coverage},
            )
        elif coverage:
            program = programs.get(COVERAGE_VERTEX_SHADER, COVERAGE_FRAGMENT_SHADER)
        else:
            sphere_defines = {"HAS_TEMPERATURE": True} if has_temperature else None
            program = programs.get(VERTEX_SHADER, FRAGMENT_SHADER, sphere_defines)
        key = (ellipsoid, has_temperature, coverage)
        vao = self._vaos.get(key)
        if vao is None:
            attributes: list[tuple[Any, ...]] = [
                (self._corner_buffer, "2f", "in_corner"),
                (self._instance_buffer, "4f", "in_center_radius"),
            ]
            if ellipsoid:
                attributes.append(
                    (self._axes_buffer, "3f 3f 3f", "in_axis0", "in_axis1", "in_axis2")
                )
            if has_temperature:
                attributes.append((self._temperature_buffer, "1f", "in_temperature"))
            vao = self._context.gl.ctx.vertex_array(
                program, attributes, index_buffer=self._index_buffer, index_element_size=4
            )
            self._vaos[key] = vao
        return program, vao

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

    def _draw_spheres(
        self,
        vao: moderngl.VertexArray | None,
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
        if prepared.axes is not None:
            axes = prepared.axes if rows is None else prepared.axes[rows]
            columns = np.ascontiguousarray(axes.transpose(0, 2, 1)).reshape(-1, 9)
            self._axes_buffer.write(np.repeat(columns, 4, axis=0).tobytes(), offset=first * 144)
        if prepared.temperatures is not None:
            kelvin = prepared.temperatures if rows is None else prepared.temperatures[rows]
            self._temperature_buffer.write(np.repeat(kelvin, 4).tobytes(), offset=first * 16)
        if vao is not None:  # None: upload only
            vao.render(moderngl.TRIANGLES, vertices=6 * data.shape[0], first=6 * first)

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        self._targets.release()
        for buffer in (
            self._corner_buffer,
            self._index_buffer,
            self._instance_buffer,
            self._temperature_buffer,
            self._axes_buffer,
        ):
            buffer.release()


def _texture(target: Target | None) -> moderngl.Texture | None:
    return None if target is None else target.texture
