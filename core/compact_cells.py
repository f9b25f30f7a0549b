"""The order-free position coding of the compact encoding (PROTOCOL.md §4.7, ``predict:
"cells"``): particles sorted into grid cells, the occupied cells sent as gaps, the particles'
offsets inside their cells as byte planes.

Particle order carries no meaning for rendering, and an ordered array pays about log2(N / e)
bits a particle to say it. Here quantised positions ``q`` are split per axis into a cell
coordinate ``q >> k`` and an offset ``q & (2^k - 1)``; cells are numbered x-major with each
axis's coordinate in ``grid_bits`` bits; particles go out in cell order (every other array of
the frame permuted with them). The section inflates to: the gaps between the occupied cells'
numbers (``cells`` values, ``width`` bytes each), their particle counts (``count_width`` bytes,
only when fewer cells than particles) and the offsets (3 x N values, ``ceil(k / 8)`` bytes),
each as byte planes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError, show
from sphrender.core.scratch import Allocate, Lease

__all__ = ["CELLS", "CellLayout", "cells_layout", "decode_cells", "encode_cells"]

#: The ``predict`` value of this coding.
CELLS = "cells"
#: Largest cell size, in bits of quanta per axis.
MAX_CELL_BITS = 16
#: Largest cell number's bits (x, y and z together): the numbers and their sums fit int64.
MAX_GRID_BITS = 62
_WIDTHS = (1, 2, 4, 8)


@dataclass(frozen=True)
class CellLayout:
    """A ``cells`` array's layout, as its descriptor declares it."""

    cell_bits: int
    grid_bits: tuple[int, int, int]
    cells: int
    width: int
    count_width: int

    def raw_size(self, particles: int) -> int:
        counts = self.cells * self.count_width if self.cells < particles else 0
        return self.cells * self.width + counts + 3 * particles * self.offset_width

    @property
    def offset_width(self) -> int:
        return (self.cell_bits + 7) // 8


