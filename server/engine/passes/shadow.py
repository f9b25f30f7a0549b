"""The shadow pass: shadow maps of the lights that ask (``shadows = true``), made by splatting
the frame's particles as sphere impostors (the camera splat's radii) from each light.

Point and sphere lights get a cube map around the light (six 90 degree faces: no distortion of
the impostors, which a dual paraboloid would bend, and every direction covered, so a light
inside the cloud or behind the camera needs nothing special); a directional light gets an
orthographic map fitted to the particles' bounds (`geometry/shadow_frames.py`, float64 relative to
the particles' centre). Every map lives in one R32F atlas, one slot per shadowed light (a cube:
3 x 2 faces; an orthographic map: one square), written under MIN blending with no depth buffer:
each texel keeps the distance (cube) or depth (ortho) of the nearest sphere surface along its ray.
The shade pass reads them (`shaders/shadow/shadow_lookup.glsl`: PCSS). A scene with no shadowed
light never runs this pass and its shading program has no shadow code.

Owns: the programs (cube and ortho variants), the particle buffer (storage binding 25), the
quad index buffer, the atlas and its framebuffer.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.shadow_frames import (
    CUBE_FACES,
    ShadowSpheres,
    cube_frame,
    ortho_frame,
)
from sphrender.server.engine.gpu.uniforms import set_if_used, write_matrix
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.scene import MAX_LIGHTS, LightConfig, Scene

VERTEX_SHADER = "shadow/shadow_sphere.vert.glsl"
FRAGMENT_SHADER = "shadow/shadow_sphere.frag.glsl"
SPHERES_BINDING = 25
#: What an empty texel holds: no blocker at any distance.
NOTHING = 3.0e38
#: shadow_lookup.glsl's slot kinds.
CUBE, ORTHO = 1, 2


@dataclass(frozen=True)
class ShadowMaps:
    """The atlas and, per light of the scene (MAX_LIGHTS rows), the lookup's uniforms."""

    atlas: moderngl.Texture
    slot: npt.NDArray[np.float32]  # (MAX_LIGHTS, 4): kind, first row, side, depth bias
    #: (MAX_LIGHTS, 4): ortho origin (eye-relative); w: radius (cube), tan(angular radius) (ortho)
    light: npt.NDArray[np.float32]
    axes: npt.NDArray[np.float32]  # (MAX_LIGHTS, 3, 3): ortho world -> map axes, rows
    half: npt.NDArray[np.float32]  # (MAX_LIGHTS, 2): ortho half extents


def shadowed(scene: Scene) -> bool:
    return any(light.shadows for light in scene.lights)


def _slot_rows(light: LightConfig) -> int:
    return light.shadow_map_size * (1 if light.type == "directional" else 2)


class ShadowPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        ctx = context.gl.ctx
        self._spheres = ctx.buffer(reserve=16)
        self._indices = ctx.buffer(reserve=4)
        self._quads = 0
        self._count = 0
        self._vaos: dict[bool, moderngl.VertexArray] = {}
        self._atlas: tuple[moderngl.Texture, moderngl.Framebuffer] | None = None

    def check(self, scene: Scene) -> None:
        """Raise when the scene's shadow maps do not fit one texture of this GL."""
        width, height = self._atlas_size(scene)
        limit = self._context.gl.limits.max_texture_size
        if max(width, height) > limit:
            raise InputError(
                "lights",
                f"the shadow maps need a {width} x {height} texture, more than this GPU's "
                f"{limit}; use a smaller shadow_map_size or fewer lights with shadows",
            )

    def run(
        self, frame: ParticleFrame, scene: Scene, camera: Camera, reference_radius: float
    ) -> ShadowMaps:
        """Draw every shadowed light's map; `reference_radius` (the surface's typical particle
        radius) is the depth bias: the smoothed surface lies within it of the spheres' fronts."""
        self.check(scene)
        maps = ShadowMaps(
            self._atlas_for(scene),
            np.zeros((MAX_LIGHTS, 4), np.float32),
            np.zeros((MAX_LIGHTS, 4), np.float32),
            np.zeros((MAX_LIGHTS, 3, 3), np.float32),
            np.zeros((MAX_LIGHTS, 2), np.float32),
        )
        if frame.count == 0:
            return maps
        radii = (
            frame.radii
            if frame.radii is not None
            else np.full(frame.count, scene.particles.radius, np.float32)
        )
        spheres = ShadowSpheres.of(np.asarray(frame.positions, dtype=np.float64), radii)
        self._upload(spheres.spheres)
        row = 0
        for i, light in enumerate(scene.lights):
            if not light.shadows:
                continue
            size = light.shadow_map_size
            maps.slot[i] = (ORTHO if light.type == "directional" else CUBE, row, size, 0.0)
            maps.slot[i, 3] = reference_radius
            if light.type == "directional":
                assert light.direction is not None
                self._draw_ortho(maps, i, light, spheres, camera, row)
            else:
                assert light.position is not None
                frame_of = cube_frame(np.asarray(light.position, dtype=np.float64), spheres)
                self._draw_cube(frame_of.light, frame_of.near, frame_of.far, row, size)
                maps.light[i, 3] = light.radius if light.type == "sphere" else 0.0
            row += _slot_rows(light)
        return maps

    # -- drawing ---------------------------------------------------------------------------

    def _atlas_size(self, scene: Scene) -> tuple[int, int]:
        lights = [light for light in scene.lights if light.shadows]
        width = max((3 * light.shadow_map_size for light in lights), default=1)
        return width, max(sum(_slot_rows(light) for light in lights), 1)

    def _atlas_for(self, scene: Scene) -> moderngl.Texture:
        size = self._atlas_size(scene)
        if self._atlas is None or self._atlas[0].size != size:
            self._release_atlas()
            ctx = self._context.gl.ctx
            texture = ctx.texture(size, 1, dtype="f4")
            texture.filter = (moderngl.NEAREST, moderngl.NEAREST)
            texture.repeat_x = texture.repeat_y = False
            self._atlas = (texture, ctx.framebuffer([texture]))
        texture, fbo = self._atlas
        fbo.viewport = (0, 0, *size)
        with self._context.gl.clock:
            fbo.clear(NOTHING, 0.0, 0.0, 0.0)
        return texture

    def _upload(self, spheres: npt.NDArray[np.float32]) -> None:
        count = spheres.shape[0]
        if self._spheres.size < spheres.nbytes:
            self._spheres.orphan(spheres.nbytes)
        self._spheres.write(spheres.tobytes())
        if count > self._quads:
            quads = np.arange(count, dtype=np.uint32)[:, None] * 4
            indices = (quads + np.array([0, 1, 2, 2, 1, 3], dtype=np.uint32)).ravel()
            self._indices.orphan(indices.nbytes)
            self._indices.write(indices.tobytes())
            self._quads = count
        self._count = count

    def _vao(self, cube: bool) -> moderngl.VertexArray:
        vao = self._vaos.get(cube)
        if vao is None:
            program = self._context.programs.get(VERTEX_SHADER, FRAGMENT_SHADER, {"CUBE": cube})
            vao = self._context.gl.ctx.vertex_array(
                program, [], index_buffer=self._indices, index_element_size=4
            )
            set_if_used(program, "u_cube", cube)
            self._vaos[cube] = vao
        return vao

    def _draw(self, vao: moderngl.VertexArray, viewport: tuple[int, int, int, int]) -> None:
        assert self._atlas is not None
        fbo = self._atlas[1]
        fbo.viewport = viewport
        fbo.use()
        ctx = self._context.gl.ctx
        # Binding points are shared context state: claiming tells the other users to rebind.
        self._context.gl.claim_storage_bindings(self)
        self._spheres.bind_to_storage_buffer(SPHERES_BINDING)
        ctx.enable(moderngl.BLEND)
        ctx.blend_func = moderngl.ONE, moderngl.ONE
        ctx.blend_equation = moderngl.MIN  # type: ignore[assignment]  # the stub wants a pair
        try:
            self._context.gl.clock.call(vao.render, moderngl.TRIANGLES, vertices=6 * self._count)
        finally:
            ctx.blend_equation = moderngl.FUNC_ADD  # type: ignore[assignment]
            ctx.blend_func = moderngl.DEFAULT_BLENDING  # type: ignore[assignment]
            ctx.disable(moderngl.BLEND)

    def _draw_cube(
        self, light: npt.NDArray[np.float64], near: float, far: float, row: int, size: int
    ) -> None:
        vao = self._vao(True)
        program = vao.program
        set_if_used(program, "u_origin", tuple(float(x) for x in light))
        set_if_used(program, "u_near_far", (near, far))
        for face, rows in enumerate(CUBE_FACES):
            write_matrix(program, "u_face", rows, face)
            self._draw(vao, ((face % 3) * size, row + (face // 3) * size, size, size))

    def _draw_ortho(
        self,
        maps: ShadowMaps,
        i: int,
        light: LightConfig,
        spheres: ShadowSpheres,
        camera: Camera,
        row: int,
    ) -> None:
        assert light.direction is not None
        frame_of = ortho_frame(np.asarray(light.direction, dtype=np.float64), spheres)
        vao = self._vao(False)
        program = vao.program
        set_if_used(program, "u_origin", tuple(float(x) for x in frame_of.origin))
        set_if_used(program, "u_half_extent", frame_of.half_extent)
        write_matrix(program, "u_face", frame_of.axes, frame_of.axes.tobytes())
        size = light.shadow_map_size
        self._draw(vao, (0, row, size, size))
        maps.light[i, :3] = spheres.centre + frame_of.origin - camera.eye
        maps.axes[i] = frame_of.axes
        maps.half[i] = frame_of.half_extent
        maps.light[i, 3] = np.tan(np.radians(light.angular_radius_deg))

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        self._release_atlas()
        self._spheres.release()
        self._indices.release()

    def _release_atlas(self) -> None:
        if self._atlas is not None:
            self._atlas[1].release()
            self._atlas[0].release()
            self._atlas = None
