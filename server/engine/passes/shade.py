"""The shade pass: physically based metal under direct lights and image-based light, plus the
glow of hot metal (thesis chapter 4; `shaders/shade_pbr.frag.glsl`).

`ShadePass` is owned by the `SurfaceRenderer` and runs on the GL owner thread. Per scene it
resolves the material, lights and environment; everything expensive (environment textures, SH,
prefiltered chain, BRDF table, blackbody table, programs) is built on first use and cached
(`IblCache`, `ProgramCache`), so a frame only sets uniforms and draws one full-screen triangle.
Only what the scene needs is built: no IBL resources with ``ibl_mode = "none"`` (unless the
background shows the environment), no prefiltered chain in sampled mode, no temperature target
or blackbody table without temperatures.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import moderngl
import numpy as np
import numpy.typing as npt

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.lighting.blackbody import TABLE_MAX_K, TABLE_MIN_K, blackbody_table
from sphrender.server.engine.lighting.environment import EnvironmentLibrary, rotation_about_y
from sphrender.server.engine.lighting.ibl import PREFILTER_LEVELS, IblCache
from sphrender.server.engine.lighting.materials import resolve_material
from sphrender.server.scene import MAX_LIGHTS, Scene

_IBL_DEFINES = {"none": 0, "prefiltered": 1, "sampled": 2}
_COMBINE_DEFINES = {"add": 0, "eq55": 1}
_VIEW_DEFINES = {
    "none": 0,
    "direct": 1,
    "diffuse_ibl": 2,
    "specular_ibl": 3,
    "emission": 4,
    "irradiance": 5,
}
_G_TERM_DEFINES = {"smith_height_correlated": 0, "eq37": 1}
#: Temperature blur: sigma in projected particle radii, kernel cap, and the depth window (in
#: particle radii) outside which samples belong to another surface.
TEMPERATURE_SIGMA_RADII = 2.0
TEMPERATURE_MAX_REACH_PX = 24
TEMPERATURE_DEPTH_RANGE_RADII = 4.0


def write_matrix(program: moderngl.Program, name: str, matrix: npt.NDArray[np.floating]) -> None:
    """Upload a row-major numpy matrix to a GLSL matN uniform (GLSL is column-major)."""
    uniform = program[name]
    assert isinstance(uniform, moderngl.Uniform), name
    uniform.write(np.ascontiguousarray(matrix.T, dtype=np.float32).tobytes())


def _set(program: moderngl.Program, name: str, value: object) -> None:
    """Set a uniform if the compiled variant uses it (GLSL drops unused ones)."""
    if name in program:
        program[name] = value


class _BlurTargets:
    """Targets of the temperature blur for one image size: the packed depth guide, two packed
    kelvin images (ping-pong) and the unpacked result."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.size = size
        packed_size = ((size[0] + 3) // 4, size[1])

        def texture(texture_size: tuple[int, int], components: int) -> moderngl.Texture:
            result = ctx.texture(texture_size, components, dtype="f4")
            result.filter = (moderngl.NEAREST, moderngl.NEAREST)
            return result

        self.packed_depth = texture(packed_size, 4)
        self.packed_depth_fbo = ctx.framebuffer([self.packed_depth])
        self.packed = [texture(packed_size, 4) for _ in range(2)]
        self.packed_fbos = [ctx.framebuffer([t]) for t in self.packed]
        self.result = texture(size, 1)
        self.result_fbo = ctx.framebuffer([self.result])

    def release(self) -> None:
        for fbo in (self.packed_depth_fbo, *self.packed_fbos, self.result_fbo):
            fbo.release()
        for texture in (self.packed_depth, *self.packed, self.result):
            texture.release()


class ShadePass:
    def __init__(
        self,
        gl: GLContext,
        programs: ProgramCache,
        environment_dirs: Sequence[str | Path] = (),
    ) -> None:
        self._gl = gl
        self._programs = programs
        self.environments = EnvironmentLibrary(environment_dirs)
        self.ibl = IblCache(gl, programs)
        self._blackbody: moderngl.Texture | None = None
        self._vaos: dict[int, moderngl.VertexArray] = {}
        # Targets of the temperature blur, rebuilt only when the image size changes.
        self._blur: _BlurTargets | None = None

    def program_for(self, scene: Scene, has_temperature: bool) -> moderngl.Program:
        shading = scene.shading
        return self._programs.get(
            "common/fullscreen.vert.glsl",
            "shade/shade_pbr.frag.glsl",
            {
                "IBL_MODE": _IBL_DEFINES[shading.ibl_mode],
                "COMBINE": _COMBINE_DEFINES[shading.combine],
                "HAS_TEMPERATURE": has_temperature,
                "MULTIPLE_SCATTERING": shading.multiple_scattering,
                "BACKGROUND_ENVIRONMENT": shading.background == "environment",
                "DEBUG_VIEW": _VIEW_DEFINES[shading.debug_view],
                "G_TERM": _G_TERM_DEFINES[shading.g_term],
                "MAX_LIGHTS": MAX_LIGHTS,
            },
        )

    def _blackbody_texture(self) -> moderngl.Texture:
        if self._blackbody is None:
            table = blackbody_table()
            texture = self._gl.ctx.texture((table.shape[0], 1), 4, table.tobytes(), dtype="f4")
            texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            texture.repeat_x = texture.repeat_y = False
            self._blackbody = texture
        return self._blackbody

    def _vao(self, program: moderngl.Program) -> moderngl.VertexArray:
        vao = self._vaos.get(program.glo)
        if vao is None:
            vao = self._gl.ctx.vertex_array(program, [])
            self._vaos[program.glo] = vao
        return vao

    def _blur_targets(self, size: tuple[int, int]) -> _BlurTargets:
        if self._blur is None or self._blur.size != size:
            if self._blur is not None:
                self._blur.release()
            self._blur = _BlurTargets(self._gl.ctx, size)
        return self._blur

    def smooth_temperature(
        self,
        temperature: moderngl.Texture,
        depth: moderngl.Texture,
        px_per_unit: float,
        particle_radius: float,
    ) -> moderngl.Texture:
        """Depth-aware separable blur of the splatted temperature (`smooth_temperature.frag`),
        on packed images: pack depth and kelvin, blur along x then y, unpack; sigma =
        TEMPERATURE_SIGMA_RADII projected particle radii. `px_per_unit`: pixels per scene unit
        at eye depth 1 (`Camera.pixels_per_unit_at_unit_depth`)."""
        blur = self._blur_targets(temperature.size)
        programs = self._programs
        pack = programs.get("common/fullscreen.vert.glsl", "common/image_pack.frag.glsl")
        pack["u_image"] = 0
        for source, target in ((depth, blur.packed_depth_fbo), (temperature, blur.packed_fbos[0])):
            source.use(0)
            target.use()
            self._vao(pack).render(moderngl.TRIANGLES, vertices=3)
        blur.packed_depth.use(1)
        for axis in (0, 1):
            program = programs.get(
                "common/fullscreen.vert.glsl",
                "temperature/smooth_temperature.frag.glsl",
                {"AXIS": axis},
            )
            program["u_radius_px_at_unit_depth"] = particle_radius * px_per_unit
            program["u_sigma_radii"] = TEMPERATURE_SIGMA_RADII
            program["u_max_reach_px"] = TEMPERATURE_MAX_REACH_PX
            program["u_depth_range"] = TEMPERATURE_DEPTH_RANGE_RADII * particle_radius
            program["u_packed_temperature"] = 0
            program["u_packed_depth"] = 1
            blur.packed[axis].use(0)
            blur.packed_fbos[1 - axis].use()
            self._vao(program).render(moderngl.TRIANGLES, vertices=3)
        unpack = programs.get("common/fullscreen.vert.glsl", "common/image_unpack.frag.glsl")
        unpack["u_packed"] = 0
        blur.packed[0].use(0)
        blur.result_fbo.use()
        self._vao(unpack).render(moderngl.TRIANGLES, vertices=3)
        return blur.result

    def run(
        self,
        scene: Scene,
        camera: Camera,
        normal_depth: moderngl.Texture,
        temperature: moderngl.Texture | None,
        target: moderngl.Framebuffer,
    ) -> None:
        """Shade `normal_depth` (world normal xyz, eye depth w) into `target`; `temperature`
        (kelvin per pixel, already smoothed) adds the hot-metal glow."""
        program = self.program_for(scene, temperature is not None)
        shading = scene.shading
        # Textures are bound only after every resource exists: building one (prefiltering, the
        # BRDF table) runs passes of its own that rebind texture units.
        textures: list[tuple[str, moderngl.Texture]] = []

        def bind(name: str, texture: moderngl.Texture) -> None:
            if name in program:
                textures.append((name, texture))

        bind("u_normal_depth", normal_depth)
        _set(
            program,
            "u_tan_half_fov",
            (camera.tan_half_fov_y * camera.aspect, camera.tan_half_fov_y),
        )
        if "u_view_to_world" in program:
            write_matrix(program, "u_view_to_world", camera.rotation.T)

        material = resolve_material(scene.material)
        _set(program, "u_f0", material.specular_f0)
        _set(program, "u_diffuse_albedo", material.diffuse_albedo)
        _set(program, "u_roughness", material.roughness)
        self._set_lights(program, scene, camera)

        needs_environment = shading.ibl_mode != "none" or shading.background == "environment"
        if needs_environment:
            image = self.environments.resolve(scene.environment)
            entry = self.ibl.environment(image)
            world_to_env = rotation_about_y(scene.environment.rotation_deg)
            if "u_world_to_env" in program:
                write_matrix(program, "u_world_to_env", world_to_env)
            _set(program, "u_env_intensity", scene.environment.intensity)
            bind("u_env_source", entry.source)
            _set(program, "u_env_source_size", tuple(float(s) for s in entry.source_size))
            if "u_sh" in program:
                program["u_sh"].write(entry.sh.astype(np.float32).tobytes())  # type: ignore[union-attr]

            if shading.ibl_mode == "prefiltered":
                bind("u_env_prefiltered", self.ibl.prefiltered(entry, shading.prefilter_samples))
                _set(program, "u_prefiltered_max_lod", float(PREFILTER_LEVELS - 1))
            _set(program, "u_ibl_samples", shading.ibl_samples)
        if shading.ibl_mode != "none" or shading.multiple_scattering:
            bind("u_brdf_lut", self.ibl.brdf_lut(shading.g_term))
        _set(program, "u_eq55_k", shading.eq55_k)

        if temperature is not None:
            bind("u_temperature", temperature)
            bind("u_blackbody", self._blackbody_texture())
            _set(program, "u_blackbody_range", (TABLE_MIN_K, TABLE_MAX_K))
            _set(program, "u_emissivity", material.normal_emissivity)
            _set(program, "u_emission_scale", shading.emission_scale)

        for unit, (name, texture) in enumerate(textures):
            texture.use(unit)
            program[name] = unit
        target.use()
        self._vao(program).render(moderngl.TRIANGLES, vertices=3)

    def _set_lights(self, program: moderngl.Program, scene: Scene, camera: Camera) -> None:
        count = len(scene.lights)
        _set(program, "u_light_count", count)
        if count == 0 or "u_light_type" not in program:
            return
        types = np.zeros(MAX_LIGHTS, dtype=np.int32)
        vectors = np.zeros((MAX_LIGHTS, 3), dtype=np.float32)
        radiance = np.zeros((MAX_LIGHTS, 3), dtype=np.float32)
        for i, light in enumerate(scene.lights):
            radiance[i] = np.asarray(light.color) * light.intensity
            if light.type == "point":
                assert light.position is not None
                types[i] = 1
                # float64 subtraction first: a light at 1e5 near a surface at 1e5 keeps its
                # millimetres (the same rule as the particles).
                vectors[i] = np.asarray(light.position, dtype=np.float64) - camera.eye
            else:
                assert light.direction is not None
                travel = np.asarray(light.direction, dtype=np.float64)
                vectors[i] = -travel / np.linalg.norm(travel)
        program["u_light_type"].write(types.tobytes())  # type: ignore[union-attr]
        program["u_light_vector"].write(vectors.tobytes())  # type: ignore[union-attr]
        program["u_light_radiance"].write(radiance.tobytes())  # type: ignore[union-attr]

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        if self._blur is not None:
            self._blur.release()
            self._blur = None
        self.ibl.release()
        if self._blackbody is not None:
            self._blackbody.release()
            self._blackbody = None