def _small_int(where: str, value: Any, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise InputError(where, f"must be an integer from {low} to {high}, got {show(value)}")
    return value


def cells_layout(where: str, spec: Mapping[str, Any], particles: int) -> CellLayout:
    """Check a ``cells`` descriptor's keys against its particle count (before any inflating)."""
    k = _small_int(f"{where}.cell_bits", spec.get("cell_bits"), 1, MAX_CELL_BITS)
    grid = spec.get("grid_bits")
    if not isinstance(grid, list) or len(grid) != 3:
        raise InputError(f"{where}.grid_bits", f"must be 3 integers, got {show(grid)}")
    bits = tuple(_small_int(f"{where}.grid_bits[{a}]", b, 0, 52 - k) for a, b in enumerate(grid))
    if sum(bits) > MAX_GRID_BITS:
        raise InputError(f"{where}.grid_bits", f"sum to {sum(bits)}, at most {MAX_GRID_BITS}")
    cells = _small_int(f"{where}.cells", spec.get("cells"), min(particles, 1), particles)
    width = spec.get("width")
    if width not in _WIDTHS or isinstance(width, bool):
        raise InputError(f"{where}.width", f"must be 1, 2, 4 or 8, got {show(width)}")
    count_width = 0
    if cells < particles:
        given = spec.get("count_width")
        if given not in _WIDTHS or isinstance(given, bool):
            raise InputError(
                f"{where}.count_width",
                f"must be 1, 2, 4 or 8 when cells < particles, got {show(given)}",
            )
        count_width = int(given)
    elif "count_width" in spec:
        raise InputError(f"{where}.count_width", "is only for fewer cells than particles")
    return CellLayout(k, (bits[0], bits[1], bits[2]), cells, width, count_width)


def _planes(values: np.ndarray, width: int) -> bytes:
    if width == 1:
        return np.ascontiguousarray(values, dtype=np.uint8).tobytes()
    flat = np.ascontiguousarray(values).reshape(-1).astype(np.uint64, copy=False)
    planes = np.empty((width, flat.size), np.uint8)
    for b in range(width):
        planes[b] = flat >> np.uint64(8 * b)
    return planes.tobytes()


def _unplanes(data: memoryview, count: int, width: int, scratch: Lease | None) -> np.ndarray:
    planes = np.frombuffer(data, np.uint8, count * width).reshape(width, count)
    if width == 1:
        return planes[0]  # a view of the section: nothing to combine
    values = _empty(scratch, count, np.dtype(f"=u{width}"))
    values[...] = planes[width - 1]
    for b in range(width - 2, -1, -1):
        values <<= 8
        values |= planes[b]
    return values


def _empty(scratch: Lease | None, shape: int, dtype: npt.DTypeLike) -> np.ndarray:
    return np.empty(shape, dtype) if scratch is None else scratch.array(shape, dtype)


def _width(top: int) -> int:
    return next(w for w in _WIDTHS if top < 1 << (8 * w))


def _order(number: np.ndarray, q: np.ndarray, cell_bits: int, grid_bits: int) -> np.ndarray:
    """Particles by cell number, then by position inside the cell: the same particles come out
    in the same order whatever order they were given in (a solid's surfel cache keys on it).
    Where a combined key fits 63 bits, its stable radix sort (equal keys are equal positions and
    keep the order given)."""
    bits = grid_bits + 3 * cell_bits
    if bits > 63:
        return np.lexsort((q[2], q[1], q[0], number))
    key = number << (3 * cell_bits)
    mask = (1 << cell_bits) - 1
    for axis, shift in ((0, 2 * cell_bits), (1, cell_bits), (2, 0)):
        key |= (q[axis] & mask) << shift
    return _radix_argsort(key, bits)


def _radix_argsort(key: np.ndarray, bits: int) -> np.ndarray:
    """Indices that sort `key` (int64, 0 to 2^bits - 1), ties in the order given: numpy's
    stable argsort of 16-bit integers is a radix sort, so one pass per 16 bits, lowest first."""
    order: np.ndarray | None = None
    for shift in range(0, bits, 16):
        digits = (key if order is None else key[order]) >> shift
        step = np.argsort(digits.astype(np.uint16), kind="stable")
        order = step if order is None else order[step]
    return np.arange(len(key)) if order is None else order


def encode_cells(q: np.ndarray, cell_bits: int) -> tuple[np.ndarray, dict[str, Any], bytes] | None:
    """(order, descriptor keys, inflated section) for quantised positions `q` (3, N) int64, or
    None when the cell numbers would not fit `MAX_GRID_BITS`. ``order[j]`` is the particle sent
    j-th (the caller gathers ``q[:, order]`` once it has chosen this coding)."""
    n = q.shape[1]
    cell = q >> cell_bits
    top = cell.max(axis=1) if n else np.zeros(3, np.int64)
    bits = [int(v).bit_length() for v in top]
    if sum(bits) > MAX_GRID_BITS or max(bits) > 52 - cell_bits:
        return None
    number = cell[0] << (bits[1] + bits[2])
    number |= cell[1] << bits[2]
    number |= cell[2]
    order = _order(number, q, cell_bits, sum(bits))
    ranked = number[order]
    starts = np.flatnonzero(np.diff(ranked, prepend=-1))  # each occupied cell's first particle
    occupied = ranked[starts]
    counts = np.diff(starts, append=n)
    gaps = np.diff(occupied, prepend=0)
    spec: dict[str, Any] = {
        "predict": CELLS,
        "cell_bits": cell_bits,
        "grid_bits": bits,
        "cells": len(occupied),
        "width": _width(int(gaps.max()) if n else 0),
    }
    sections = [_planes(gaps, spec["width"])]
    if len(occupied) < n:
        spec["count_width"] = _width(int(counts.max()))
        sections.append(_planes(counts, spec["count_width"]))
    offsets = np.empty((3, n), np.uint8 if cell_bits <= 8 else np.uint16)
    for axis in range(3):
        np.bitwise_and(q[axis][order], (1 << cell_bits) - 1, out=offsets[axis], casting="unsafe")
    sections.append(_planes(offsets, (cell_bits + 7) // 8))
    return order, spec, b"".join(sections)


def decode_cells(
    layout: CellLayout,
    index: int,
    raw: Any,
    particles: int,
    scratch: Lease | None = None,
    keep: Allocate = np.empty,
) -> np.ndarray:
    """The quantised positions (3, N) of an inflated ``cells`` section, in the order sent: int32
    where every cell number and coordinate fits 31 bits, else int64; every value is checked
    except against the upper bounds (the caller's range check). Temporaries from `scratch`
    when given, the result from `keep`."""
    where = f"arrays[{index}]"
    view = memoryview(raw)
    m, k = layout.cells, layout.cell_bits
    gaps = _unplanes(view, m, layout.width, scratch)
    at = m * layout.width
    total_bits = sum(layout.grid_bits)
    if m and float(gaps.sum(dtype=np.float64)) >= 2.0**total_bits:
        raise InputError(f"{where}.cells", f"gaps sum past the grid's {total_bits} bits")
    narrow = total_bits <= 31 and max(layout.grid_bits) + k <= 31
    dtype = np.int32 if narrow else np.int64
    if m < particles:
        counts = _unplanes(view[at:], m, layout.count_width, scratch)
        at += m * layout.count_width
        if counts.min() < 1 or int(counts.sum(dtype=np.uint64)) != particles:
            raise InputError(
                f"{where}.cells", f"counts must each be >= 1 and sum to {particles} particles"
            )
        number = _spread(gaps, counts, particles, dtype, scratch)  # sums checked: no wrap
    else:
        number = np.cumsum(gaps, dtype=dtype, out=_empty(scratch, m, dtype))
    offsets = _unplanes(view[at:], 3 * particles, layout.offset_width, scratch)
    offsets = offsets.reshape(3, particles)
    if particles and int(offsets.max()) >> k:
        raise InputError(f"{where}.cell_bits", f"an offset is not below 2^{k}")
    return _coordinates(number, offsets, layout.grid_bits, k, keep((3, particles), dtype))


def _spread(
    gaps: np.ndarray, counts: np.ndarray, particles: int, dtype: Any, scratch: Lease | None
) -> np.ndarray:
    """Each particle's cell number (the gaps' running sum, once per particle in the cell): each
    cell's gap at its first particle, 0 elsewhere, summed. `counts` (each >= 1) sum to
    `particles`."""
    starts = _empty(scratch, counts.size - 1, np.int64)
    starts[...] = counts[:-1]  # widened first: a cumsum into another dtype casts a copy
    np.cumsum(starts, out=starts)
    steps = _empty(scratch, gaps.size, dtype)
    steps[...] = gaps  # widened once: assigning the gaps through `starts` would cast a copy
    number = _empty(scratch, particles, dtype)
    number[...] = 0
    number[starts] = steps[1:]
    number[0] = steps[0]
    return np.cumsum(number, dtype=dtype, out=number)


def _coordinates(
    number: np.ndarray,
    offsets: np.ndarray,
    grid_bits: tuple[int, int, int],
    cell_bits: int,
    q: np.ndarray,
) -> np.ndarray:
    """Each particle's cell coordinate per axis (shifted and masked out of its cell number),
    times 2^cell_bits, plus its offset in the cell, into `q` (3, N)."""
    by, bz = grid_bits[1], grid_bits[2]
    for axis, (shift, mask) in enumerate(((by + bz, -1), (bz, (1 << by) - 1), (0, (1 << bz) - 1))):
        row = q[axis]
        if shift:
            np.right_shift(number, shift, out=row)
            if mask >= 0:
                row &= mask
        else:
            np.bitwise_and(number, mask, out=row)
        row <<= cell_bits
        row |= offsets[axis]
    return q
