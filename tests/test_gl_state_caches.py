"""The per-frame GL state the render thread skips when nothing changed (issue "GPU-ready frame"):
uniform values and groups (`gpu/uniforms.py`), and the storage-buffer bindings shared by the
splat, the display pass and other renderers on one context (`GLContext.claim_storage_bindings`).

A skipped write is only correct while the GL state still holds the value, so each test checks
the state the driver reports (``uniform.value``) or the image a frame makes, not the cache.
"""

from __future__ import annotations

from collections.abc import Iterator

import moderngl
import numpy as np
import pytest

from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.frame_output import DisplayRequest
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.uniforms import (
    same,
    set_group,
    set_if_used,
    write_array,
    write_matrix,
)
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.display import OETF8_THRESHOLDS
from sphrender.server.scene import CameraConfig, scene_from_dict

VERTEX = """#version 430 core
uniform float u_a;
uniform vec2 u_b;
uniform int u_c;
uniform mat3 u_m;
uniform int u_arr[4];
out vec4 v;
void main() {
    v = vec4(u_a, u_b, float(u_c)) + vec4(u_m[0], float(u_arr[0] + u_arr[1] + u_arr[3]));
    gl_Position = vec4(0.0);
}
"""
FRAGMENT = """#version 430 core
in vec4 v;
out vec4 colour;
void main() { colour = v; }
"""


@pytest.fixture
def program(gl_context: GLContext) -> Iterator[moderngl.Program]:
    program = gl_context.ctx.program(vertex_shader=VERTEX, fragment_shader=FRAGMENT)
    yield program
    program.release()


def value(program: moderngl.Program, name: str) -> object:
    uniform = program[name]
    assert isinstance(uniform, moderngl.Uniform)
    return uniform.value


def test_set_if_used_writes_changes_and_skips_repeats(program: moderngl.Program) -> None:
    set_if_used(program, "u_a", 1.5)
    assert value(program, "u_a") == 1.5
    program["u_a"] = 9.0  # behind the cache's back (the contract forbids it): shows the skip
    set_if_used(program, "u_a", 1.5)
    assert value(program, "u_a") == 9.0
    set_if_used(program, "u_a", 2.5)
    assert value(program, "u_a") == 2.5
    set_if_used(program, "u_not_in_this_variant", 3)  # dropped by the compiler: no error


def test_a_group_is_built_once_per_key(program: moderngl.Program) -> None:
    calls = []

    def values(scale: float) -> dict[str, object]:
        calls.append(scale)
        return {"u_a": scale, "u_b": (scale, 2 * scale), "u_c": 3}

    for _ in range(3):
        set_group(program, "g", ("key", 1.0), lambda: values(1.0))
    assert calls == [1.0]
    assert value(program, "u_b") == (1.0, 2.0)
    set_group(program, "g", ("key", 2.0), lambda: values(2.0))
    assert calls == [1.0, 2.0] and value(program, "u_b") == (2.0, 4.0)


def test_a_member_written_elsewhere_makes_its_group_rebuild(program: moderngl.Program) -> None:
    def values() -> dict[str, object]:
        return {"u_a": 1.0, "u_c": 4}

    set_group(program, "g", "k", values)
    set_group(program, "other", "k", lambda: {"u_b": (5.0, 6.0)})
    set_if_used(program, "u_c", 7)  # another path changes a member of "g"
    assert value(program, "u_c") == 7
    set_group(program, "g", "k", values)  # same key, but its value was overwritten
    assert value(program, "u_c") == 4
    program["u_b"] = (0.0, 0.0)  # not through the cache: "other" does not know (contract)
    set_group(program, "other", "k", lambda: {"u_b": (5.0, 6.0)})
    assert value(program, "u_b") == (0.0, 0.0)


