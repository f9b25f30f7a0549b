"""The compact frame encoding (PROTOCOL.md §4.7): error-bounded quantisation + byte planes + zstd.

A FRAME whose header says ``"encoding": "compact"`` carries, per array, one zstd frame instead of
the array's raw bytes. Each array's descriptor adds to ``name``/``dtype``/``shape`` (the array as
decoded) how it was stored:

* ``coding`` ``"quantized"`` (float arrays): integers ``q = round((x - lo) / step)`` per
  component, decoded as ``lo + q * step`` in float64 then cast to ``dtype``. ``bounds`` is
  ``[lo, hi]`` (float64 per component), ``step`` the quantum; the encoder guarantees
  ``|decoded - x| <= error`` for the error it was given (``step`` just under ``2 * error``,
  with a per-value fix-up for float rounding). ``predict``: ``none`` (store q), ``particle``
  (q minus the previous particle's q), ``frame`` (q minus the same array's q in the frame
  named by the header's ``base``), ``motion`` (that difference minus the previous
  particle's) or ``cells`` (positions only, order-free: core/compact_cells.py); residuals are
  zigzag-mapped to unsigned. ``width``: bytes per stored value.
* ``coding`` ``"raw"``: the array's own little-endian bytes, lossless (ids, flags, radii and any
  array without a precision in compact_encoder.py's `DEFAULT_ERRORS`).

Stored values are split into byte planes (byte 0 of every value, then byte 1, ...; quantised
arrays component by component) and compressed with zstd. Byte planes put the slowly varying high
bytes together, which is what lets zstd find the runs; zstd was chosen over blosc2 by measurement
(benchmarks/STUDIES.md, "Compact frame encoding").

Decoding checks every declared size before inflating anything: the decompressed size of each
section follows from the header (``N x components x width``), the zstd frame must declare that
same size, and decompression is bounded by it. Errors are `InputError` naming the field.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zstandard

from sphrender.core.compact_cells import CELLS, CellLayout, cells_layout, decode_cells
from sphrender.core.errors import InputError, show
from sphrender.core.protocol import plan_frame_arrays
from sphrender.core.scratch import DECODE_SCRATCH, Allocate, Lease

__all__ = [
    "ENCODING",
    "MAX_Q",
    "CompactDecoder",
    "CompactSlot",
    "decode_compact_arrays",
    "plan_compact_arrays",
]

#: The value of a FRAME header's ``encoding`` key for this encoding.
ENCODING = "compact"
CODINGS = ("quantized", "raw")
PREDICTORS = ("none", "particle", "frame", "motion", CELLS)
WIDTHS = (1, 2, 4, 8)
#: Largest quantised integer: decoded values stay exact in float64 arithmetic.
MAX_Q = 2**52
_CELL_KEYS = ("cell_bits", "grid_bits", "cells", "count_width")
_COMPACT_KEYS = ("coding", "step", "bounds", "predict", "width", "bytes", *_CELL_KEYS)
_THREAD = threading.local()


@dataclass(frozen=True)
class CompactSlot:
    """One array of a compact FRAME, as its header declares it."""

    name: str
    dtype: np.dtype[Any]
    shape: tuple[int, ...]
    coding: str
    predict: str
    width: int
    offset: int
    nbytes: int
    step: float = 0.0
    lo: tuple[float, ...] = ()
    hi: tuple[float, ...] = ()
    layout: CellLayout | None = None  # predict: cells

    @property
    def components(self) -> int:
        return self.shape[1] if len(self.shape) == 2 else 1

    @property
    def raw_size(self) -> int:
        if self.layout is not None:
            return self.layout.raw_size(self.shape[0])
        return math.prod(self.shape) * self.width


# --------------------------------------------------------------------------------------------
# Header


def _int_key(where: str, spec: Mapping[str, Any], key: str) -> int:
    value = spec.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(f"{where}.{key}", f"must be an integer >= 0, got {show(value)}")
    return value


def _finite(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(where, f"must be a finite number, got {show(value)}")
    return float(value)


def _quantized(where: str, spec: Mapping[str, Any], components: int) -> tuple[float, list, list]:
    step = spec.get("step")
    if (
        isinstance(step, bool)
        or not isinstance(step, int | float)
        or not math.isfinite(step)
        or step <= 0
    ):
        raise InputError(
            f"{where}.step",
            f"must be a finite number > 0 (twice the error bound), got {show(step)}",
        )
    bounds = spec.get("bounds")
    if (
        not isinstance(bounds, list)
        or len(bounds) != 2
        or not all(isinstance(b, list) and len(b) == components for b in bounds)
    ):
        raise InputError(
            f"{where}.bounds",
            f"must be [lo, hi], each a list of {components} numbers, got {show(bounds)}",
        )
    lo = [_finite(f"{where}.bounds[0][{c}]", v) for c, v in enumerate(bounds[0])]
    hi = [_finite(f"{where}.bounds[1][{c}]", v) for c, v in enumerate(bounds[1])]
    for c in range(components):
        if hi[c] < lo[c]:
            raise InputError(f"{where}.bounds[1][{c}]", f"is {hi[c]!r}, below lo {lo[c]!r}")
        if (hi[c] - lo[c]) / step >= MAX_Q:
            raise InputError(
                f"{where}.step",
                f"{step!r} is too fine for bounds {lo[c]!r}..{hi[c]!r}: at most 2^52 steps",
            )
    return float(step), lo, hi


def plan_compact_arrays(
    header: Mapping[str, Any], payload_length: int, *, max_particles: int
) -> tuple[list[CompactSlot], int]:
    """Check a compact FRAME header against `payload_length` and `max_particles` before any of
    the payload is read; returns the arrays' slots and the particle count."""
    specs = header.get("arrays")
    if not isinstance(specs, list) or not specs:
        raise InputError("arrays", "must be a non-empty array of array descriptors")
    plain = []
    for index, spec in enumerate(specs):
        if not isinstance(spec, dict):
            raise InputError(f"arrays[{index}]", "must be an object (an array descriptor)")
        plain.append({k: v for k, v in spec.items() if k not in _COMPACT_KEYS})
    decoded_size = sum(_declared_size(spec) for spec in plain)
    base_slots, count = plan_frame_arrays(plain, decoded_size, max_particles=max_particles)
    slots: list[CompactSlot] = []
    offset = 0
    for index, (spec, base) in enumerate(zip(specs, base_slots, strict=True)):
        where = f"arrays[{index}]"
        coding = spec.get("coding")
        if coding not in CODINGS:
            raise InputError(f"{where}.coding", f"must be one of {', '.join(CODINGS)}")
        nbytes = _int_key(where, spec, "bytes")
        if offset + nbytes > payload_length:
            raise InputError(
                f"{where}.bytes",
                f"declares {nbytes} bytes at offset {offset} but the payload has {payload_length}",
            )
        if coding == "raw":
            extra = set(spec) & {"step", "bounds", "width", *_CELL_KEYS}
            if extra or spec.get("predict", "none") != "none":
                key = sorted(extra)[0] if extra else "predict"
                raise InputError(f"{where}.{key}", "is only for quantized arrays")
            slots.append(
                CompactSlot(
                    base.name,
                    base.dtype,
                    base.shape,
                    coding,
                    "none",
                    base.dtype.itemsize,
                    offset,
                    nbytes,
                )
            )
        else:
            if base.dtype.kind != "f":
                raise InputError(
                    f"{where}.coding", f"quantized needs a float dtype for {base.name}"
                )
            predict = spec.get("predict", "none")
            if predict not in PREDICTORS:
                raise InputError(f"{where}.predict", f"must be one of {', '.join(PREDICTORS)}")
            width = spec.get("width")
            if width not in WIDTHS or isinstance(width, bool):
                raise InputError(f"{where}.width", f"must be 1, 2, 4 or 8, got {show(width)}")
            components = base.shape[1] if len(base.shape) == 2 else 1
            step, lo, hi = _quantized(where, spec, components)
            layout = None
            if predict == CELLS:
                if components != 3:
                    raise InputError(f"{where}.predict", "cells codes [N, 3] positions only")
                layout = cells_layout(where, spec, base.shape[0])
            elif set(spec) & set(_CELL_KEYS):
                key = sorted(set(spec) & set(_CELL_KEYS))[0]
                raise InputError(f"{where}.{key}", "is only for predict cells")
            slot = CompactSlot(
                base.name,
                base.dtype,
                base.shape,
                coding,
                predict,
                width,
                offset,
                nbytes,
                step,
                tuple(lo),
                tuple(hi),
                layout,
            )
            slots.append(slot)
        offset += nbytes
    if offset != payload_length:
        raise InputError(
            "payload_length", f"is {payload_length} bytes but the arrays declare {offset} bytes"
        )
    return slots, count


