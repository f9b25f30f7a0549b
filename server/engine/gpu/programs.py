"""Compiled GL programs, built once per (shader files, defines) and owned by one GL context.

Compile and link errors are re-raised as `ShaderCompileError` with line numbers translated back to
the original GLSL files (``smooth_depth.frag.glsl:42: error: ...``).
"""

from __future__ import annotations

from collections.abc import Mapping

import moderngl

from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.shader_loader import DefineValue, ShaderLoader
from sphrender.server.engine.gpu.uniforms import set_if_used


class ShaderCompileError(RuntimeError):
    """A GLSL program failed to compile or link; the message names file and line."""


class ProgramCache:
    def __init__(self, gl: GLContext, loader: ShaderLoader | None = None) -> None:
        self._gl = gl
        self._loader = loader or ShaderLoader()
        self._programs: dict[tuple[str, str, tuple[tuple[str, str], ...]], moderngl.Program] = {}
        self._compute: dict[str, moderngl.ComputeShader] = {}
        # Keyed by the defines' repr as the caller built them (one C call, insertion order
        # and value types included): the per-frame lookup, in front of the canonical key.
        self._by_repr: dict[tuple[str, str, str], moderngl.Program] = {}

    @property
    def built(self) -> int:
        """How many programs and compute shaders have been compiled (and are held)."""
        return len(self._programs) + len(self._compute)

    def get(
        self,
        vertex: str,
        fragment: str,
        defines: Mapping[str, DefineValue] | None = None,
        samplers: Mapping[str, int] | None = None,
    ) -> moderngl.Program:
        """The program of these shader files and defines. `samplers` (sampler uniform ->
        texture unit) are set once, when the program is built: a sampler's unit is part of
        the pass's code, not of its frame, so no frame pays for setting it again (callers
        that share a program must pass the same units: the first build's are kept)."""
        fast = (vertex, fragment, repr(defines) if defines else "")
        program = self._by_repr.get(fast)
        if program is not None:
            return program
        key = (vertex, fragment, tuple(sorted((k, repr(v)) for k, v in (defines or {}).items())))
        program = self._programs.get(key)
        if program is None:
            with self._gl.clock:  # compiling is the driver's work, not the frame's host work
                program = self._build(vertex, fragment, defines)
            self._programs[key] = program
            _bind_samplers(program, samplers)
        self._by_repr[fast] = program
        return program

    def compute(
        self, name: str, samplers: Mapping[str, int] | None = None
    ) -> moderngl.ComputeShader:
        """The compute shader `name` (GL 4.3), compiled on first use (`samplers`: as `get`)."""
        shader = self._compute.get(name)
        if shader is None:
            composed = self._loader.compose(name)
            try:
                with self._gl.clock:
                    shader = self._gl.ctx.compute_shader(composed.source)
            except moderngl.Error as exc:
                translated = self._loader.translate_compile_error(composed, str(exc))
                raise ShaderCompileError(f"{name}: {translated}") from None
            self._compute[name] = shader
            _bind_samplers(shader, samplers)
        return shader

    def _build(
        self, vertex: str, fragment: str, defines: Mapping[str, DefineValue] | None
    ) -> moderngl.Program:
        vs = self._loader.compose(vertex)
        fs = self._loader.compose(fragment, defines)
        try:
            return self._gl.ctx.program(vertex_shader=vs.source, fragment_shader=fs.source)
        except moderngl.Error as exc:
            log = str(exc)
            # moderngl's message holds the stage name and the driver log; translate both
            # stages' line numbers (only the failing stage's log is present).
            translated = self._loader.translate_compile_error(
                fs if "fragment_shader" in log else vs, log
            )
            raise ShaderCompileError(f"{vertex} + {fragment}: {translated}") from None

    def release(self) -> None:
        for program in self._programs.values():
            program.release()
        self._programs.clear()
        self._by_repr.clear()
        for shader in self._compute.values():
            shader.release()
        self._compute.clear()


def _bind_samplers(
    program: moderngl.Program | moderngl.ComputeShader, samplers: Mapping[str, int] | None
) -> None:
    """Point each sampler uniform at its texture unit (through the uniform cache, so a later
    `set_if_used` with the same unit writes nothing)."""
    for name, unit in (samplers or {}).items():
        set_if_used(program, name, unit)
