"""Read one frame of particles from a file into a validated `ParticleFrame`.

Formats, chosen by the (case-insensitive) suffix:

- ``.npz``: entries ``positions`` (N, 3), optional ``densities``, ``radii``, ``temperatures``,
  ``peak_temperatures``, ``ids``, ``solid`` (N,) and ``velocities`` (N, 3);
  an optional ``scene`` entry (0-d string array with scene JSON, see `read_npz_scene_json`); any
  other entry is ignored. Never unpickles.
- ``.npy``: an (N, 3) positions array. Never unpickles.
- ``.vtk`` (legacy), ``.vtu``, ``.ply``: via meshio; positions from the points, attributes from the
  point data (``density``/``densities``/``rho``, ``radius``/``radii``,
  ``temperature``/``temperatures``, ``velocity``/``velocities``/``v`` or ``vx``/``vy``/``vz``,
  ``id``/``ids``, ``peak_temperature``/``peak_temperatures``).
- ``.bgeo``, ``.bgeo.gz``: Houdini classic binary geometry (version 5) as partio writes it, gzip
  compressed or not (decided by the gzip magic bytes, not by the name). Parsed here.
- ``.csv``: a header row naming the columns; ``x``, ``y``, ``z`` required; ``density``, ``radius``,
  ``temperature``, ``peak_temperature``, ``vx``/``vy``/``vz`` (all three), ``id`` (whole numbers)
  optional.

Every problem with the file (missing, unreadable, corrupt, truncated, unsupported) raises
`InputError` with field ``file`` and a one-line message that names the path; problems with the
arrays themselves are reported by `make_frame` with the array name and index.
"""

from __future__ import annotations

import csv
import gzip
import importlib
import os
import re
import struct
import warnings
import zipfile
import zlib
from collections.abc import Callable, Collection, Mapping
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sphrender.core.errors import InputError
from sphrender.core.frame import MAX_PARTICLES, ParticleFrame, make_frame

__all__ = [
    "SUPPORTED_SUFFIXES",
    "natural_sort_key",
    "read_npz_scene_json",
    "read_particles",
]

#: Suffixes `read_particles` understands (matched case-insensitively).
SUPPORTED_SUFFIXES: tuple[str, ...] = (
    ".npz",
    ".npy",
    ".vtk",
    ".vtu",
    ".ply",
    ".bgeo",
    ".bgeo.gz",
    ".csv",
)

#: Canonical attribute names (the keys of ``attribute_map``), with their accepted spellings.
_CANONICAL_KEYS: dict[str, str] = {
    "density": "density",
    "densities": "density",
    "radius": "radius",
    "radii": "radius",
    "temperature": "temperature",
    "temperatures": "temperature",
    "velocity": "velocity",
    "velocities": "velocity",
    "id": "id",
    "ids": "id",
    "peak_temperature": "peak_temperature",
    "peak_temperatures": "peak_temperature",
}
_ATTRIBUTES: tuple[str, ...] = (
    "density",
    "radius",
    "temperature",
    "velocity",
    "id",
    "peak_temperature",
)

#: Attribute names looked up when ``attribute_map`` says nothing (first match wins).
_DEFAULT_NAMES: dict[str, tuple[str, ...]] = {
    "density": ("density", "densities", "rho"),
    "radius": ("radius", "radii"),
    "temperature": ("temperature", "temperatures"),
    "velocity": ("velocity", "velocities", "v"),
    "id": ("id", "ids"),
    "peak_temperature": ("peak_temperature", "peak_temperatures"),
}
_NPZ_NAMES: dict[str, tuple[str, ...]] = {
    "density": ("densities",),
    "radius": ("radii",),
    "temperature": ("temperatures",),
    "velocity": ("velocities",),
    "id": ("ids",),
    "peak_temperature": ("peak_temperatures",),
}

