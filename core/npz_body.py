"""The HTTP body of ``POST /v1/render``: an ``.npz`` archive, encoded and decoded (numpy + stdlib).

`decode_npz_frame` parses the archive itself, entry by entry, so nothing is ever unpickled, and
every size is checked *before* the bytes it describes are read or allocated:

1. the zip's end-of-archive record: at most `max_entries` entries and a central directory of at
   most `max_entries` x 512 bytes (a 26 MB archive of 300 000 empty entries is refused before
   Python builds 300 000 directory records);
2. every used entry's ``.npy`` header: dtype (numbers, booleans or text only), shape, and the
   declared size against what the entry holds and against `max_uncompressed_bytes` summed over
   the entries (a small deflated body cannot expand into gigabytes); particles against
   `max_particles`; the scene text against `max_scene_bytes`;
3. then `admit(scene_json, particles, array_names)`, the caller's last word (the service checks
   its memory budget there), and only then the arrays' data.

Any failure is an `InputError` naming the entry (or ``body``); a size limit is a `LimitError`.
"""

from __future__ import annotations

import io
import json
import math
import struct
import zipfile
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from sphrender.core.errors import InputError, LimitError, show

__all__ = ["NpzFrame", "decode_npz_frame", "encode_npz_frame"]

#: The arrays an .npz frame may carry (the same names as the stream's FRAME arrays).
NPZ_ARRAYS: tuple[str, ...] = (
    "positions",
    "densities",
    "radii",
    "temperatures",
    "velocities",
    "ids",
    "peak_temperatures",
    "solid",
)
#: Default cap on entries in an archive (a frame needs at most eight).
DEFAULT_MAX_ENTRIES = 64
#: Default cap on the scene entry's text, UTF-8 bytes.
DEFAULT_MAX_SCENE_BYTES = 1 << 20
#: Bytes of central directory allowed per entry (46 fixed + name + extra fields, generously).
_DIRECTORY_BYTES_PER_ENTRY = 512
_EOCD = struct.Struct("<4sHHHHIIH")  # end of central directory record, 22 bytes
_EOCD64 = struct.Struct("<4sQHHIIQQQQ")  # zip64 end of central directory record, 56 bytes

#: What zipfile, zlib and numpy's header parser raise on malformed input. Anything else that
#: escapes is still turned into a `bad_input` answer by the service's decode boundary.
_ZIP_ERRORS: tuple[type[BaseException], ...] = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    EOFError,
    OSError,
    ValueError,
    struct.error,
    NotImplementedError,  # unsupported compression method
    RuntimeError,  # encrypted entry
    KeyError,
    OverflowError,
)


@dataclass(frozen=True)
class NpzFrame:
    """The particle arrays of an .npz body and its scene JSON text (None when absent)."""

    arrays: dict[str, np.ndarray]
    scene_json: str | None


def encode_npz_frame(
    positions: object,
    *,
    densities: object | None = None,
    radii: object | None = None,
    temperatures: object | None = None,
    velocities: object | None = None,
    ids: object | None = None,
    peak_temperatures: object | None = None,
    solid: object | None = None,
    scene: Mapping[str, Any] | str | None = None,
    compress: bool = False,
) -> bytes:
    """An .npz body for ``POST /v1/render`` (what ``np.savez`` writes; the scene as 0-d str)."""
    entries: dict[str, np.ndarray] = {"positions": np.asarray(positions)}
    named = (
        ("densities", densities),
        ("radii", radii),
        ("temperatures", temperatures),
        ("velocities", velocities),
        ("ids", ids),
        ("peak_temperatures", peak_temperatures),
        ("solid", solid),
    )
    for name, value in named:
        if value is not None:
            entries[name] = np.asarray(value)
    if scene is not None:
        text = scene if isinstance(scene, str) else json.dumps(scene, allow_nan=False)
        entries["scene"] = np.array(text)
    buffer = io.BytesIO()
    save: Callable[..., None] = np.savez_compressed if compress else np.savez
    save(buffer, **entries)
    return buffer.getvalue()


class _ViewFile(io.RawIOBase):
    """A seekable read-only file over a buffer without copying it (io.BytesIO copies)."""

    def __init__(self, data: bytes | bytearray | memoryview) -> None:
        self._view = memoryview(data).cast("B")
        self._pos = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def tell(self) -> int:
        return self._pos

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: len(self._view)}[whence]
        self._pos = max(0, base + offset)
        return self._pos

    def readinto(self, buffer: Any) -> int:
        out = memoryview(buffer).cast("B")
        chunk = self._view[self._pos : self._pos + len(out)]
        out[: len(chunk)] = chunk
        self._pos += len(chunk)
        return len(chunk)


