"""One frame of particles, as every reader returns it and the engine consumes it.

Validation lives here so the CLI, the readers and (later) the service reject bad arrays with the
same `InputError` naming the array and the offending index.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError, show

FloatArray = npt.NDArray[np.floating]

#: Hard upper bound on particles per frame accepted anywhere; the service may configure less.
MAX_PARTICLES = 50_000_000


@dataclass(frozen=True)
class ParticleFrame:
    """Particle arrays of one frame, validated, native-endian.

    positions: (N, 3) float64 (kept in float64 so scenes far from the origin lose nothing before
        the engine subtracts the camera position).
    densities: (N,) float32 kg/m^3, or None (the SPH pass computes them when a feature needs them).
    radii: (N,) float32 per-particle radii in scene units, or None (the scene's radius is used).
    temperatures: (N,) float32 kelvin, or None.
    velocities: (N, 3) float32 scene units per second, or None (motion blur when the camera's
        shutter is open).
    ids: (N,) int64 unique non-negative particle ids, or None (carried; the renderer ignores it;
        the service keeps each id's peak temperature when `peak_temperatures` is absent).
    peak_temperatures: (N,) float32 kelvin, the hottest each particle has been (the heat tint
        reads it), or None (the current temperature stands in); needs temperatures. A peak below
        the current temperature is taken as the current one (max of the two).
    solid: (N,) bool, True where the particle belongs to a solid workpiece, or None (the scene's
        `[solids] source` says what is solid then).
    """

    positions: npt.NDArray[np.float64]
    densities: npt.NDArray[np.float32] | None = None
    radii: npt.NDArray[np.float32] | None = None
    temperatures: npt.NDArray[np.float32] | None = None
    velocities: npt.NDArray[np.float32] | None = None
    ids: npt.NDArray[np.int64] | None = None
    peak_temperatures: npt.NDArray[np.float32] | None = None
    solid: npt.NDArray[np.bool_] | None = None

    @property
    def count(self) -> int:
        return int(self.positions.shape[0])


def _first_bad_index(mask: npt.NDArray[np.bool_]) -> int:
    return int(np.flatnonzero(mask)[0])


def _as_float_array(name: str, value: object, shape_tail: tuple[int, ...]) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype.kind not in "fiu":
        raise InputError(name, f"must be a numeric array, got dtype {show(array.dtype.str)}")
    expected = "(N, 3)" if shape_tail else "(N,)"
    if array.ndim != 1 + len(shape_tail) or tuple(array.shape[1:]) != shape_tail:
        raise InputError(name, f"must have shape {expected}, got {show(list(array.shape))}")
    return array


def make_frame(
    positions: object,
    densities: object | None = None,
    radii: object | None = None,
    temperatures: object | None = None,
    velocities: object | None = None,
    ids: object | None = None,
    peak_temperatures: object | None = None,
    solid: object | None = None,
    *,
    max_particles: int = MAX_PARTICLES,
) -> ParticleFrame:
    """Validate raw arrays and build a `ParticleFrame`.

    Raises `InputError` naming the array (and the first offending index) for: non-numeric dtypes,
    wrong shapes, mismatched lengths, more than `max_particles`, NaN/Inf anywhere, radii <= 0,
    densities <= 0, temperatures or peak_temperatures < 0, peak_temperatures without
    temperatures, velocities not (N, 3), ids not integers, negative or repeated, solid flags
    other than 0/1 (bool or integer). Zero particles is valid.
    """
    pos = _as_float_array("positions", positions, (3,))
    n = pos.shape[0]
    if n > max_particles:
        raise InputError("positions", f"{n} particles exceed the limit of {max_particles}")
    pos64 = pos.astype(np.float64, copy=False)
    finite = np.isfinite(pos64).all(axis=1)
    if not finite.all():
        raise InputError(
            f"positions[{_first_bad_index(np.logical_not(finite))}]",
            "must be finite (a row of 3 coordinates; found NaN or Infinity)",
        )

    def optional(name: str, value: object | None, low: float, inclusive: bool) -> np.ndarray | None:
        if value is None:
            return None
        arr = _as_float_array(name, value, ())
        if arr.shape[0] != n:
            raise InputError(name, f"has {arr.shape[0]} entries but positions has {n}")
        arr32 = arr.astype(np.float32)
        bad = ~np.isfinite(arr32)
        bad |= (arr32 < low) if inclusive else (arr32 <= low)
        if bad.any():
            i = _first_bad_index(bad)
            bound = f">= {low}" if inclusive else f"> {low}"
            raise InputError(f"{name}[{i}]", f"must be finite and {bound}, got {show(arr[i])}")
        return np.ascontiguousarray(arr32)

    vel = None
    if velocities is not None:
        vel = _as_float_array("velocities", velocities, (3,))
        if vel.shape[0] != n:
            raise InputError("velocities", f"has {vel.shape[0]} rows but positions has {n}")
        with np.errstate(over="ignore"):  # beyond float32's range becomes inf, refused below
            vel = np.ascontiguousarray(vel, dtype=np.float32)
        finite = np.isfinite(vel).all(axis=1)
        if not finite.all():
            raise InputError(
                f"velocities[{_first_bad_index(np.logical_not(finite))}]",
                "must be finite (a row of 3 components; found NaN or Infinity, or a value "
                "beyond float32's range)",
            )
    if peak_temperatures is not None and temperatures is None:
        raise InputError(
            "peak_temperatures", "needs temperatures in the same frame (the current kelvin)"
        )
    return ParticleFrame(
        positions=np.ascontiguousarray(pos64),
        densities=optional("densities", densities, 0.0, inclusive=False),
        radii=optional("radii", radii, 0.0, inclusive=False),
        temperatures=optional("temperatures", temperatures, 0.0, inclusive=True),
        velocities=vel,
        ids=None if ids is None else _checked_ids(ids, n),
        peak_temperatures=optional("peak_temperatures", peak_temperatures, 0.0, inclusive=True),
        solid=None if solid is None else _checked_solid(solid, n),
    )


def _checked_solid(value: object, n: int) -> npt.NDArray[np.bool_]:
    """(N,) flags: bool, or integers that are 0 or 1."""
    array = np.asarray(value)
    if array.dtype.kind not in "biu":
        raise InputError(
            "solid", f"must be a bool or integer array of 0 and 1, got dtype {array.dtype}"
        )
    if array.ndim != 1:
        raise InputError("solid", f"must have shape (N,), got {show(list(array.shape))}")
    if array.shape[0] != n:
        raise InputError("solid", f"has {array.shape[0]} entries but positions has {n}")
    if array.dtype.kind != "b":
        bad = (array != 0) & (array != 1)
        if bad.any():
            i = _first_bad_index(bad)
            raise InputError(f"solid[{i}]", f"must be 0 or 1, got {show(array[i])}")
    return np.ascontiguousarray(array != 0)


def _checked_ids(value: object, n: int) -> npt.NDArray[np.int64]:
    """(N,) int64 ids: integers, 0 <= id <= 2**63 - 1, no id twice."""
    array = np.asarray(value)
    if array.dtype.kind not in "iu":
        raise InputError("ids", f"must be an integer array, got dtype {array.dtype}")
    if array.ndim != 1:
        raise InputError("ids", f"must have shape (N,), got {show(list(array.shape))}")
    if array.shape[0] != n:
        raise InputError("ids", f"has {array.shape[0]} entries but positions has {n}")
    if not n:
        return np.zeros(0, np.int64)
    if array.dtype.kind == "i" and int(array.min()) < 0:
        i = _first_bad_index(array < 0)
        raise InputError(f"ids[{i}]", f"must be >= 0, got {show(array[i])}")
    top = int(array.max())
    if top > np.iinfo(np.int64).max:
        i = _first_bad_index(array == top)
        raise InputError(f"ids[{i}]", f"must be at most 2**63 - 1, got {top}")
    ids = np.ascontiguousarray(array, dtype=np.int64)
    if top < 8 * n:  # dense ids (the usual 0..N-1): a bitmap of <= 8 bytes a particle, O(N)
        seen = np.zeros(top + 1, np.bool_)
        seen[ids] = True
        unique = int(np.count_nonzero(seen)) == n
    else:
        ordered = np.sort(ids)
        unique = not bool((ordered[1:] == ordered[:-1]).any())
    if not unique:
        values, counts = np.unique(ids, return_counts=True)
        twice = values[counts > 1][0]
        where = np.flatnonzero(ids == twice)
        raise InputError(
            f"ids[{int(where[1])}]",
            f"must be unique: id {int(twice)} also appears at ids[{int(where[0])}]",
        )
    return ids