def _declared_size(spec: Mapping[str, Any]) -> int:
    """The raw size a descriptor declares, or 0 when it is malformed (plan_frame_arrays names
    the problem)."""
    shape, dtype = spec.get("shape"), spec.get("dtype")
    if not isinstance(shape, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in shape
    ):
        return 0
    try:
        itemsize = np.dtype(dtype).itemsize if isinstance(dtype, str) and len(dtype) < 8 else 0
    except (TypeError, ValueError):
        itemsize = 0
    return math.prod(shape) * itemsize


# --------------------------------------------------------------------------------------------
# Byte planes and integers


def _planes(values: np.ndarray, width: int) -> bytes:
    """uint64 values (any shape, C order) -> byte planes of their low `width` bytes."""
    flat = np.ascontiguousarray(values, dtype=np.uint64).reshape(-1)
    planes = np.empty((width, flat.size), np.uint8)
    for b in range(width):  # shifts, not a strided transpose: contiguous rows
        planes[b] = flat >> np.uint64(8 * b)
    return planes.tobytes()


def _unplanes(data: Any, count: int, width: int, allocate: Allocate = np.empty) -> np.ndarray:
    """Byte planes -> values as unsigned integers `width` bytes wide (in `allocate`'s array)."""
    planes = np.frombuffer(data, np.uint8, count * width).reshape(width, count)
    values = allocate(count, np.dtype(f"=u{width}"))
    values[...] = planes[width - 1]
    for b in range(width - 2, -1, -1):  # shifts, not a strided transpose: contiguous rows
        values <<= 8
        values |= planes[b]
    return values