#: Exceptions that mean "this file could not be read"; turned into InputError("file", ...).
_FILE_ERRORS: tuple[type[BaseException], ...] = (
    OSError,  # includes gzip.BadGzipFile, FileNotFoundError, PermissionError
    EOFError,
    ValueError,
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    struct.error,
    zlib.error,
    UnicodeDecodeError,
)

_GZIP_MAGIC = b"\x1f\x8b"
_NPY_MAGIC = b"\x93NUMPY"


# --------------------------------------------------------------------------------------------------
# Public helpers


def natural_sort_key(path: str | os.PathLike[str]) -> tuple[tuple[str, int], ...]:
    """Sort key that orders embedded numbers numerically: ``frame_2`` before ``frame_10``.

    Text is compared case-insensitively; the full path breaks ties so the order is total.
    """
    text = os.fspath(path)
    parts = re.split(r"(\d+)", text)
    # parts alternates text, digits, text, ..., text (always an odd count).
    key = [(parts[i].casefold(), int(parts[i + 1])) for i in range(0, len(parts) - 1, 2)]
    key.append((parts[-1].casefold(), -1))
    key.append((text, -1))
    return tuple(key)


def read_npz_scene_json(path: str | os.PathLike[str]) -> str | None:
    """Return the ``scene`` entry of an ``.npz`` file (scene JSON text), or None if it has none.

    The JSON is not parsed here. Raises `InputError` (field ``file``) if the file cannot be read
    and (field ``scene``) if the entry is not a single string.
    """
    where = os.fspath(path)
    try:
        _require_zip(where)
        with np.load(where, allow_pickle=False) as npz:
            if "scene" not in npz.files:
                return None
            value = _load_npz_entry(npz, "scene", where)
    except InputError:
        raise
    except _FILE_ERRORS as exc:
        raise _file_error(where, exc) from None
    if value.ndim != 0 and value.size != 1:
        raise InputError("scene", f"{where}: must be a single string, got shape {value.shape}")
    item = value.reshape(()).item()
    if isinstance(item, bytes):
        try:
            return item.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError("scene", f"{where}: scene bytes are not valid UTF-8") from None
    if isinstance(item, str):
        return item
    raise InputError("scene", f"{where}: must be a string array, got dtype {value.dtype}")


def read_particles(
    path: str | os.PathLike[str],
    *,
    attribute_map: Mapping[str, str] | None = None,
    max_particles: int = MAX_PARTICLES,
) -> ParticleFrame:
    """Read one frame of particles from ``path``, dispatching on its suffix.

    ``attribute_map`` maps our canonical names (``density``, ``radius``, ``temperature``,
    ``velocity``, ``id``; plural spellings accepted too) to the attribute, column or entry name
    used in the file, e.g. ``{"density": "rho0"}``. A mapped name that the file lacks is an
    `InputError`.
    """
    where = os.fspath(path)
    names = _normalise_attribute_map(attribute_map)
    suffix = _suffix(where)
    readers: dict[str, Callable[[str, dict[str, str], int], ParticleFrame]] = {
        ".npz": _read_npz,
        ".npy": _read_npy,
        ".vtk": _read_meshio,
        ".vtu": _read_meshio,
        ".ply": _read_meshio,
        ".bgeo": _read_bgeo,
        ".bgeo.gz": _read_bgeo,
        ".csv": _read_csv,
    }
    reader = readers.get(suffix)
    if reader is None:
        shown = suffix or "(none)"
        raise InputError(
            "file",
            f"{where}: unsupported format '{shown}'; supported: {', '.join(SUPPORTED_SUFFIXES)}",
        )
    if not os.path.isfile(where):
        reason = "is not a regular file" if os.path.exists(where) else "no such file"
        raise InputError("file", f"{where}: cannot read: {reason}")
    return reader(where, names, max_particles)


# --------------------------------------------------------------------------------------------------
# Shared plumbing


