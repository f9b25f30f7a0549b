"""Splat pass: sphere impostors -> eye depth (and the front sphere's temperature).

Shaders: `shaders/splat/splat_sphere.{vert,frag}.glsl`. Per particle one quad perpendicular to
the eye ray, sized to the silhouette cone; per fragment a ray-sphere hit writes the eye depth to
an R32F target (0 = background) and a linear `gl_FragDepth` for the depth test. Frames with
temperatures also write the front sphere's kelvin to a second R32F target.

With the spheres' screen bounds (occlusion culling on) and enough particles, the front layer is
drawn first and only the particles its depth image does not hide follow
(`geometry/occlusion.py`, exact): the same image from a fraction of the quads.

The vertex stage pulls each quad's particle from storage buffers (`splat_buffers.py`): the host
prepare uploads the culled view-space spheres once and the occlusion culling's subsets as id
lists; the device prepare (`device_prepare.py`) writes the spheres on the GPU.

Owns: the storage buffers (`SplatBuffers`), the attribute-less vertex arrays, and the splat
targets (depth texture, depth renderbuffer, temperature texture, their framebuffers).
"""

from __future__ import annotations

from contextlib import nullcontext
from dataclasses import dataclass, replace

import moderngl
import numpy as np

from sphrender.server.engine.geometry import occlusion
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.prepare import PreparedParticles
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, float_texture
from sphrender.server.engine.gpu.gl_clock import GLClock
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, write_matrix
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.coverage_band import CoverageBand, gate
from sphrender.server.engine.passes.device_culling import (
    COVER,
    FRONT,
    SECOND,
    DeviceCulling,
    DeviceCullInput,
)
from sphrender.server.engine.passes.splat_buffers import (
    AXES,
    IDS,
    PEAKS,
    SPHERES,
    TEMPERATURES,
    SplatBuffers,
)

VERTEX_SHADER = "splat/splat_sphere.vert.glsl"
FRAGMENT_SHADER = "splat/splat_sphere.frag.glsl"
SEED_SHADER = "splat/depth_seed.frag.glsl"
ELLIPSOID_VERTEX_SHADER = "splat/splat_ellipsoid.vert.glsl"
ELLIPSOID_FRAGMENT_SHADER = "splat/splat_ellipsoid.frag.glsl"
COVERAGE_VERTEX_SHADER = "splat/splat_coverage.vert.glsl"
COVERAGE_FRAGMENT_SHADER = "splat/splat_coverage.frag.glsl"
#: How far past a silhouette the coverage quads reach, in pixels.
COVERAGE_MARGIN_PX = 1.5
#: Which particles' coverage is drawn: those whose bounds rectangle, grown by this many pixels,
#: the front layer does not cover all over. Why that is every coverage the shade pass reads:
#: it reads coverage only at a pixel next to one without surface (coverage_band.py), where the
#: value is the largest of the spheres overlapping it. A sphere covering the pixel's centre
#: gives at least 1/2 there, one not covering it at most 1/2 (the straight-edge model of
#: common/edge_coverage.glsl), so at a pixel with a surface only the spheres covering its
#: centre count: their rectangles hold the pixel and its neighbours (a rectangle is the pixel
#: centres its sphere covers and one more on each side), among them the one without surface.
#: A pixel without surface gets the coverage of the spheres overlapping it, whose rectangles
#: hold it. Either way the rectangle has a pixel without surface. So a hidden particle (every
#: pixel of its rectangle has a nearer surface) never needs its coverage drawn either.
COVERAGE_NEED_PX = 0