def _check_directory(view: memoryview, max_entries: int) -> None:
    """Entry count and central directory size from the end-of-archive record, before zipfile
    reads the directory (it loops over the directory's bytes, whatever the count says)."""
    start = max(0, len(view) - (_EOCD.size + 0xFFFF))
    tail = bytes(view[start:])
    at = tail.rfind(b"PK\x05\x06")
    if at < 0 or at + _EOCD.size > len(tail):
        raise InputError("body", "is not a complete .npz (zip) archive: no end-of-archive record")
    _sig, _disk, _cd_disk, _on_disk, entries, cd_size, _cd_offset, _comment = _EOCD.unpack_from(
        tail, at
    )
    if entries == 0xFFFF or cd_size == 0xFFFFFFFF:  # zip64: the real numbers are further back
        at64 = tail.rfind(b"PK\x06\x06", 0, at)
        if at64 < 0 or at64 + _EOCD64.size > len(tail):
            raise InputError("body", "zip64 archive without its zip64 end-of-archive record")
        fields = _EOCD64.unpack_from(tail, at64)
        entries, cd_size = fields[7], fields[8]
    if entries > max_entries:
        raise LimitError(
            "body", f"the .npz archive has {entries} entries; at most {max_entries} are accepted"
        )
    if cd_size > max_entries * _DIRECTORY_BYTES_PER_ENTRY:
        raise LimitError(
            "body",
            f"the .npz archive's directory is {cd_size} bytes; at most "
            f"{max_entries * _DIRECTORY_BYTES_PER_ENTRY} are accepted",
        )


@dataclass(frozen=True)
class _Entry:
    name: str
    info: zipfile.ZipInfo
    shape: tuple[int, ...]
    fortran: bool
    dtype: np.dtype[Any]
    header_size: int
    nbytes: int


def _read_header(archive: zipfile.ZipFile, member: str, name: str) -> _Entry:
    """The .npy header of one entry (parsed by numpy: literal_eval, never pickle)."""
    info = archive.getinfo(member)
    with archive.open(info) as handle:
        try:
            version = np.lib.format.read_magic(handle)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(handle)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(handle)
            else:
                raise InputError(
                    name,
                    f"not a valid .npy entry: NPY version {version[0]}.{version[1]} is not "
                    "supported (1.0, 2.0 and 3.0 are)",
                )
        except (InputError, zipfile.BadZipFile, zlib.error, EOFError):
            raise  # the archive's own damage is named by the caller
        except Exception:  # numpy raises ValueError, SyntaxError, tokenize.TokenError, ...
            raise InputError(
                name,
                "not a valid .npy entry: its header is not a dictionary of descr, "
                "fortran_order and shape",
            ) from None
        header_size = handle.tell()
    if dtype.hasobject or dtype.fields is not None or dtype.kind not in "fiuUSb":
        shown = "a structured or object dtype" if dtype.fields or dtype.hasobject else dtype.str
        raise InputError(name, f"dtype {shown} is not allowed (numbers, booleans or text only)")
    nbytes = math.prod(shape) * dtype.itemsize
    if nbytes + header_size != info.file_size:
        raise InputError(
            name,
            f"declares shape {show(list(shape))} ({nbytes} bytes) but the entry holds "
            f"{info.file_size - header_size} bytes",
        )
    return _Entry(name, info, tuple(shape), bool(fortran), dtype, header_size, nbytes)


def _read_data(archive: zipfile.ZipFile, entry: _Entry) -> np.ndarray:
    with archive.open(entry.info) as handle:
        handle.read(entry.header_size)
        data = handle.read(entry.nbytes)
    if len(data) != entry.nbytes:
        raise InputError(entry.name, f"entry is truncated: {len(data)} of {entry.nbytes} bytes")
    order: Literal["C", "F"] = "F" if entry.fortran else "C"
    return np.frombuffer(data, dtype=entry.dtype).reshape(entry.shape, order=order)