def _zigzag(r: np.ndarray) -> np.ndarray:
    return ((r << 1) ^ (r >> 63)).view(np.uint64)


def _unzigzag(z: np.ndarray, scratch: Lease) -> np.ndarray:
    """Zigzag back to signed, in the stored width (cheap); callers widen when summing."""
    one = z.dtype.type(1)
    signed = np.dtype(f"=i{z.dtype.itemsize}")
    sign = scratch.array(z.shape, z.dtype)
    np.bitwise_and(z, one, out=sign)
    np.negative(sign.view(signed), out=sign.view(signed))
    half = scratch.array(z.shape, z.dtype)
    np.right_shift(z, one, out=half)
    return np.bitwise_xor(half.view(signed), sign.view(signed), out=half.view(signed))


def _width_for(top: int) -> int:
    return next(w for w in WIDTHS if top < 1 << (8 * w))


# --------------------------------------------------------------------------------------------
# Decoding


@dataclass
class CompactDecoder:
    """Decodes compact FRAMEs of one session, holding the last frame's quantised integers for
    ``predict: frame`` (transport threads only; one decoder per session). A decoder that is not
    to `hold` them (one frame, as over HTTP) keeps nothing."""

    base_id: int | None = None
    base_q: dict[str, np.ndarray] = field(default_factory=dict)
    hold: bool = True
    #: The pooled buffers behind `base_q`, given back once the next frame no longer needs them.
    _held: Lease | None = field(default=None, repr=False, compare=False)

    def decode(
        self,
        header: Mapping[str, Any],
        payload: bytes | bytearray | memoryview,
        *,
        max_particles: int,
    ) -> dict[str, np.ndarray]:
        """The frame's arrays; on any error the held base is dropped (the client resends full)."""
        held_id, held_q, held = self.base_id, self.base_q, self._held
        self.base_id, self.base_q, self._held = None, {}, None
        kept = DECODE_SCRATCH.hold() if self.hold else None
        try:
            slots, _count = plan_compact_arrays(
                header, memoryview(payload).nbytes, max_particles=max_particles
            )
            if any(slot.predict in ("frame", "motion") for slot in slots):
                _check_base(header.get("base"), held_id)
            elif "base" in header:
                raise InputError("base", "is only for frames with an array predicted from a frame")
            arrays, quantised = decode_compact_arrays(slots, payload, held_q, kept)
        except BaseException:
            if kept is not None:
                kept.release()
            raise
        finally:
            if held is not None:
                held.release()
        if kept is not None:
            frame_id = header.get("id")
            self.base_id = frame_id if isinstance(frame_id, int) else None
            self.base_q, self._held = quantised, kept
        return arrays

    def forget(self) -> None:
        """Hold no frame (its buffers go back to the pool)."""
        held, self._held = self._held, None
        self.base_id, self.base_q = None, {}
        if held is not None:
            held.release()