@dataclass(frozen=True)
class SplatOutput:
    depth: moderngl.Texture  # eye depth, R32F, 0 = background
    # kelvin of the front sphere, when the frame has them (RG32F: + its peak, when it has those)
    temperature: moderngl.Texture | None
    splatted: int  # particles rasterised (visible less those found hidden); -1: device prepare
    coverage: moderngl.Texture | None = None  # sub-pixel coverage (R32F), when anti-aliasing
    # The bulk's eye depth the droplets drew over (run_droplets); None: `depth` is the bulk's.
    bulk_depth: moderngl.Texture | None = None


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
        self, with_temperature: bool, channels: int = 1
    ) -> tuple[moderngl.Texture, moderngl.Framebuffer, moderngl.Framebuffer]:
        """(composite texture, its seed framebuffer, the framebuffer the droplets draw into:
        composite + temperature when `with_temperature`), all on the splat's depth buffer."""
        if self.composite is None or self.composite_fbo is None:
            self.composite = float_texture(self._ctx, self.size, 1)
            self.composite_fbo = self._ctx.framebuffer([self.composite], self.depth_buffer)
        if not with_temperature:
            return self.composite, self.composite_fbo, self.composite_fbo
        temperature, _ = self.temperature_targets(channels)
        if self.composite_with_temperature is None:
            self.composite_with_temperature = self._ctx.framebuffer(
                [self.composite, temperature], self.depth_buffer
            )
        return self.composite, self.composite_fbo, self.composite_with_temperature

    def coverage_target(self) -> Target:
        if self.coverage is None:
            self.coverage = Target.float(self._ctx, self.size, 1)
        return self.coverage

    def temperature_targets(
        self, channels: int = 1
    ) -> tuple[moderngl.Texture, moderngl.Framebuffer]:
        """The kelvin target (`channels` 2: kelvin and peak kelvin) and its framebuffer with the
        depth; rebuilt when the frames switch between with and without peaks."""
        if self.temperature is not None and self.temperature.components != channels:
            for fbo in (self.fbo_with_temperature, self.composite_with_temperature):
                if fbo is not None:
                    fbo.release()
            self.temperature.release()
            self.temperature = self.fbo_with_temperature = self.composite_with_temperature = None
        if self.temperature is None or self.fbo_with_temperature is None:
            self.temperature = float_texture(self._ctx, self.size, channels)
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


@dataclass(frozen=True)
class SplatBatch:
    """The particles the splat buffers hold for one draw (`SplatPass.upload`, or the device
    prepare pass): quads 0 .. count - 1."""

    count: int
    far: float
    has_temperature: bool
    ellipsoid: bool
    #: Draw the particles marked as exact droplets (device prepare marks them in the spheres'
    #: sign) instead of the bulk.
    droplets: bool = False
    #: The CPU's copy (host prepare): what the occlusion culling reads. None: device prepare.
    host: PreparedParticles | None = None
    #: The frame's peak temperatures are in the buffers (written beside the kelvin).
    has_peak: bool = False


class SplatPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        # Quads are plain indexed triangles, 4 vertices per particle, not instances: llvmpipe's
        # draw module runs its vertex pipeline once per instance, which made the splat of 90k
        # particles cost ~70 ms of pure per-instance overhead. The vertex stage pulls its
        # particle from storage buffers (splat_buffers.py), so nothing is repeated per corner.
        self.buffers = SplatBuffers(context.gl)
        self._culling = DeviceCulling(context, self.buffers, COVERAGE_NEED_PX)
        self._culled_on_device = False
        # Keyed by (ellipsoid, has temperature, coverage, has peak).
        self._vaos: dict[
            tuple[bool, bool, bool, bool], tuple[moderngl.Program, moderngl.VertexArray]
        ] = {}
        self._targets = PerSize(lambda size: SplatTargets(context.gl.ctx, size))
        self._band = CoverageBand(context)  # where the coverage pass does its work

    def targets(self, size: tuple[int, int]) -> SplatTargets:
        """The targets for `size` (rebuilt only when the size changes)."""
        return self._targets.get(size)

    def upload(self, prepared: PreparedParticles) -> SplatBatch:
        """Host prepare: write `prepared` (already culled, view space) into the buffers."""
        buffers = self.buffers
        buffers.write(SPHERES, prepared.center_radius)
        if prepared.temperatures is not None:
            buffers.write(TEMPERATURES, prepared.temperatures)
        if prepared.axes is not None:
            buffers.write(AXES, prepared.axes)
        if prepared.peak_temperatures is not None:
            buffers.write(PEAKS, prepared.peak_temperatures)
        return SplatBatch(
            int(prepared.center_radius.shape[0]),
            prepared.far,
            prepared.temperatures is not None,
            prepared.axes is not None,
            host=prepared,
            has_peak=prepared.temperatures is not None and prepared.peak_temperatures is not None,
        )

    def run(
        self,
        camera: Camera,
        batch: SplatBatch,
        *,
        bounds: occlusion.SphereBounds | None,
        box: ScreenBox | None,
        antialias: bool = False,
        device_cull: DeviceCullInput | None = None,
    ) -> SplatOutput:
        """Splat `batch`; `bounds` (host prepare) or `device_cull` (device prepare), None for
        neither: no occlusion culling; `bounds` are the spheres' screen rectangles, `box` the
        screen box holding them (where the front layer is read back or its pyramid built).
        `antialias`: also draw the splatted spheres' sub-pixel coverage."""
        self._culled_on_device = False
        targets = self.targets((camera.width, camera.height))
        temperature: moderngl.Texture | None = None
        fbo = targets.fbo
        if batch.has_temperature:
            temperature, fbo = targets.temperature_targets(2 if batch.has_peak else 1)
        clock = self._context.gl.clock
        fbo.use()
        with clock:
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        # Cleared by the coverage band (passes/coverage_band.py) when there are particles.
        coverage = targets.coverage_target() if antialias else None
        if batch.count == 0:
            if coverage is not None:
                with clock:
                    coverage.fbo.clear(0.0, 0.0, 0.0, 0.0)
            return SplatOutput(targets.depth, temperature, 0, _texture(coverage))
        self.buffers.ensure_quads(batch.count)
        self.buffers.bind()
        vao = self._depth_draw(camera, batch)
        ctx = self._context.gl.ctx
        ctx.enable(moderngl.DEPTH_TEST)
        try:
            coverage_ids = None  # None: every quad drawn needs its coverage
            coverage_mask = 0
            host = batch.host
            few = batch.count < occlusion.MIN_PARTICLES
            if host is None and device_cull is not None and not few:
                self._draw_culled_on_device(vao, camera, device_cull, targets, box, antialias)
                splatted, coverage_mask = -1, COVER
            elif host is None or bounds is None or few:
                _render(vao, 0, batch.count, use_ids=False, clock=self._context.gl.clock)
                splatted = batch.count
            else:
                splatted, coverage_ids = self._draw_culled(
                    fbo, vao, camera, host, bounds, box, antialias
                )
        finally:
            ctx.disable(moderngl.DEPTH_TEST)
        if host is None:
            splatted = -1  # the device prepare counts what it drew
        if coverage is not None:
            gated = self._band.run(targets.depth, coverage.texture, box)
            if coverage_ids is None:
                self._draw_coverage(
                    gated, camera, batch, 0, batch.count, banded=True, flag_mask=coverage_mask
                )
            elif coverage_ids[1]:
                self._draw_coverage(gated, camera, batch, *coverage_ids, banded=True, use_ids=True)
        return SplatOutput(targets.depth, temperature, splatted, _texture(coverage))

    def run_droplets(
        self,
        camera: Camera,
        droplets: SplatBatch,
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
        with_temperature = temperature is not None and droplets.has_temperature
        channels = temperature.components if temperature is not None else 1
        composite, seed_fbo, draw_fbo = targets.composite_targets(with_temperature, channels)
        ctx = self._context.gl.ctx
        seed_fbo.use()
        with self._context.gl.clock:
            seed_fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        seed = self._context.programs.get(FULLSCREEN_VERT, SEED_SHADER, samplers={"u_depth": 0})
        set_if_used(seed, "u_far", droplets.far)
        surface.use(0)
        count = droplets.count
        ctx.enable(moderngl.DEPTH_TEST)
        try:
            self._context.fullscreen.draw(seed)
            if count:
                self.buffers.ensure_quads(count)
                self.buffers.bind()
                vao = self._depth_draw(
                    camera,
                    replace(
                        droplets,
                        has_temperature=with_temperature,
                        has_peak=with_temperature and channels == 2,
                    ),
                )
                draw_fbo.use()
                _render(vao, 0, count, use_ids=False, clock=self._context.gl.clock)
        finally:
            ctx.disable(moderngl.DEPTH_TEST)
        if coverage is not None and count:
            self._draw_coverage(targets.coverage_target().fbo, camera, droplets, 0, count)
        splatted = count if droplets.host is not None else -1  # -1: the device prepare counts
        return SplatOutput(composite, temperature, splatted, coverage, bulk_depth=surface)

    def _depth_draw(self, camera: Camera, batch: SplatBatch) -> moderngl.VertexArray:
        """The vertex array of `batch`'s depth splat, its uniforms set."""
        program, vao = self._vertex_array(
            batch.ellipsoid, batch.has_temperature, has_peak=batch.has_peak
        )
        set_group(
            program,
            "batch",
            _uniform_key(camera, batch),
            lambda: _particle_uniforms(program, camera, batch, margin=0.0),
        )
        return vao

    def _draw_coverage(
        self,
        fbo: moderngl.Framebuffer,
        camera: Camera,
        batch: SplatBatch,
        first: int,
        count: int,
        *,
        banded: bool = False,
        use_ids: bool = False,
        flag_mask: int = 0,
    ) -> None:
        """Coverage of quads `first` .. `first + count` (of the id list when `use_ids`) into
        `fbo` with blending MAX (see splat_coverage.frag.glsl); `banded`: only inside the band
        that `fbo` holds as its depth (coverage_band.py `gate`), else everywhere."""
        if count == 0:
            return
        ctx = self._context.gl.ctx
        program, vao = self._vertex_array(batch.ellipsoid, False, coverage=True)
        focal_px = camera.pixels_per_unit_at_unit_depth
        set_group(
            program,
            "batch",
            _uniform_key(camera, batch),
            lambda: {
                **_particle_uniforms(
                    program,
                    camera,
                    replace(batch, has_temperature=False),
                    margin=COVERAGE_MARGIN_PX / focal_px,
                ),
                "u_focal_px": focal_px,
            },
        )
        fbo.use()
        ctx.enable(moderngl.BLEND)
        ctx.blend_equation = moderngl.MAX  # type: ignore[assignment]  # the stub wants a pair
        try:
            with gate(ctx, fbo) if banded else nullcontext():
                _render(
                    vao,
                    first,
                    count,
                    use_ids=use_ids,
                    clock=self._context.gl.clock,
                    mask=flag_mask,
                )
        finally:
            ctx.blend_equation = moderngl.FUNC_ADD  # type: ignore[assignment]
            ctx.disable(moderngl.BLEND)

    def _draw_culled(
        self,
        fbo: moderngl.Framebuffer,
        vao: moderngl.VertexArray,
        camera: Camera,
        prepared: PreparedParticles,
        bounds: occlusion.SphereBounds,
        box: ScreenBox | None,
        antialias: bool = False,
    ) -> tuple[int, tuple[int, int] | None]:
        """Front layer, read its depth back, then only the particles it does not hide; each
        subset is an id list (splat_buffers.IDS) over the uploaded spheres. Returns how many were
        drawn and, with `antialias`, where in the id list the ones that can reach a silhouette
        are (first, count; None: all): a particle whose surroundings the front layer covers
        entirely within COVERAGE_NEED_PX adds nothing to the coverage the shade pass keeps, nor
        does a hidden one (see COVERAGE_NEED_PX)."""
        radius = prepared.center_radius[:, 3].astype(np.float64)
        size = (camera.width, camera.height)
        in_front = occlusion.front_layer(bounds, radius, size)
        repeated = occlusion.repeats(bounds, prepared.center_radius, in_front, size)
        in_front &= ~repeated
        front = np.flatnonzero(in_front).astype(np.uint32)
        count = int(radius.size)
        # front + others + the coverage rows after them: at most 2 count ids, and quads
        self.buffers.reserve(IDS, 2 * count + 1)
        self.buffers.ensure_quads(2 * count)
        self.buffers.write(IDS, front)
        _render(vao, 0, front.size, use_ids=True, clock=self._context.gl.clock)
        others = np.flatnonzero(~(in_front | repeated))
        if not others.size and not antialias:
            return int(front.size), None
        read_box = box if box is not None else (0, 0, camera.width, camera.height)
        x, y, w, h = read_box
        with self._context.gl.clock:
            data = fbo.read(viewport=read_box, components=1, attachment=0, dtype="f4")
        depth = np.frombuffer(data, np.float32).reshape(h, w)
        sides = np.minimum(bounds.x1 - bounds.x0, bounds.y1 - bounds.y0) + 1
        if antialias and COVERAGE_NEED_PX:  # rectangles grown for the coverage test
            sides = np.concatenate([sides, sides + 2 * COVERAGE_NEED_PX])
        table = occlusion.DepthMaxTable(depth, (x, y), sides)
        # The front layer's largest depth in each rectangle: a particle nearer than none of it
        # is hidden; one whose rectangle (grown by COVERAGE_NEED_PX) holds no background is
        # covered all over. One query for both where the rectangles are the same.
        shared = antialias and not COVERAGE_NEED_PX
        largest = table.largest(bounds, np.arange(count)) if shared else None
        if others.size:
            behind = largest[others] if largest is not None else table.largest(bounds, others)
            others = others[~(bounds.near_depth[others] > behind)]
            self.buffers.write(IDS, others.astype(np.uint32), offset_items=front.size)
            _render(vao, front.size, others.size, use_ids=True, clock=self._context.gl.clock)
        drawn = int(front.size + others.size)
        if not antialias:
            return drawn, None
        ids = np.concatenate([front, others.astype(np.uint32)]).astype(np.intp)
        if largest is None:
            largest = np.full(count, np.inf)
            largest[ids] = table.largest(bounds.grown(COVERAGE_NEED_PX), ids)
        edge = ids[~np.isfinite(largest[ids])].astype(np.uint32)
        self.buffers.write(IDS, edge, offset_items=drawn)
        return drawn, (drawn, int(edge.size))

    def splatted(self, answered: int, visible: int) -> int:
        """Particles the last `run` rasterised: what it `answered`, or when that is -1 (device
        prepare) all `visible` ones or what the device culling counted (waits for the GPU)."""
        if answered >= 0:
            return answered
        return self._culling.drawn() if self._culled_on_device else visible

    def _draw_culled_on_device(
        self,
        vao: moderngl.VertexArray,
        camera: Camera,
        cull: DeviceCullInput,
        targets: SplatTargets,
        box: ScreenBox | None,
        antialias: bool,
    ) -> None:
        """Front layer, its max-depth pyramid, then the rest (device_culling.py); the
        particles' flags select each draw's quads."""
        clock = self._context.gl.clock
        self._culling.mark_front(camera, cull, antialias)
        _render(vao, 0, cull.count, use_ids=False, clock=clock, mask=FRONT)
        self._culling.mark_rest(camera, cull, targets.depth, box, antialias)
        _render(vao, 0, cull.count, use_ids=False, clock=clock, mask=SECOND)
        self._culled_on_device = True

    def _vertex_array(
        self,
        ellipsoid: bool,
        has_temperature: bool,
        *,
        coverage: bool = False,
        has_peak: bool = False,
    ) -> tuple[moderngl.Program, moderngl.VertexArray]:
        """The program and vertex array of one kind of splat draw (spheres or ellipsoids,
        with or without temperatures, depth or coverage). The arrays have no attributes: the
        vertex stage pulls its particle from the storage buffers."""
        has_peak = has_peak and has_temperature and not coverage
        key = (ellipsoid, has_temperature, coverage, has_peak)
        known = self._vaos.get(key)
        if known is not None:
            return known
        programs = self._context.programs
        if ellipsoid:
            program = programs.get(
                ELLIPSOID_VERTEX_SHADER,
                ELLIPSOID_FRAGMENT_SHADER,
                {"HAS_TEMPERATURE": has_temperature, "COVERAGE": coverage, "HAS_PEAK": has_peak},
            )
        elif coverage:
            program = programs.get(COVERAGE_VERTEX_SHADER, COVERAGE_FRAGMENT_SHADER)
        else:
            sphere_defines = {"HAS_TEMPERATURE": True} if has_temperature else None
            if has_peak:
                sphere_defines = {"HAS_TEMPERATURE": True, "HAS_PEAK": True}
            program = programs.get(VERTEX_SHADER, FRAGMENT_SHADER, sphere_defines)
        vao = self._context.gl.ctx.vertex_array(
            program, [], index_buffer=self.buffers.index_buffer, index_element_size=4
        )
        self._vaos[key] = (program, vao)
        return program, vao

    def release(self) -> None:
        for _, vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        self._targets.release()
        self._band.release()
        self.buffers.release()


def _uniform_key(camera: Camera, batch: SplatBatch) -> tuple[object, ...]:
    """What `_particle_uniforms` depends on (not the batch itself: its host arrays would be
    compared element by element)."""
    return (
        camera,
        batch.far,
        batch.droplets,
        batch.has_temperature,
        batch.ellipsoid,
        batch.has_peak,
    )


def _particle_uniforms(
    program: moderngl.Program, camera: Camera, batch: SplatBatch, *, margin: float
) -> dict[str, object]:
    """The uniforms of common/splat_particles.glsl and the impostor's projection (u_use_ids and
    u_flag_mask are set per draw); the matrices are written here."""
    projection = lambda: camera.projection_matrix(batch.far)  # noqa: E731
    write_matrix(program, "u_projection", projection, (camera, batch.far))
    if batch.ellipsoid:
        write_matrix(program, "u_view_rotation", lambda: camera.rotation, camera)
    return {
        "u_class": -1.0 if batch.droplets else 1.0,
        "u_has_temperature": batch.has_temperature,
        "u_has_peak": batch.has_peak,
        "u_near": camera.near,
        "u_far": batch.far,
        "u_margin": margin,
    }


def _render(
    vao: moderngl.VertexArray,
    first: int,
    count: int,
    *,
    use_ids: bool,
    clock: GLClock,
    mask: int = 0,
) -> None:
    """Draw quads `first` .. `first + count` (ids[first ..] when `use_ids`; only particles
    with one of the device culling's flags in `mask`, when not 0)."""
    if count:
        set_if_used(vao.program, "u_use_ids", use_ids)
        set_if_used(vao.program, "u_flag_mask", mask)
        clock.call(vao.render, moderngl.TRIANGLES, vertices=6 * count, first=6 * first)


def _texture(target: Target | None) -> moderngl.Texture | None:
    return None if target is None else target.texture
