"""Cheap, dependency-free checks that an output image is complete (for ``submit --resume``).

A frame whose output passes is not rendered again. The checks catch what an interrupted writer
leaves behind (a truncated file, a missing end marker, a bad chunk) without decoding pixels:
PNG: signature, every chunk's length and CRC-32, IHDR first and IEND last.
EXR (single-part scanline or tiled): magic and version, a header that parses up to its
terminator, and a chunk offset table whose entries all point inside the file, with the last chunk
ending exactly at the end of the file.
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
EXR_MAGIC = 20000630

# scanlines per chunk for each OpenEXR compression id
_EXR_LINES_PER_CHUNK = {
    0: 1,
    1: 1,
    2: 1,
    3: 16,
    4: 32,
    5: 16,
    6: 32,
    7: 32,
    8: 32,
    9: 256,
    10: 256,
    11: 32,
}


def is_complete_png(path: str | os.PathLike[str]) -> bool:
    try:
        data = Path(path).read_bytes()
    except OSError:
        return False
    if not data.startswith(PNG_SIGNATURE):
        return False
    pos = len(PNG_SIGNATURE)
    first = True
    while pos + 12 <= len(data):
        (length,) = struct.unpack_from(">I", data, pos)
        kind = data[pos + 4 : pos + 8]
        end = pos + 12 + length
        if end > len(data):
            return False
        body = data[pos + 8 : pos + 8 + length]
        (crc,) = struct.unpack_from(">I", data, pos + 8 + length)
        if zlib.crc32(kind + body) & 0xFFFFFFFF != crc:
            return False
        if first and kind != b"IHDR":
            return False
        first = False
        if kind == b"IEND":
            return end == len(data)
        pos = end
    return False


def _read_exr_header(data: bytes, pos: int) -> tuple[dict[str, tuple[str, bytes]], int]:
    attributes: dict[str, tuple[str, bytes]] = {}
    while True:
        end = data.index(b"\x00", pos)
        name = data[pos:end].decode("latin-1")
        pos = end + 1
        if not name:
            return attributes, pos
        end = data.index(b"\x00", pos)
        kind = data[pos:end].decode("latin-1")
        pos = end + 1
        (size,) = struct.unpack_from("<i", data, pos)
        pos += 4
        if size < 0 or pos + size > len(data):
            raise ValueError("attribute runs past the end")
        attributes[name] = (kind, data[pos : pos + size])
        pos += size


def is_complete_exr(path: str | os.PathLike[str]) -> bool:
    try:
        data = Path(path).read_bytes()
        if len(data) < 8:
            return False
        magic, version = struct.unpack_from("<ii", data, 0)
        if magic != EXR_MAGIC or version & 0xFF != 2:
            return False
        if version & 0x1000:  # multi-part: trust the header only
            return True
        attributes, pos = _read_exr_header(data, 8)
        tiled = bool(version & 0x200)
        _, ymin, _, ymax = struct.unpack("<iiii", attributes["dataWindow"][1])
        compression = attributes["compression"][1][0]
        if tiled:
            return True  # tile tables depend on level modes; the header parsed, that suffices
        lines = _EXR_LINES_PER_CHUNK.get(compression)
        if lines is None:
            return False
        chunks = -(-(ymax - ymin + 1) // lines)
        offsets = struct.unpack_from(f"<{chunks}Q", data, pos)
        if any(not (pos + 8 * chunks <= o < len(data)) for o in offsets):
            return False
        last = max(offsets)
        (size,) = struct.unpack_from("<i", data, last + 4)
        return last + 8 + size == len(data)
    except (OSError, KeyError, ValueError, IndexError, struct.error):
        return False


def is_complete_jpeg(path: str | os.PathLike[str]) -> bool:
    """Start of image first, end of image (FF D9) last."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return False
    return data[:3] == b"\xff\xd8\xff" and data[-2:] == b"\xff\xd9"


def is_complete_image(path: str | os.PathLike[str]) -> bool:
    """Dispatch on the suffix (.png / .exr / .jpg / .raw); anything else is not complete. A raw
    file carries no size of its own: it counts as complete when it is not empty (the submitter
    writes every output atomically, so it never leaves a partial one)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".png":
        return is_complete_png(path)
    if suffix == ".exr":
        return is_complete_exr(path)
    if suffix in (".jpg", ".jpeg"):
        return is_complete_jpeg(path)
    if suffix == ".raw":
        try:
            return Path(path).stat().st_size > 0
        except OSError:
            return False
    return False