def _suffix(path: str) -> str:
    name = os.path.basename(path).lower()
    if name.endswith(".bgeo.gz"):
        return ".bgeo.gz"
    return Path(name).suffix


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    detail = text[0].strip() if text else ""
    if isinstance(exc, OSError) and exc.strerror:
        detail = exc.strerror
    kind = type(exc).__name__
    if kind == "error":  # zlib.error, struct.error
        kind = f"{type(exc).__module__}.error"
    return f"{kind}: {detail}" if detail else kind


def _file_error(path: str, exc: BaseException) -> InputError:
    return InputError("file", f"{path}: cannot read: {_one_line(exc)}")


def _normalise_attribute_map(attribute_map: Mapping[str, str] | None) -> dict[str, str]:
    """Return {canonical name: file attribute name}, rejecting unknown keys and clashes."""
    if attribute_map is None:
        return {}
    if not isinstance(attribute_map, Mapping):
        raise InputError("attribute_map", f"must be a mapping, got {type(attribute_map).__name__}")
    result: dict[str, str] = {}
    for key, value in attribute_map.items():
        canonical = _CANONICAL_KEYS.get(key) if isinstance(key, str) else None
        if canonical is None:
            allowed = ", ".join(_CANONICAL_KEYS)
            raise InputError("attribute_map", f"unknown key {key!r}; expected one of {allowed}")
        if not isinstance(value, str) or not value:
            raise InputError(f"attribute_map.{key}", f"must be a non-empty string, got {value!r}")
        if canonical in result and result[canonical] != value:
            raise InputError(
                f"attribute_map.{key}",
                f"conflicts with another key for {canonical!r} ({result[canonical]!r})",
            )
        result[canonical] = value
    return result


def _choose_name(
    canonical: str,
    available: Collection[str],
    mapped: Mapping[str, str],
    defaults: Mapping[str, tuple[str, ...]],
    path: str,
) -> str | None:
    """Pick the file's name for a canonical attribute: mapped (must exist) or a default alias."""
    if canonical in mapped:
        name = mapped[canonical]
        if name not in available:
            listing = ", ".join(sorted(available)) or "none"
            raise InputError(
                f"attribute_map.{canonical}",
                f"{path}: attribute {name!r} not found; available: {listing}",
            )
        return name
    for name in defaults[canonical]:
        if name in available:
            return name
    return None


def _native(array: np.ndarray) -> np.ndarray:
    """The same values with native byte order (meshio and bgeo give big-endian arrays)."""
    if not array.dtype.isnative:
        return array.astype(array.dtype.newbyteorder("="))
    return array


def _column(array: np.ndarray) -> np.ndarray:
    """(N, 1) per-point scalars (as meshio gives some) become (N,); anything else is unchanged."""
    if array.ndim == 2 and array.shape[1] == 1:
        return array[:, 0]
    return array


def _pad_points(points: np.ndarray) -> np.ndarray:
    if points.ndim == 2 and points.shape[1] == 2:
        return np.concatenate([points, np.zeros((points.shape[0], 1), points.dtype)], axis=1)
    return points


def _frame_from(
    positions: np.ndarray,
    attributes: Mapping[str, np.ndarray | None],
    max_particles: int,
) -> ParticleFrame:
    def prepared(name: str) -> np.ndarray | None:
        value = attributes.get(name)
        return None if value is None else _native(_column(np.asarray(value)))

    return make_frame(
        _native(np.asarray(positions)),
        densities=prepared("density"),
        radii=prepared("radius"),
        temperatures=prepared("temperature"),
        velocities=prepared("velocity"),
        ids=prepared("id"),
        peak_temperatures=prepared("peak_temperature"),
        solid=prepared("solid"),
        max_particles=max_particles,
    )


# --------------------------------------------------------------------------------------------------
# NumPy


def _load_npz_entry(npz: Any, name: str, path: str) -> np.ndarray:
    try:
        value = npz[name]
    except ValueError as exc:
        # allow_pickle=False: object arrays (and broken .npy headers) end up here, unpickled.
        if "object" in str(exc).lower() or "pickle" in str(exc).lower():
            raise InputError(name, f"{path}: object arrays are not allowed") from None
        raise InputError(name, f"{path}: cannot load entry: {_one_line(exc)}") from None
    except _FILE_ERRORS as exc:
        raise _file_error(path, exc) from None
    return np.asarray(value)


