"""The shade pass: physically based metal under direct lights and image-based light, plus the
glow of hot metal (thesis chapter 4; `shaders/shade/shade_pbr.frag.glsl`, BRDF in
`common/brdf.glsl`, SH9 in `common/sh9.glsl`, GGX sampling in `common/sampling.glsl`).

`ShadePass` is owned by the `SurfaceRenderer` and runs on the GL owner thread. Per scene it
resolves the material, lights and environment; everything expensive (environment textures, SH,
prefiltered chain, BRDF table, blackbody table, programs) is built on first use and cached
(`IblCache`, `ProgramCache`), so a frame only sets uniforms and draws one full-screen triangle.
Only what the scene needs is built: no IBL resources with ``ibl_mode = "none"`` (unless the
background shows the environment), no prefiltered chain in sampled mode, no temperature target
or blackbody table without temperatures. Owns: the colour target, the blackbody table, the
`IblCache`, the brushed lobe's split-sum table (`AnisotropicLut`), the `EnvironmentLibrary` and
the surface-detail pass (`detail`; the renderer runs it after the normals and the solid's
compose, so the N AOV has the detail too).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import moderngl
import numpy as np

from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.screen_box import ScreenBox
from sphrender.server.engine.gpu.draw import PerSize, Target, clear_and_scissor, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used, uses, write_matrix
from sphrender.server.engine.lighting.anisotropic_lut import AnisotropicLut
from sphrender.server.engine.lighting.blackbody import TABLE_MAX_K, TABLE_MIN_K, blackbody_table
from sphrender.server.engine.lighting.environment import EnvironmentLibrary, rotation_about_y
from sphrender.server.engine.lighting.ibl import PREFILTER_LEVELS, EnvironmentTextures, IblCache
from sphrender.server.engine.lighting.lights import DIRECTIONAL, SPHERE, light_kind, light_radiance
from sphrender.server.engine.lighting.materials import resolve_material
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.shade_heat import FilmTables, heat_defines, heat_uniforms
from sphrender.server.engine.passes.shadow import ShadowMaps
from sphrender.server.engine.passes.surface_detail import (
    SurfaceDetailPass,
    detail_uniforms,
    set_image_texels,
    write_planes,
)
from sphrender.server.scene import MAX_LIGHTS, Scene

SHADER = "shade/shade_pbr.frag.glsl"
_IBL_DEFINES = {"none": 0, "prefiltered": 1, "sampled": 2}
_COMBINE_DEFINES = {"add": 0, "weighted": 1}
_VIEW_DEFINES = {
    "none": 0,
    "direct": 1,
    "diffuse_ibl": 2,
    "specular_ibl": 3,
    "emission": 4,
    "irradiance": 5,
}
_G_TERM_DEFINES = {"smith_height_correlated": 0, "cook_torrance": 1}


def _pattern_roughness(scene: Scene) -> bool:
    return scene.finish.detail != "none" and scene.finish.detail_roughness_strength > 0.0


def _image_roughness(scene: Scene) -> bool:
    return scene.finish.detail_image is not None and scene.finish.detail_image_roughness > 0.0


def _detail_roughness(scene: Scene) -> bool:
    return _pattern_roughness(scene) or _image_roughness(scene)


def _finish_uniforms(program: moderngl.Program, scene: Scene, camera: Camera) -> dict[str, object]:
    """The brushed lobe's and the roughness detail's uniforms (none when the scene has neither)."""
    finish = scene.finish
    values: dict[str, object] = {}
    if finish.anisotropy != 0.0:
        brush = np.asarray(finish.brush_direction, dtype=np.float64)
        values["u_brush_direction"] = tuple(float(c) for c in brush / np.linalg.norm(brush))
        values["u_anisotropy"] = finish.anisotropy
    if _detail_roughness(scene):
        values.update(detail_uniforms(finish, camera))
        write_planes(program, finish, camera.eye)
    return values


class ShadePass:
    def __init__(self, context: PassContext, environment_dirs: Sequence[str | Path] = ()) -> None:
        self._context = context
        self.environments = EnvironmentLibrary(environment_dirs)
        self.ibl = IblCache(context.gl, context.programs)
        self._anisotropic_lut = AnisotropicLut(context.gl, context.programs)
        self._blackbody: moderngl.Texture | None = None
        self._film = FilmTables(context)
        self._target = PerSize(lambda size: Target.float(context.gl.ctx, size, 4))
        #: The world-fixed surface detail on the normals, which this pass and the N AOV read.
        self.detail = SurfaceDetailPass(context, environment_dirs)

    def program_for(
        self, scene: Scene, has_temperature: bool, antialias: bool = False, shadows: bool = False
    ) -> moderngl.Program:
        shading = scene.shading
        return self._context.programs.get(
            FULLSCREEN_VERT,
            SHADER,
            {
                "IBL_MODE": _IBL_DEFINES[shading.ibl_mode],
                "COMBINE": _COMBINE_DEFINES[shading.combine],
                "HAS_TEMPERATURE": has_temperature,
                "MULTIPLE_SCATTERING": shading.multiple_scattering,
                "BACKGROUND_ENVIRONMENT": shading.background == "environment",
                "DEBUG_VIEW": _VIEW_DEFINES[shading.debug_view],
                "G_TERM": _G_TERM_DEFINES[shading.g_term],
                "MAX_LIGHTS": MAX_LIGHTS,
                "ANTIALIAS": antialias,
                **heat_defines(scene.material, has_temperature),
                "SPHERE_LIGHTS": any(light_kind(light) == SPHERE for light in scene.lights),
                "SHADOWS": shadows,
                "ANISOTROPIC": scene.finish.anisotropy != 0.0,
                "DETAIL_ROUGHNESS": _detail_roughness(scene),
                "DETAIL_PATTERN": _pattern_roughness(scene),
                "DETAIL_IMAGE": _image_roughness(scene),
            },
        )

    def _blackbody_texture(self) -> moderngl.Texture:
        if self._blackbody is None:
            table = blackbody_table()
            texture = self._context.gl.ctx.texture(
                (table.shape[0], 1), 4, table.tobytes(), dtype="f4"
            )
            texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            texture.repeat_x = texture.repeat_y = False
            self._blackbody = texture
        return self._blackbody

    def target(self, size: tuple[int, int]) -> Target:
        """The RGBA32F colour target for `size` (straight alpha = coverage)."""
        return self._target.get(size)

    def run(
        self,
        scene: Scene,
        camera: Camera,
        normal_depth: moderngl.Texture,
        temperature: moderngl.Texture | None,
        box: ScreenBox | None = None,
        coverage: moderngl.Texture | None = None,
        peak: moderngl.Texture | None = None,
        shadows: ShadowMaps | None = None,
    ) -> Target:
        """Shade `normal_depth` (world normal xyz, eye depth w) into the colour target;
        `temperature` (kelvin per pixel, already smoothed) adds the hot-metal glow. With a
        transparent background only `box` can be non-zero (the shader writes vec4(0) where
        there is no surface), so only `box` is shaded; an environment background covers every
        pixel. `coverage` (the splat's sub-pixel coverage) anti-aliases the silhouettes: alpha
        = coverage, and the pixels just outside show their neighbours' surface. `peak` (kelvin,
        smoothed) is the heat tint's peak temperature; without it the tint reads `temperature`.
        `shadows`: the shadow maps of the lights that cast shadows (passes/shadow.py)."""
        program = self.program_for(
            scene, temperature is not None, coverage is not None, shadows is not None
        )
        shading = scene.shading
        entry = None
        if shading.ibl_mode != "none" or shading.background == "environment":
            entry = self.ibl.environment(self.environments.resolve(scene.environment))
        # Textures are bound only after every resource exists: building one (prefiltering, the
        # BRDF table) runs passes of its own that rebind texture units.
        textures = self._textures(program, scene, entry, normal_depth, temperature, coverage)
        if temperature is not None and uses(program, "u_film_table"):
            textures += [
                ("u_film_table", self._film.texture(resolve_material(scene.material))),
                ("u_peak_temperature", peak if peak is not None else temperature),
            ]
        set_group(
            program,
            "scene",
            (scene, camera, entry),
            lambda: self._scene_uniforms(program, scene, camera, entry),
        )
        if shadows is not None:
            textures.append(("u_shadow_atlas", shadows.atlas))
            _set_shadows(program, shadows)
        for unit, (name, texture) in enumerate(textures):
            texture.use(unit)
            set_if_used(program, name, unit)
        if _image_roughness(scene):
            set_image_texels(program, self.detail.image_texture(scene.finish))
        target = self.target(normal_depth.size)
        clear_and_scissor(target.fbo, box if shading.background == "transparent" else None)
        target.fbo.use()
        self._context.fullscreen.draw(program)
        set_scissor(target.fbo, None)
        return target

    def _textures(
        self,
        program: moderngl.Program,
        scene: Scene,
        entry: EnvironmentTextures | None,
        normal_depth: moderngl.Texture,
        temperature: moderngl.Texture | None,
        coverage: moderngl.Texture | None,
    ) -> list[tuple[str, moderngl.Texture | moderngl.Texture3D]]:
        """The (sampler, texture) pairs the variant reads, resources built on first use."""
        shading = scene.shading
        wanted: list[tuple[str, moderngl.Texture | moderngl.Texture3D | None]] = [
            ("u_normal_depth", normal_depth),
            ("u_coverage", coverage),
        ]
        if entry is not None:
            wanted.append(("u_env_source", entry.source))
            if shading.ibl_mode == "prefiltered":
                prefiltered = self.ibl.prefiltered(entry, shading.prefilter_samples)
                wanted.append(("u_env_prefiltered", prefiltered))
        if shading.ibl_mode != "none" or shading.multiple_scattering:
            wanted.append(("u_brdf_lut", self.ibl.brdf_lut(shading.g_term)))
            if scene.finish.anisotropy != 0.0:
                wanted.append(("u_anisotropic_lut", self._anisotropic_lut.texture(shading.g_term)))
        if temperature is not None:
            wanted += [("u_temperature", temperature), ("u_blackbody", self._blackbody_texture())]
        if _image_roughness(scene):
            wanted.append(("u_detail_image", self.detail.image_texture(scene.finish).texture))
        return [(n, t) for n, t in wanted if t is not None and uses(program, n)]

    def _scene_uniforms(
        self,
        program: moderngl.Program,
        scene: Scene,
        camera: Camera,
        entry: EnvironmentTextures | None,
    ) -> dict[str, object]:
        """Every uniform that is a function of the scene and the camera; the matrices, arrays
        and lights are written here too (set_group calls this only when one of them changed)."""
        shading, material = scene.shading, resolve_material(scene.material)
        tan_y = camera.tan_half_fov_y
        values: dict[str, object] = {
            "u_tan_half_fov": (tan_y * camera.aspect, tan_y),
            "u_f0": material.specular_f0,
            "u_diffuse_albedo": material.diffuse_albedo,
            "u_roughness": material.roughness,
            "u_neighbour_reach": 1,  # shade_pbr.frag.glsl: a uniform, so its loops stay loops
            "u_direct_weight": shading.direct_weight,
            "u_blackbody_range": (TABLE_MIN_K, TABLE_MAX_K),
            "u_emissivity": material.normal_emissivity,
            "u_emission_scale": shading.emission_scale,
            **heat_uniforms(material),
        }
        write_matrix(program, "u_view_to_world", lambda: camera.rotation.T, camera)
        values.update(_finish_uniforms(program, scene, camera))
        if entry is not None:
            rotation = scene.environment.rotation_deg
            write_matrix(program, "u_world_to_env", lambda: rotation_about_y(rotation), rotation)
            values["u_env_intensity"] = scene.environment.intensity
            values["u_env_source_size"] = tuple(float(s) for s in entry.source_size)
            if uses(program, "u_sh"):
                program["u_sh"].write(entry.sh.astype(np.float32).tobytes())  # type: ignore[union-attr]
            values["u_prefiltered_max_lod"] = float(PREFILTER_LEVELS - 1)
            values["u_ibl_samples"] = shading.ibl_samples
        self._set_lights(program, scene, camera)
        return values

    def _set_lights(self, program: moderngl.Program, scene: Scene, camera: Camera) -> None:
        count = len(scene.lights)
        set_if_used(program, "u_light_count", count)
        if count == 0 or not uses(program, "u_light_type"):
            return
        types = np.zeros(MAX_LIGHTS, dtype=np.int32)
        vectors = np.zeros((MAX_LIGHTS, 3), dtype=np.float32)
        radiance = np.zeros((MAX_LIGHTS, 3), dtype=np.float32)
        radii = np.zeros(MAX_LIGHTS, dtype=np.float32)
        for i, light in enumerate(scene.lights):
            radiance[i] = light_radiance(light)
            types[i] = light_kind(light)
            radii[i] = light.radius
            if types[i] != DIRECTIONAL:
                assert light.position is not None
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
        if uses(program, "u_light_radius"):
            program["u_light_radius"].write(radii.tobytes())  # type: ignore[union-attr]

    def release(self) -> None:
        self._target.release()
        self.detail.release()
        self.ibl.release()
        self._anisotropic_lut.release()
        self._film.release()
        if self._blackbody is not None:
            self._blackbody.release()
            self._blackbody = None


def _set_shadows(program: moderngl.Program, shadows: ShadowMaps) -> None:
    """The shadow lookup's per-light uniforms (shadow/shadow_lookup.glsl), every frame: the
    orthographic maps follow the particles' bounds."""
    for name, values in (
        ("u_shadow_slot", shadows.slot),
        ("u_shadow_light", shadows.light),
        ("u_shadow_half", shadows.half),
        # GLSL matrices are column-major: the transposes of the rows.
        ("u_shadow_axes", np.ascontiguousarray(shadows.axes.transpose(0, 2, 1))),
    ):
        if uses(program, name):
            program[name].write(np.asarray(values, dtype=np.float32).tobytes())  # type: ignore[union-attr]