def decode_npz_frame(
    data: bytes | bytearray | memoryview,
    *,
    max_particles: int,
    max_uncompressed_bytes: int,
    max_entries: int = DEFAULT_MAX_ENTRIES,
    max_scene_bytes: int = DEFAULT_MAX_SCENE_BYTES,
    admit: Callable[[str | None, int, tuple[str, ...]], None] | None = None,
) -> NpzFrame:
    """Parse an .npz body: arrays named as in `NPZ_ARRAYS` plus an optional ``scene``.

    Other entries are ignored unread. See the module docstring for the order of the checks;
    `admit(scene_json, particles, array_names)` may raise to refuse the frame before its arrays
    are read.
    """
    view = memoryview(data).cast("B")
    if bytes(view[:4]) != b"PK\x03\x04":
        raise InputError("body", "must be an .npz (zip) archive (application/x-npz)")
    _check_directory(view, max_entries)
    try:
        with zipfile.ZipFile(_ViewFile(view)) as archive:
            members = {name.removesuffix(".npy"): name for name in archive.namelist()}
            if "positions" not in members:
                listing = ", ".join(sorted(members)[:8]) or "none"
                raise InputError("positions", f"missing entry positions; the body has {listing}")
            entries = [
                _read_header(archive, members[name], name)
                for name in (*NPZ_ARRAYS, "scene")
                if name in members
            ]
            total = 0
            for entry in entries:
                total += entry.nbytes
                if total > max_uncompressed_bytes:
                    raise LimitError(
                        entry.name,
                        f"the arrays decompress to more than the limit of "
                        f"{max_uncompressed_bytes} bytes",
                    )
                _check_entry(entry, max_particles, max_scene_bytes)
            scene_json = None
            for entry in entries:
                if entry.name == "scene":
                    scene_json = _scene_text(_read_data(archive, entry), max_scene_bytes)
            positions = next(e for e in entries if e.name == "positions")
            if admit is not None:
                names = tuple(e.name for e in entries if e.name != "scene")
                admit(scene_json, positions.shape[0] if positions.shape else 0, names)
            arrays = {e.name: _read_data(archive, e) for e in entries if e.name != "scene"}
    except InputError:
        raise
    except _ZIP_ERRORS as exc:
        raise InputError("body", f"cannot read the .npz archive: {_archive_fault(exc)}") from None
    return NpzFrame(arrays, scene_json)


def _archive_fault(exc: BaseException) -> str:
    """What went wrong in the archive, in this project's words: a library's message may quote
    bytes or internals, so only its kind is used, never its text."""
    if isinstance(exc, zipfile.BadZipFile):
        text = str(exc).lower()
        if "crc" in text:
            return "an entry fails its CRC-32 check (its data is corrupted)"
        if "differ" in text:
            return "an entry's local header names another file than the archive's directory"
        if "overlap" in text:
            return "two entries overlap in the archive"
        return "an entry's local header is missing or damaged"
    if isinstance(exc, zipfile.LargeZipFile):
        return "the archive needs zip64 records it does not have"
    if isinstance(exc, (zlib.error, EOFError)):
        return "an entry's compressed data is corrupted or truncated"
    if isinstance(exc, NotImplementedError):
        return "an entry uses a compression method the server cannot read (use stored or deflate)"
    if isinstance(exc, RuntimeError):
        return "an entry is encrypted, which is not supported"
    return "its records are damaged"


def _check_entry(entry: _Entry, max_particles: int, max_scene_bytes: int) -> None:
    if entry.name == "scene":
        if entry.dtype.kind not in "US" or math.prod(entry.shape) != 1:
            raise InputError(
                "scene",
                f"must be a single string, got dtype {show(entry.dtype.str)} "
                f"shape {show(list(entry.shape))}",
            )
        # UTF-32 in the archive (numpy's 'U' dtype): up to 4 bytes per character.
        if entry.nbytes > 4 * max_scene_bytes:
            raise LimitError(
                "scene", f"the scene text exceeds this server's limit of {max_scene_bytes} bytes"
            )
        return
    kinds = "biu" if entry.name == "solid" else "fiu"
    if entry.dtype.kind not in kinds:
        raise InputError(entry.name, f"must be a numeric array, got dtype {show(entry.dtype.str)}")
    if entry.shape and entry.shape[0] > max_particles:
        raise LimitError(
            entry.name, f"{entry.shape[0]} particles exceed the limit of {max_particles}"
        )


def _scene_text(value: npt.NDArray[Any], max_scene_bytes: int) -> str:
    item = value.reshape(()).item()
    if isinstance(item, bytes):
        try:
            text = item.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError("scene", "bytes are not valid UTF-8") from None
    else:
        text = str(item)
    try:
        size = len(text.encode("utf-8"))
    except UnicodeEncodeError:
        raise InputError("scene", "is not valid Unicode text (lone surrogates)") from None
    if size > max_scene_bytes:
        raise LimitError(
            "scene",
            f"the scene text is {size} bytes; this server's limit is {max_scene_bytes} bytes",
        )
    return text