def _require_zip(path: str) -> None:
    """np.load() decides by content; insist on a zip archive so a .npy is not taken for .npz."""
    with open(path, "rb") as probe:
        if probe.read(4) != b"PK\x03\x04":
            raise InputError("file", f"{path}: not an .npz (zip) archive")


def _read_npz(path: str, mapped: dict[str, str], max_particles: int) -> ParticleFrame:
    arrays: dict[str, np.ndarray | None] = {}
    try:
        _require_zip(path)
        with np.load(path, allow_pickle=False) as npz:
            files = set(npz.files)
            if "positions" not in files:
                listing = ", ".join(sorted(files)) or "none"
                raise InputError("positions", f"{path}: missing entry 'positions'; has {listing}")
            positions = _load_npz_entry(npz, "positions", path)
            for canonical in _ATTRIBUTES:
                name = _choose_name(canonical, files, mapped, _NPZ_NAMES, path)
                arrays[canonical] = None if name is None else _load_npz_entry(npz, name, path)
            if "solid" in files:  # a workpiece's flags (bool or 0 / 1): .npz frames only
                arrays["solid"] = _load_npz_entry(npz, "solid", path)
    except InputError:
        raise
    except _FILE_ERRORS as exc:
        raise _file_error(path, exc) from None
    return _frame_from(positions, arrays, max_particles)


def _read_npy(path: str, mapped: dict[str, str], max_particles: int) -> ParticleFrame:
    del mapped  # a bare .npy holds positions only
    try:
        with open(path, "rb") as probe:
            if probe.read(len(_NPY_MAGIC)) != _NPY_MAGIC:
                raise InputError("file", f"{path}: not a .npy file (bad magic)")
        positions = np.load(path, allow_pickle=False)
    except InputError:
        raise
    except ValueError as exc:
        if "object" in str(exc).lower() or "pickle" in str(exc).lower():
            raise InputError("positions", f"{path}: object arrays are not allowed") from None
        raise _file_error(path, exc) from None
    except _FILE_ERRORS as exc:
        raise _file_error(path, exc) from None
    return _frame_from(np.asarray(positions), {}, max_particles)


# --------------------------------------------------------------------------------------------------
# meshio (VTK legacy, VTU, PLY)


def _read_meshio(path: str, mapped: dict[str, str], max_particles: int) -> ParticleFrame:
    # meshio is imported lazily (only these formats need it), and we call the format's own reader:
    # meshio.read() prints the error and calls sys.exit(1) when a file cannot be parsed.
    module = importlib.import_module(f"meshio.{_suffix(path).lstrip('.')}")
    try:
        mesh = module.read(path)
    except (Exception, SystemExit) as exc:  # meshio raises anything from ReadError to IndexError
        raise _file_error(path, exc) from None
    points = _pad_points(np.asarray(mesh.points))  # some meshio readers give (N, 2) points
    point_data: dict[str, np.ndarray] = {str(k): np.asarray(v) for k, v in mesh.point_data.items()}
    arrays: dict[str, np.ndarray | None] = {}
    for canonical in _ATTRIBUTES:
        name = _choose_name(canonical, point_data, mapped, _DEFAULT_NAMES, path)
        arrays[canonical] = None if name is None else point_data[name]
    if arrays["velocity"] is None and all(axis in point_data for axis in ("vx", "vy", "vz")):
        # PLY keeps a vector as one scalar property per component
        arrays["velocity"] = np.stack([_column(point_data[a]) for a in ("vx", "vy", "vz")], 1)
    return _frame_from(points, arrays, max_particles)


# --------------------------------------------------------------------------------------------------
# CSV