def _check_base(base: Any, held: int | None) -> None:
    if isinstance(base, bool) or not isinstance(base, int):
        raise InputError(
            "base", f"must be the integer id of the frame predicted from, got {show(base)}"
        )
    if held is None:
        raise InputError(
            "base",
            f"frame {base} is not held: the server keeps only the last frame this session decoded "
            "without error, and has none; send this frame in full",
        )
    if base != held:
        raise InputError(
            "base",
            f"frame {base} is not held: the server keeps only this session's last decoded frame, "
            f"frame {held}; send this frame in full",
        )


def _decompressor() -> zstandard.ZstdDecompressor:
    """This thread's decompressor (reused: making one costs about as much as a small frame)."""
    dctx: zstandard.ZstdDecompressor | None = getattr(_THREAD, "dctx", None)
    if dctx is None:
        dctx = _THREAD.dctx = zstandard.ZstdDecompressor()
    return dctx


def _inflate(slot: CompactSlot, index: int, data: memoryview, out: np.ndarray) -> np.ndarray:
    """Section `index`'s zstd frame inflated into `out` (uint8, the declared raw size)."""
    where = f"arrays[{index}].bytes"
    expected = slot.raw_size
    try:
        params = zstandard.get_frame_parameters(data)
    except zstandard.ZstdError:
        raise InputError(where, "is not a zstd frame (damaged or truncated)") from None
    if not params.has_checksum:
        raise InputError(where, "zstd frame has no checksum; the encoding requires one")
    if params.content_size != expected:
        unknown = params.content_size >= 2**63  # zstd's "size unknown"
        declared = "no size" if unknown else f"{params.content_size} bytes"
        raise InputError(
            where, f"zstd frame declares {declared}; the header's shape and width need {expected}"
        )
    target = out.data.cast("B")
    filled = 0
    try:
        reader = _decompressor().stream_reader(data, read_across_frames=False)
        while filled < expected and (got := reader.readinto(target[filled:])):
            filled += got
        past = len(reader.read(1))  # reads to the frame's end, where zstd checks its checksum
    except zstandard.ZstdError:
        raise InputError(
            where, "compressed data is damaged or truncated (zstd refused it)"
        ) from None
    if filled != expected or past:
        size = f"more than {expected}" if past else str(filled)
        raise InputError(where, f"inflates to {size} bytes, the header needs {expected}")
    return out


