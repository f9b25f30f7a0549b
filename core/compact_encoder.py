"""The encoder of the compact frame encoding (core/compact.py has the format and the decoder):
per-array error bounds, quantisation that keeps every decoded value within its bound exactly,
prediction from the previous particle or the previous frame, or positions coded order-free
(core/compact_cells.py), byte planes, zstd."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zstandard

from sphrender.core.compact import ENCODING, MAX_Q, _planes, _width_for, _zigzag
from sphrender.core.compact_cells import MAX_CELL_BITS, encode_cells
from sphrender.core.errors import InputError, show

__all__ = ["DEFAULT_ERRORS", "POSITION_ERROR_FRACTION", "CompactEncoder"]

#: Default position error bound, as a fraction of the particle radius.
POSITION_ERROR_FRACTION = 0.01
#: Default absolute error per array (its unit); None = lossless. Arrays not listed are lossless.
DEFAULT_ERRORS: dict[str, float | None] = {
    "densities": 0.05,  # kg/m^3 (rest density 1000)
    "temperatures": 0.05,  # K
    "peak_temperatures": 0.05,  # K
    "velocities": 1e-3,  # scene units per second
    "radii": None,
    "ids": None,
    "solid": None,
}
_ZSTD_LEVEL = 3
#: Every this many frames (and on a session's first 4) the encoder tries the cell size next to its
#: last one and both codings (the first frame walks up to 3 sizes); in between it keeps the last
#: size (each try costs a sort and a compression).
_CELL_RETRY = 8
#: Fractions of the error bound kept free for float rounding, smallest first.
_ROOM = (2.0**-40, 2.0**-30, 2.0**-20, 2.0**-10, 2.0**-4)


def _check_error(name: str, error: float) -> float:
    if isinstance(error, bool) or not isinstance(error, int | float):
        raise InputError(f"errors.{name}", f"must be a number > 0, got {show(error)}")
    if not math.isfinite(error) or error <= 0:
        raise InputError(
            f"errors.{name}",
            f"must be a finite error bound > 0 in the array's unit, got {show(float(error))}",
        )
    return float(error)


def _quantise(
    name: str,
    values: np.ndarray,
    error: float,
    dtype: np.dtype[Any],
    bounds: tuple[np.ndarray, np.ndarray] | None,
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """(q as (C, N) int64, step, lo, hi) with |decoded - values| <= error, decoded as the
    decoder does it (float64 lo + q * step, then cast to `dtype`)."""
    components = values.shape[1] if values.ndim == 2 else 1
    x = np.ascontiguousarray(np.asarray(values, np.float64).reshape(len(values), components).T)
    if bounds is None:  # a NaN or an infinity shows in the minima or maxima
        lo = x.min(axis=1) if x.size else np.zeros(x.shape[0])
        hi = x.max(axis=1) if x.size else np.zeros(x.shape[0])
        finite = bool(np.isfinite(lo).all() and np.isfinite(hi).all())
    else:
        finite = bool(np.isfinite(x).all())
    if not finite:
        i = int(np.flatnonzero(~np.isfinite(x).all(axis=0))[0])
        raise InputError(f"{name}[{i}]", "must be finite (found NaN or Infinity)")
    if bounds is not None:
        lo, hi = (np.asarray(b, np.float64).reshape(-1) for b in bounds)
        outside = ((x < lo[:, None]) | (x > hi[:, None])).any(axis=0)
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            raise InputError(
                f"{name}[{i}]",
                f"lies outside the bounds given, {show(lo.tolist())} to {show(hi.tolist())}",
            )
    # Leave room for the decoder's float rounding (and the cast to `dtype`): one ulp at the
    # largest magnitude; a bound that leaves no room is refused.
    top_value = float(max(np.abs(lo).max(), np.abs(hi).max())) if x.size else 0.0
    margin = 2.0 * top_value * float(np.finfo(dtype).eps) + 4.0 * top_value * 2.0**-52
    # From a short ladder, so that frames of similar extent share a step (frame prediction).
    room = next((r for r in _ROOM if error * r >= margin), None)
    if room is None:
        raise InputError(
            f"errors.{name}",
            f"{error!r} is finer than {dtype.name} resolves at {top_value!r}; use a larger bound",
        )
    step = 2.0 * error * (1.0 - room)
    if x.size and float(((hi - lo) / step).max()) >= MAX_Q / 2:
        raise InputError(
            f"errors.{name}", f"{error!r} is too fine for {name}'s extent (at most 2^51 steps)"
        )
    q = x - lo[:, None]
    q /= step
    np.rint(q, out=q)
    top = np.broadcast_to(np.floor((hi - lo) / step)[:, None] + 1, q.shape)
    for attempt in range(3):  # float rounding can leave a value one ulp past the bound: nudge it
        miss = _decoded(q, lo, step, dtype)
        miss -= x
        if not miss.size or (miss.max() <= error and miss.min() >= -error):
            break
        bad = np.abs(miss) > error
        if attempt == 2:
            i = int(np.flatnonzero(bad.any(axis=0))[0])
            raise InputError(
                f"errors.{name}",
                f"{error!r} is finer than {dtype.name} resolves at {name}[{i}]; use a larger bound",
            )
        q[bad] = np.clip(q[bad] - np.sign(miss[bad]), 0, top[bad])
    return q.astype(np.int64), step, lo, hi


def _decoded(q: np.ndarray, lo: np.ndarray, step: float, dtype: np.dtype[Any]) -> np.ndarray:
    """What the decoder makes of `q` (float64 lo + q * step, then `dtype`), as float64."""
    decoded = q * step
    decoded += lo[:, None]
    if dtype != np.float64:
        decoded[...] = decoded.astype(dtype)  # rounded as the decoder's cast rounds
    return decoded


@dataclass
class CompactEncoder:
    """Encodes one session's frames (client side): per-array error bounds (`errors`, None =
    lossless; arrays not named use `DEFAULT_ERRORS`), ``predict: frame`` against the
    previous frame when its arrays have the same shapes and steps (`delta`), and positions
    coded order-free (``cells``, every array permuted with them) when that is smaller and
    `reorder` allows it. `order` says which particle each sent one is."""

    position_error: float
    errors: dict[str, float | None] = field(default_factory=dict)
    delta: bool = True
    level: int = _ZSTD_LEVEL
    bounds: tuple[np.ndarray, np.ndarray] | None = None
    reorder: bool = True
    #: The last frame's order: ``order[j]`` is the index (in the arrays given) of the particle
    #: sent j-th; None when sent as given.
    order: np.ndarray | None = None
    _base_id: int | None = None
    _base: dict[str, tuple[float, np.ndarray]] = field(default_factory=dict)
    _cell_bits: int | None = None
    _frames: int = 0
    _ordered_won: bool = False
    _cells_bytes: int = 0

    def __post_init__(self) -> None:
        self.position_error = _check_error("positions", self.position_error)
        for name, error in self.errors.items():
            if error is not None:
                _check_error(name, error)
        self._compressor = zstandard.ZstdCompressor(
            level=self.level, write_content_size=True, write_checksum=True
        )

    def reset(self) -> None:
        """Forget the previous frame: the next frame is sent in full."""
        self._base_id, self._base, self.order = None, {}, None

    def error_for(self, name: str) -> float | None:
        if name == "positions":
            return self.position_error
        return self.errors[name] if name in self.errors else DEFAULT_ERRORS.get(name)

    def encode(
        self, frame_id: int, arrays: Mapping[str, np.ndarray]
    ) -> tuple[dict[str, Any], bytes]:
        """(FRAME header without ``scene``, payload) for `arrays` (already wire dtypes)."""
        n = len(arrays["positions"]) if "positions" in arrays else -1
        held = self.order if self.order is not None and len(self.order) == n else None
        order, same_order = held, True
        descriptors: list[dict[str, Any]] = []
        sections: list[bytes] = []
        state: dict[str, tuple[float, np.ndarray]] = {}
        uses_base = False
        for name, array in arrays.items():
            error = self.error_for(name)
            if error is None or array.dtype.kind != "f":
                spec, data = self._raw(array if order is None else array[order])
                packed = self._compressor.compress(data)
            elif name == "positions":
                spec, packed, q, step, by_frame, order = self._positions(array, error, held)
                same_order = order is held
                state[name] = (step, q)
                uses_base |= by_frame
            else:
                values = array if order is None else array[order]
                spec, packed, q, step, by_frame = self._lossy(name, values, error, same_order)
                state[name] = (step, q)
                uses_base |= by_frame
            sections.append(packed)
            desc = {"name": name, "dtype": array.dtype.str, "shape": list(array.shape)}
            descriptors.append({**desc, **spec, "bytes": len(packed)})
        header: dict[str, Any] = {"id": int(frame_id), "encoding": ENCODING, "arrays": descriptors}
        if uses_base:
            header["base"] = self._base_id
        self._base_id, self._base, self.order = int(frame_id), state, order
        return header, b"".join(sections)

    @staticmethod
    def _raw(array: np.ndarray) -> tuple[dict[str, Any], bytes]:
        flat = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<")).reshape(-1)
        planes = flat.view(np.uint8).reshape(-1, flat.dtype.itemsize).T
        return {"coding": "raw"}, np.ascontiguousarray(planes).tobytes()

    def _positions(
        self, array: np.ndarray, error: float, held: np.ndarray | None
    ) -> tuple[dict[str, Any], bytes, np.ndarray, float, bool, np.ndarray | None]:
        """The smaller of the positions coded order-free and in the held order (predicted as any
        array): (keys, zstd frame, q as sent, step, predicted from a frame?, order). Both are
        tried on a session's first 4 frames and every `_CELL_RETRY`-th; in between the
        order-free one unless the ordered one won last time and is still smaller than the
        order-free one was, and the ordered one when it won last time or an eighth of the
        particles says frame prediction may win."""
        q, step, lo, hi = _quantise("positions", array, error, array.dtype, self.bounds)
        quantised = {"coding": "quantized", "step": step, "bounds": [lo.tolist(), hi.tolist()]}
        self._frames += 1
        retry = self._frames <= 4 or self._frames % _CELL_RETRY == 1
        free = self.reorder and q.shape[1] > 1
        tried = free and (retry or not self._ordered_won)
        cells = self._cells(q, step, lo, hi, retry) if tried else None
        ordered = None
        if cells is None or retry or self._ordered_won or self._may_win(q, held, len(cells[1])):
            ordered = self._in_order(q, step, held)
            if free and not tried and len(ordered[1]) > self._cells_bytes:
                cells = self._cells(q, step, lo, hi, retry)
        self._ordered_won = cells is None or (
            ordered is not None and len(ordered[1]) <= len(cells[1])
        )
        if self._ordered_won:
            assert ordered is not None
            spec, packed, sent, by_frame = ordered
            order = held
        else:
            assert cells is not None
            spec, packed, order = cells
            sent, by_frame = q[:, order], False
        if cells is not None:
            self._cells_bytes = len(cells[1])
        return {**quantised, **spec}, packed, sent, step, by_frame, order

    def _in_order(
        self, q: np.ndarray, step: float, held: np.ndarray | None
    ) -> tuple[dict[str, Any], bytes, np.ndarray, bool]:
        """Positions in the held order, predicted as any array: (keys, zstd frame, q as sent,
        predicted from a frame?)."""
        ordered = q if held is None else q[:, held]
        spec, data, by_frame = self._predicted("positions", ordered, step, True)
        return spec, self._compressor.compress(data), ordered, by_frame

    def _may_win(self, q: np.ndarray, held: np.ndarray | None, cells: int) -> bool:
        """Can the positions be predicted from the frame before (in the held order), and does
        that on the first eighth of the particles come within 5 % of the order-free coding's
        bytes a particle?"""
        base = self._base.get("positions") if self.delta and held is not None else None
        if held is None or base is None or base[1].shape != q.shape:
            return False
        part = held[: max(1, len(held) // 8)]
        by_frame = q[:, part] - base[1][:, : len(part)]
        by_motion = np.diff(by_frame, axis=1, prepend=0)
        residual = min((by_frame, by_motion), key=lambda r: float(np.abs(r).mean()))
        stored = _zigzag(residual)
        data = _planes(stored, _width_for(int(stored.max())))
        return len(self._compressor.compress(data)) / len(part) < 1.05 * cells / len(held)

    def _cells(
        self, q: np.ndarray, step: float, lo: np.ndarray, hi: np.ndarray, retry: bool
    ) -> tuple[dict[str, Any], bytes, np.ndarray] | None:
        """The ``cells`` coding at the last cell size, or a smaller one next to it on the retry
        frames (the first starts from the bounds' mean spacing and walks up to 3 sizes)."""
        first = self._cell_bits is None
        if self._cell_bits is None:
            spacing = (float(np.prod((hi - lo) / step + 1)) / q.shape[1]) ** (1 / 3)
            self._cell_bits = int(np.clip(math.floor(math.log2(max(spacing, 2.0))) - 1, 1, 16))
        k = self._cell_bits
        tried: dict[int, tuple[dict[str, Any], bytes, np.ndarray] | None] = {}

        def attempt(bits: int) -> tuple[dict[str, Any], bytes, np.ndarray] | None:
            if bits not in tried:
                made = encode_cells(q, bits) if 1 <= bits <= MAX_CELL_BITS else None
                tried[bits] = (
                    None if made is None else (made[1], self._compressor.compress(made[2]), made[0])
                )
            return tried[bits]

        here = attempt(k)
        if here is None or not (first or retry):
            return here
        for direction in (-1, 1):  # smaller cells, then larger: walk while the bytes shrink
            start = k
            for _ in range(3 if first else 1):
                there = attempt(k + direction)
                if there is None or len(there[1]) >= len(here[1]):
                    break
                k, here = k + direction, there
            if k != start:
                break
        self._cell_bits = k
        return here

    def _lossy(
        self, name: str, array: np.ndarray, error: float, same_order: bool
    ) -> tuple[dict[str, Any], bytes, np.ndarray, float, bool]:
        """(keys, zstd frame, q, step, predicted from a frame?): predicted as `_predicted`
        says, or stored as they are when that is no larger (no running sum to decode)."""
        q, step, lo, hi = _quantise(name, array, error, array.dtype, None)
        spec, data, by_frame = self._predicted(name, q, step, same_order)
        packed = self._compressor.compress(data)
        if spec["predict"] == "particle" and q.size:
            width = _width_for(int(q.max()))
            plain = self._compressor.compress(_planes(q, width))
            if len(plain) <= len(packed):
                spec, packed = {"predict": "none", "width": width}, plain
        quantised = {"coding": "quantized", "step": step, "bounds": [lo.tolist(), hi.tolist()]}
        return {**quantised, **spec}, packed, q, step, by_frame

    def _predicted(
        self, name: str, q: np.ndarray, step: float, same_order: bool
    ) -> tuple[dict[str, Any], bytes, bool]:
        """q predicted from the previous particle, or the previous frame when that is smaller
        (a sample of the residuals decides): (keys, byte planes, predicted from a frame?)."""
        by_particle = np.diff(q, axis=1, prepend=0)
        residual, predict = by_particle, "particle"
        base = self._base.get(name) if self.delta and same_order else None
        if base is not None and base[0] == step and base[1].shape == q.shape and q.size:
            by_frame = q - base[1]
            by_motion = np.diff(by_frame, axis=1, prepend=0)
            sample = slice(None, None, 7)  # a sample decides which residuals are smallest
            candidates = ((by_particle, "particle"), (by_frame, "frame"), (by_motion, "motion"))
            residual, predict = min(candidates, key=lambda c: np.abs(c[0][:, sample]).mean())
        stored = _zigzag(residual)
        width = _width_for(int(stored.max()) if stored.size else 0)
        spec = {"predict": predict, "width": width}
        return spec, _planes(stored, width), predict in ("frame", "motion")
