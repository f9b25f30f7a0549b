"""Crowd merging for the SPH kernels: in a grid cell (side h) holding more than CROWD particles
(coincident, near-coincident or clustered ones), the particles sharing a sub-cell become one
weighted representative. The sub-cells are the finest of side h / 2^FINEST .. h / 4 that leave
the cell at most CAP representatives, so coincident and near-coincident particles merge while
distinct ones stay apart wherever the cap allows; a neighbour walk then visits at most CAP
entries per cell whatever the geometry, and the kernels' cost stays linear in the particles.

A representative is the lowest-index particle of its sub-cell, weighted by how many particles
it stands for; the kernels (shaders/sph/sph.cl, anisotropy.cl) multiply each neighbour's term
by that weight, so N coincident particles give the same sums as N separate copies (to float
rounding). Every member of a group gets its representative's result. Frames without a crowded
cell are untouched: `find_crowds` answers None after one hashed count, and their weights are 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import TypeVar

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: A cell holding more particles than this is merged.
CROWD = 64
#: The most representatives a merged cell keeps (the coarsest sub-cells, h / 4, give 64).
CAP = 1024
#: The finest sub-cells: side h / 2^FINEST (below any particle spacing a frame would use).
FINEST = 10
#: Cells are clamped to +-2^62 so the integer casts stay defined for any finite input.
_CLAMP = float(2**62)

T = TypeVar("T")


@dataclass(frozen=True)
class Crowd:
    """The merge of a frame: its representatives and which one each particle belongs to."""

    #: Indices of the representatives in the frame, ascending.
    representatives: I64
    #: For each particle of the frame, its representative's row in `representatives`.
    members: I64
    #: For each representative, how many particles it stands for.
    weights: F32

    def expand(self, result: T) -> T:
        """`result` (a dataclass of per-representative arrays) with every array field taken
        per particle of the frame; other fields unchanged."""
        arrays = {
            f.name: getattr(result, f.name)
            for f in fields(result)  # type: ignore[arg-type]
            if isinstance(getattr(result, f.name), np.ndarray)
        }
        return replace(result, **{name: value[self.members] for name, value in arrays.items()})  # type: ignore[type-var]


def _row_keys(rows: I64) -> I64:
    """One int64 per row of `rows` ((M, K) integers), equal exactly where the rows are equal
    (a mixed-radix number when the spans fit; else the rows' index in their sorted unique
    set, which costs a multi-column sort)."""
    low = rows.min(axis=0)
    spans = [int(s) + 1 for s in rows.max(axis=0) - low]
    if math.prod(spans) < 2**62:
        key = np.zeros(rows.shape[0], np.int64)
        for column, span in enumerate(spans):
            key = key * span + (rows[:, column] - low[column])
        return key
    return np.unique(rows, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int64)


def _cells(points: F64, origin: F64, side: float) -> I64:
    scaled = np.floor((points - origin) / side)
    return np.clip(scaled, -_CLAMP, _CLAMP).astype(np.int64)


def find_crowds(points: F64, h: float) -> Crowd | None:
    """The merge of `points` ((N, 3) float64) on cells of side `h`, or None when no cell holds
    more than CROWD particles."""
    n = points.shape[0]
    if n <= CROWD or not h > 0.0:
        return None
    origin = points.min(axis=0)
    if not np.isfinite(origin).all() or not np.isfinite(points.max(axis=0)).all():
        return None  # the grid's own checks answer such a frame
    cells = _cells(points, origin, h)
    # A hashed count first: no bucket over CROWD means no cell over it (the common case).
    table = 1 << max(10, math.ceil(math.log2(2 * n)))
    key = (cells[:, 0] * 73856093) ^ (cells[:, 1] * 19349663) ^ (cells[:, 2] * 83492791)
    key &= table - 1
    counts = np.bincount(key, minlength=table)
    if int(counts.max()) <= CROWD:
        return None
    candidates = np.flatnonzero(counts[key] > CROWD)
    _, inverse, per_cell = np.unique(
        _row_keys(cells[candidates]), return_inverse=True, return_counts=True
    )
    crowded = candidates[per_cell[inverse.reshape(-1)] > CROWD]
    if crowded.size == 0:
        return None
    cell = inverse.reshape(-1)[per_cell[inverse.reshape(-1)] > CROWD]  # ids of crowded cells
    owner = np.arange(n, dtype=np.int64)
    owner[crowded] = crowded[_merge_cells(points[crowded], cell, origin, h)]
    representatives = np.unique(owner)
    members = np.searchsorted(representatives, owner).astype(np.int64)
    weights = np.bincount(members, minlength=representatives.size).astype(np.float32)
    return Crowd(representatives, members, weights)


def _merge_cells(points: F64, cell: I64, origin: F64, h: float) -> I64:
    """For each of `points` (ascending frame order, in the cells `cell`), the row of its
    representative: the first point of its sub-cell, at each cell's finest level within CAP."""
    owner = np.empty(cell.size, np.int64)
    pending = np.arange(cell.size)
    for level in range(FINEST, 1, -1):
        sub = _cells(points[pending], origin, h / 2.0**level)
        rows = np.column_stack([cell[pending], sub])
        _, first, group = np.unique(_row_keys(rows), return_index=True, return_inverse=True)
        distinct = np.bincount(cell[pending][first])  # sub-cells used per cell
        fits = distinct[cell[pending]] <= CAP if level > 2 else np.ones(pending.size, np.bool_)
        owner[pending[fits]] = pending[first[group.reshape(-1)]][fits]
        pending = pending[~fits]
        if pending.size == 0:
            break
    return owner
