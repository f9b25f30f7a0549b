"""Accumulate pass: the average of a motion-blurred frame's sub-frames (geometry/motion.py), on
the GPU. Each sub-frame's shaded colour is added to a running premultiplied sum weighted 1/N
(ping-pong targets); the last one writes the average as straight RGBA, the colour target every
later pass (glare, read-back, display) expects.

Owns: its program variants (through the ProgramCache) and three float targets per image size.
"""

from __future__ import annotations

import moderngl

from sphrender.server.engine.gpu.draw import PerSize, Target
from sphrender.server.engine.gpu.uniforms import set_if_used
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext

SHADER = "motion/accumulate.frag.glsl"


class _Targets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.sums = (Target.float(ctx, size, 4), Target.float(ctx, size, 4))
        self.average = Target.float(ctx, size, 4)

    def release(self) -> None:
        for target in (*self.sums, self.average):
            target.release()


class AccumulatePass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _Targets(context.gl.ctx, size))

    def add(self, color: Target, index: int, count: int) -> Target | None:
        """Add sub-frame `index` of `count`; the average (straight RGBA) after the last, else
        None."""
        targets = self._targets.get(color.texture.size)
        first, last = index == 0, index == count - 1
        defines = {"FIRST": first, "LAST": last}
        program = self._context.programs.get(
            FULLSCREEN_VERT, SHADER, defines, {"u_color": 0, "u_sum": 1}
        )
        set_if_used(program, "u_weight", 1.0 / count)
        color.texture.use(0)
        targets.sums[(index + 1) % 2].texture.use(1)
        out = targets.average if last else targets.sums[index % 2]
        out.fbo.use()
        self._context.fullscreen.draw(program)
        return targets.average if last else None

    def release(self) -> None:
        self._targets.release()