def test_keys_holding_numpy_objects_compare_by_identity() -> None:
    config = CameraConfig(eye=(1.0, 2.0, 3.0), target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
    a, b = Camera.build(config, 64, 32), Camera.build(config, 64, 32)
    assert same((a, 1.0), (a, 1.0))
    assert not same((a, 1.0), (b, 1.0))  # equal cameras, other objects: rebuilt, never raises
    assert Camera.from_config(config, 64, 32) is Camera.from_config(config, 64, 32)


def test_matrices_are_written_column_major_once_per_key(program: moderngl.Program) -> None:
    m = np.arange(9, dtype=np.float64).reshape(3, 3)  # row-major: m[row, column]
    built = []

    def build() -> np.ndarray:
        built.append(1)
        return m

    write_matrix(program, "u_m", build, "k")
    write_matrix(program, "u_m", build, "k")
    assert built == [1]
    # GLSL reports mat3 as columns one after the other: column j = m[:, j].
    assert value(program, "u_m") == pytest.approx(tuple(m.T.ravel()))


def test_arrays_are_padded_and_cached(program: moderngl.Program) -> None:
    write_array(program, "u_arr", (3, 4), np.int32)
    assert value(program, "u_arr") == [3, 4, 0, 0]
    program["u_arr"] = [9, 9, 9, 9]
    write_array(program, "u_arr", (3, 4), np.int32)  # unchanged: skipped
    assert value(program, "u_arr") == [9, 9, 9, 9]
    write_array(program, "u_arr", (1, 2, 3, 4, 5), np.int32)  # longer than the array: cut
    assert value(program, "u_arr") == [1, 2, 3, 4]


def test_storage_claims(gl_context: GLContext) -> None:
    first, second = object(), object()
    gl_context.claim_storage_bindings(first)
    assert not gl_context.claim_storage_bindings(first)
    assert gl_context.claim_storage_bindings(second)
    assert gl_context.claim_storage_bindings(first)
    gl_context.storage_bindings_disturbed(first)  # its own binding: its claim stands
    assert not gl_context.claim_storage_bindings(first)
    gl_context.storage_bindings_disturbed(second)  # someone else's: nobody's claim stands
    assert gl_context.claim_storage_bindings(first)
    gl_context.release_storage_claim(first)
    assert gl_context.claim_storage_bindings(first)


def test_frames_keep_their_image_between_display_passes_and_other_renderers(
    gl_context: GLContext,
) -> None:
    """The display pass binds its table at binding 0 (the splat's spheres) and a second
    renderer on the context binds all of them: the next frame must rebind, or it would read
    the other's buffers. Every frame here equals the first render of its own scene."""
    scene = scene_from_dict(
        {
            "image": {"width": 96, "height": 64},
            "camera": {"eye": [0.5, 0.35, 0.6], "fov_y": 40.0},
            "particles": {"radius": 0.01},
        }
    )
    small = make_frame(jittered_lattice_ball(0.08, 0.01))
    large = make_frame(jittered_lattice_ball(0.12, 0.01) + 0.03)
    request = DisplayRequest(0.0, "aces", OETF8_THRESHOLDS)
    one = SurfaceRenderer(gl_context, prepare="device")
    two = SurfaceRenderer(gl_context, prepare="device")
    try:
        want_small = one.render(small, scene, depth=True)[0].depth
        want_large = two.render(large, scene, depth=True)[0].depth
        for _ in range(2):
            for renderer, frame, want in ((one, small, want_small), (two, large, want_large)):
                got, _ = renderer.render(frame, scene, depth=True, display=request)
                np.testing.assert_array_equal(got.depth, want)
                got, _ = renderer.render(frame, scene, depth=True)
                np.testing.assert_array_equal(got.depth, want)
    finally:
        one.release()
        two.release()


def test_values_that_cannot_be_compared_are_written(program: moderngl.Program) -> None:
    """A numpy array's == is elementwise (its truth value raises): it counts as changed."""
    set_if_used(program, "u_b", np.array([1.0, 2.0]))
    set_if_used(program, "u_b", np.array([3.0, 4.0]))
    assert value(program, "u_b") == (3.0, 4.0)
    set_if_used(program, "u_a", 2.0)
    program["u_a"] = 5.0  # behind the cache's back, as above
    set_if_used(program, "u_a", 2)  # equal but of another type: written
    assert value(program, "u_a") == 2.0