def _read_csv(path: str, mapped: dict[str, str], max_particles: int) -> ParticleFrame:
    try:
        with open(path, encoding="utf-8-sig", newline="") as handle:
            header_line = handle.readline()
            header = next(csv.reader([header_line]), [])
            columns = [name.strip() for name in header]
            if not columns or columns == [""]:
                raise InputError("file", f"{path}: empty CSV (no header row)")
            duplicates = sorted({c for c in columns if columns.count(c) > 1})
            if duplicates:
                raise InputError("file", f"{path}: duplicate CSV columns {', '.join(duplicates)}")
            missing = [axis for axis in ("x", "y", "z") if axis not in columns]
            if missing:
                raise InputError(
                    "positions",
                    f"{path}: CSV needs columns x, y, z; missing {', '.join(missing)} "
                    f"(found {', '.join(columns)})",
                )
            wanted: dict[str, str | None] = {
                canonical: _choose_name(canonical, columns, mapped, _DEFAULT_NAMES, path)
                for canonical in _ATTRIBUTES
                if canonical != "velocity"  # three columns, below
            }
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
                data = np.loadtxt(handle, delimiter=",", dtype=np.float64, ndmin=2)
    except InputError:
        raise
    except _FILE_ERRORS as exc:
        raise _file_error(path, exc) from None
    if data.size == 0:
        data = np.empty((0, len(columns)), dtype=np.float64)
    if data.shape[1] != len(columns):
        raise InputError(
            "file", f"{path}: rows have {data.shape[1]} values but the header has {len(columns)}"
        )
    index = {name: i for i, name in enumerate(columns)}
    positions = data[:, [index["x"], index["y"], index["z"]]]
    arrays: dict[str, np.ndarray | None] = {
        canonical: None if name is None else data[:, index[name]]
        for canonical, name in wanted.items()
    }
    if all(axis in index for axis in ("vx", "vy", "vz")):
        arrays["velocity"] = data[:, [index["vx"], index["vy"], index["vz"]]]
    ids = arrays.get("id")
    if ids is not None and np.isfinite(ids).all() and (ids == np.round(ids)).all():
        arrays["id"] = ids.astype(np.int64)  # whole numbers; anything else is refused as ids
    return _frame_from(positions, arrays, max_particles)


# --------------------------------------------------------------------------------------------------
# Houdini classic BGEO (version 5, as written by partio)
#
# All numbers big-endian. Layout:
#   'Bgeo' 'V' int32 version (=5)
#   int32 nPoints nPrims nPointGroups nPrimGroups nPointAttrib nVertexAttrib nPrimAttrib nAttrib
#   nPointAttrib definitions: uint16 name length, name, uint16 size (components), int32 type;
#     type 0 float, 1 int, 5 vector: then size int32 defaults;
#     type 4 indexed string: then int32 count and count strings (uint16 length, bytes).
#   nPoints records: 4 float32 position (x, y, z, w), then each attribute's size 4-byte values.
#   Then primitives, detail attributes and an 0x00 0xff trailer, which we do not need.

_BGEO_TYPES: dict[int, str] = {0: ">f4", 1: ">i4", 4: ">i4", 5: ">f4"}
_BGEO_TYPE_NAMES: dict[int, str] = {2: "string", 3: "mixed"}


class _Readable(Protocol):
    def read(self, size: int = ..., /) -> bytes: ...


class _Stream:
    """Exact reads from a binary stream; running short is a 'truncated' InputError."""

    def __init__(self, handle: _Readable, path: str) -> None:
        self._handle = handle
        self.path = path
        self.offset = 0

    def read(self, count: int, what: str) -> bytes:
        chunks: list[bytes] = []
        remaining = count
        while remaining > 0:
            chunk = self._handle.read(remaining)
            if not chunk:
                raise InputError(
                    "file",
                    f"{self.path}: truncated BGEO: needed {count} bytes for {what} at offset "
                    f"{self.offset}, got {count - remaining}",
                )
            chunks.append(chunk)
            remaining -= len(chunk)
        self.offset += count
        return b"".join(chunks) if len(chunks) != 1 else chunks[0]

    def unpack(self, fmt: str, what: str) -> tuple[Any, ...]:
        return struct.unpack(fmt, self.read(struct.calcsize(fmt), what))

    def text(self, what: str) -> str:
        (length,) = self.unpack(">H", f"{what} length")
        return self.read(length, what).decode("utf-8", errors="replace")


