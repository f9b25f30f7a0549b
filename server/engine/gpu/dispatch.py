"""1-D compute dispatches over any number of items.

GL 4.3 guarantees only 65535 work groups per dispatch along x (GL_MAX_COMPUTE_WORK_GROUP_COUNT),
so a pass over more items than that many groups hold is split; each part tells the shader
where it starts through the `u_first` uniform (the shader adds it to gl_GlobalInvocationID.x
and checks the total itself).
"""

from __future__ import annotations

import math

import moderngl

from sphrender.server.engine.gpu.uniforms import set_if_used

#: The smallest GL_MAX_COMPUTE_WORK_GROUP_COUNT[0] GL 4.3 allows.
MAX_GROUPS = 65535


def dispatch_1d(shader: moderngl.ComputeShader, items: int, group_size: int) -> None:
    """Run `shader` (local size `group_size`) over `items` invocations, in parts of at most
    MAX_GROUPS groups, setting `u_first` for each. The caller times it and places barriers."""
    per_dispatch = group_size * MAX_GROUPS
    for first in range(0, items, per_dispatch):
        set_if_used(shader, "u_first", first)
        shader.run(group_x=math.ceil(min(per_dispatch, items - first) / group_size))