def decode_compact_arrays(
    slots: list[CompactSlot],
    payload: bytes | bytearray | memoryview,
    base_q: Mapping[str, np.ndarray] | None = None,
    kept: Lease | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Decode planned slots: (arrays in their native dtypes, quantised integers (C, N) by name,
    in whichever integer dtype decoded them). Temporaries come from `DECODE_SCRATCH`, the
    integers from `kept` when given (else afresh), the arrays afresh."""
    keep: Allocate = np.empty if kept is None else kept.array
    view = memoryview(payload).cast("B")
    arrays: dict[str, np.ndarray] = {}
    quantised: dict[str, np.ndarray] = {}
    with DECODE_SCRATCH.lease() as scratch:
        for index, slot in enumerate(slots):
            section = view[slot.offset : slot.offset + slot.nbytes]
            raw = _inflate(slot, index, section, scratch.array(slot.raw_size, np.uint8))
            count = math.prod(slot.shape)
            if slot.coding == "raw":
                native = slot.dtype.newbyteorder("=")
                values = _unplanes(raw, count, slot.width)  # native-order integers of the bytes
                arrays[slot.name] = values.view(native).reshape(slot.shape)
                continue
            n, c = slot.shape[0], slot.components
            if slot.layout is not None:
                q = decode_cells(slot.layout, index, raw, n, scratch, keep)
            elif slot.predict == "none":  # the stored values are the integers themselves
                q = _unplanes(raw, count, slot.width, keep).reshape(c, n)
                if slot.width == 8 and q.size and int(q.max()) >= MAX_Q:
                    raise InputError(f"arrays[{index}]", "holds a value beyond 2^52")
            else:
                stored = _unplanes(raw, count, slot.width, scratch.array).reshape(c, n)
                q = _predicted(slot, index, stored, base_q or {}, scratch, keep)
            _check_range(slot, index, q)
            arrays[slot.name] = _dequantised(slot, q, scratch)
            quantised[slot.name] = q
    return arrays, quantised


def _dequantised(slot: CompactSlot, q: np.ndarray, scratch: Lease) -> np.ndarray:
    """lo + q * step per component, in float64 (exact for q: within the bounds, so below 2^52),
    then in the slot's dtype and shape."""
    n, c = slot.shape[0], slot.components
    decoded = np.empty((n, c), slot.dtype.newbyteorder("="))
    wide = scratch.array(n, np.float64)
    for k in range(c):  # the sum in float64, rounded once into the output's column
        np.multiply(q[k], slot.step, out=wide)
        np.add(wide, slot.lo[k], out=decoded[:, k], casting="unsafe")
    return decoded.reshape(slot.shape)


def _predicted(
    slot: CompactSlot,
    index: int,
    stored: np.ndarray,
    base_q: Mapping[str, np.ndarray],
    scratch: Lease,
    keep: Allocate,
) -> np.ndarray:
    """The quantised integers (c, n) of a predicted array, as running or frame sums in an
    array from `keep`."""
    residual = _unzigzag(stored, scratch)
    if slot.predict == "particle":
        largest = (int(stored.max()) + 1) // 2 if stored.size else 0
        return _prefix_sum(residual, keep, largest)
    base = base_q.get(slot.name)
    if base is None or base.shape != residual.shape:
        have = "none" if base is None else f"{base.shape[1]} particles"
        raise InputError(
            f"arrays[{index}].predict",
            f"frame prediction needs {slot.name} with {residual.shape[1]} particles in the base "
            f"frame; it has {have}; send this frame in full",
        )
    # motion: each particle moved as the one before it, plus s
    if slot.predict == "motion":
        moved = _prefix_sum(residual, keep)
    else:
        moved = keep(residual.shape, np.int64)
        moved[...] = residual
    # The base's integers are below 2^52 (their dtype may be uint64): the sums stay exact up to
    # the first value outside the bounds.
    np.add(moved, base, out=moved, casting="unsafe")
    return moved


def _prefix_sum(residual: np.ndarray, keep: Allocate, largest: int | None = None) -> np.ndarray:
    """Running sums of signed residuals (c, n) along the particles: in int32 when `largest`
    (a bound on |residual|) times n stays below 2^31, so no sum can wrap; else in int64, where
    every sum up to the first one outside the bounds is exact (a value below 2^52 plus one
    residual) and `_check_range` refuses that one; 8-byte residuals wrap as the encoder's
    integers would. Summed in place in the widened copy (no cast buffer of numpy's own)."""
    narrow = largest is not None and residual.shape[1] * largest < 2**31
    sums = keep(residual.shape, np.int32 if narrow else np.int64)
    sums[...] = residual
    return np.cumsum(sums, axis=1, out=sums)


def _check_range(slot: CompactSlot, index: int, q: np.ndarray) -> None:
    """Every decoded value must lie within the declared bounds, widened by step / 2."""
    if not q.size:
        return
    for c in range(slot.components):
        top = math.floor((slot.hi[c] - slot.lo[c]) / slot.step) + 1
        row = q[c]
        if (row.dtype.kind == "u" or row.min() >= 0) and row.max() <= top:
            continue
        bad = (row < 0) | (row > top)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            value = slot.lo[c] + float(row[i]) * slot.step
            raise InputError(
                f"{slot.name}[{i}]",
                f"decodes to {value!r}, outside arrays[{index}].bounds "
                f"{slot.lo[c]!r}..{slot.hi[c]!r} (component {c})",
            )