def _read_bgeo(path: str, mapped: dict[str, str], max_particles: int) -> ParticleFrame:
    try:
        with open(path, "rb") as raw:
            compressed = raw.read(2) == _GZIP_MAGIC
            raw.seek(0)
            if compressed:
                # Streamed, so a huge or corrupt archive is rejected before it is inflated.
                with gzip.GzipFile(fileobj=raw, mode="rb") as unzipped:
                    positions, attributes = _parse_bgeo(_Stream(unzipped, path), max_particles)
            else:
                positions, attributes = _parse_bgeo(_Stream(raw, path), max_particles)
    except InputError:
        raise
    except _FILE_ERRORS as exc:
        raise _file_error(path, exc) from None
    arrays: dict[str, np.ndarray | None] = {}
    for canonical in _ATTRIBUTES:
        name = _choose_name(canonical, attributes, mapped, _DEFAULT_NAMES, path)
        arrays[canonical] = None if name is None else attributes[name]
    return _frame_from(positions, arrays, max_particles)


def _parse_bgeo(stream: _Stream, max_particles: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    path = stream.path
    magic = stream.read(4, "magic")
    if magic != b"Bgeo":
        if magic == b"\x7fNSJ":
            detail = "new (Houdini 12+) BGEO format; only classic BGEO version 5 is supported"
        else:
            detail = f"not a BGEO file (magic {magic!r}, expected b'Bgeo')"
        raise InputError("file", f"{path}: {detail}")
    version_char, version = stream.unpack(">ci", "version")
    if version_char != b"V" or version != 5:
        raise InputError(
            "file", f"{path}: unsupported BGEO version {version_char!r} {version}; need 'V' 5"
        )
    counts = stream.unpack(">8i", "header counts")
    n_points, _n_prims, _n_point_groups, _n_prim_groups, n_point_attrib = counts[:5]
    if min(counts) < 0:
        raise InputError("file", f"{path}: corrupt BGEO header (negative count in {counts})")
    if n_points > max_particles:
        raise InputError(
            "positions", f"{n_points} particles exceed the limit of {max_particles} ({path})"
        )

    fields: list[tuple[str, str, tuple[int, ...]]] = [("P", ">f4", (4,))]
    numeric: dict[str, str] = {}  # file attribute name -> structured field name
    for index in range(n_point_attrib):
        name = stream.text(f"point attribute {index} name")
        size, kind = stream.unpack(">Hi", f"point attribute {name!r} size and type")
        if kind in (0, 1, 5):
            stream.read(4 * size, f"point attribute {name!r} defaults")
        elif kind == 4:
            (n_strings,) = stream.unpack(">i", f"point attribute {name!r} string count")
            if n_strings < 0:
                raise InputError("file", f"{path}: corrupt string table of attribute {name!r}")
            for _ in range(n_strings):
                stream.text(f"point attribute {name!r} strings")
        else:
            kind_name = _BGEO_TYPE_NAMES.get(kind, "unknown")
            raise InputError(
                "file",
                f"{path}: unsupported BGEO attribute type {kind} ({kind_name}) for {name!r}",
            )
        field = f"a{index}"
        fields.append((field, _BGEO_TYPES[kind], (size,)))
        if kind != 4 and name not in numeric:  # indexed strings are not per-point numbers
            numeric[name] = field

    record = np.dtype(fields)
    body = stream.read(n_points * record.itemsize, f"{n_points} points")
    points = np.frombuffer(body, dtype=record, count=n_points)
    positions = _native(np.ascontiguousarray(points["P"][:, :3]))
    attributes = {name: _native(_column(points[field])) for name, field in numeric.items()}
    return positions, attributes
