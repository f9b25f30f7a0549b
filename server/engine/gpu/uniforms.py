"""Uniform uploads that cost the render thread nothing when nothing changed.

A stream of frames of one scene sets the same values every frame; on a GPU, what the render
thread does per frame in Python is the frame time, so every uniform goes through the
cache kept in the program's `extra` dict (moderngl's slot for the user's data):

* `set_if_used(program, name, value)`: one uniform, written only when its value changed since
  this module last wrote it (and only when the compiled variant has it: the GLSL compiler drops
  unused ones);
* `set_group(program, group, key, values)`: the uniforms that are all a function of `key` (the
  scene, the camera, the image size, ...). When `key` equals the one this group was last set with,
  nothing is built or compared at all; otherwise `values()` is called and each uniform goes
  through `set_if_used`. A real write of any uniform of a group (say by another group sharing
  it) forgets that group's key, so a group can never skip over a value someone else changed;
* `write_matrix` / `write_array`: numpy matrices and arrays, cached by a caller's `key`.

Keys compare with ``==`` after identity: the same `Camera` or `Scene` object (both are cached or
reused while a stream's scene stays) matches without comparing its numpy fields; two different
objects that cannot be compared count as changed. A uniform set here must not also be written
directly (``program[name] = ...``), or the cache would be stale.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import moderngl
import numpy as np
import numpy.typing as npt

Program = moderngl.Program | moderngl.ComputeShader

#: Where in a program's cache the groups' keys and member names live.
_GROUPS = "\0groups"


def uses(program: Program, name: str) -> bool:
    """Whether the compiled variant has uniform `name`. `program.get`, not `name in program`:
    moderngl's Program has no __contains__, so `in` walks every member."""
    return program.get(name, None) is not None


def _cache(program: Program) -> dict[str, Any]:
    cache = program.extra
    if cache is None:
        cache = program.extra = {}
    return cache


def same(a: object, b: object) -> bool:
    """Equal cache keys or uniform values (numbers, bools, tuples; identical objects); anything
    that cannot be compared counts as changed."""
    if a is b:
        return True
    try:
        return type(a) is type(b) and bool(a == b)
    except (TypeError, ValueError):
        return False


def _forget_groups_with(cache: dict[str, Any], name: str) -> None:
    groups: dict[str, tuple[object, frozenset[str]]] | None = cache.get(_GROUPS)
    if groups:
        for group in [g for g, (_, names) in groups.items() if name in names]:
            del groups[group]


def set_if_used(program: Program, name: str, value: object) -> None:
    """Set uniform `name` if the variant uses it and its value changed since the last set."""
    cache = program.extra  # `_cache` inlined: this runs ~35 times a frame
    if cache is None:
        cache = _cache(program)
    old = cache.get(name, _MISSING)
    if old is value:
        return
    if old is not _MISSING:
        try:  # `same` inlined
            if type(old) is type(value) and old == value:
                return
        except (TypeError, ValueError):
            pass
    uniform = program.get(name, None)
    if uniform is not None:
        uniform.value = value  # type: ignore[union-attr]
    cache[name] = value
    _forget_groups_with(cache, name)


def set_group(
    program: Program, group: str, key: object, values: Callable[[], Mapping[str, object]]
) -> None:
    """Set the uniforms `values()` returns, all functions of `key`; nothing happens when this
    `group` of `program` was last set with the same `key`."""
    cache = program.extra
    if cache is None:
        cache = _cache(program)
    groups: dict[str, tuple[object, frozenset[str]]] | None = cache.get(_GROUPS)
    if groups is None:
        groups = cache[_GROUPS] = {}
    entry = groups.get(group)
    if entry is not None and (entry[0] is key or same(entry[0], key)):
        return
    uniforms = values()
    for name, value in uniforms.items():
        set_if_used(program, name, value)
    groups[group] = (key, frozenset(uniforms))


def write_matrix(
    program: Program, name: str, matrix: npt.NDArray[np.floating] | Callable[[], Any], key: object
) -> None:
    """Upload a row-major matrix to a GLSL matN uniform (GLSL is column-major) when `key`
    changed; `matrix` may be a callable building it, so an unchanged key builds nothing."""
    cache, slot = _cache(program), "\0matrix " + name
    if slot in cache and same(cache[slot], key):
        return
    uniform = _uniform(program, name)
    if uniform is not None:
        value = matrix() if callable(matrix) else matrix
        uniform.write(np.ascontiguousarray(np.asarray(value).T, dtype=np.float32).tobytes())
    cache[slot] = key  # after the write: a failed build leaves the key unknown


def write_array(program: Program, name: str, values: npt.ArrayLike, dtype: type) -> None:
    """Write `values` to the start of a uniform array (e.g. ``int u_offsets[8]``, ``ivec2
    u_dims[8]``) when they changed (tuples compare by value; arrays always count as changed);
    the compiler keeps only the elements it sees used, so the rows past `values` are padded
    with zeros."""
    cache, slot = _cache(program), "\0array " + name
    if slot in cache and same(cache[slot], values):
        return
    uniform = _uniform(program, name)
    if uniform is not None:
        array: npt.NDArray[Any] = np.asarray(values, dtype=dtype)
        rows = uniform.array_length
        padded = np.zeros((rows, *array.shape[1:]), dtype)
        padded[: min(rows, len(array))] = array[:rows]
        uniform.write(padded.tobytes())
    cache[slot] = values


def _uniform(program: Program, name: str) -> moderngl.Uniform | None:
    """The plain uniform `name`, None when the variant does not have it."""
    uniform = program.get(name, None)
    if uniform is None:
        return None
    assert isinstance(uniform, moderngl.Uniform), name
    return uniform


class _Missing:
    __slots__ = ()


_MISSING = _Missing()
