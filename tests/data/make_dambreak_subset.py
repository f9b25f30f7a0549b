"""Write the vendored dam-break frames in tests/data/dambreak-splishsplash/ from the full ones in
../shared/data/dambreak-splishsplash/ (run once by hand; the tests only read the result).

Each frame keeps the particles of the central slab |z| <= SLAB_HALF_WIDTH (8 of the 32 particle
layers of the initial block, about a fifth of the tank's width), in their original order and with
every attribute. The files are cut at the byte level, so they keep the simulator's exact layout
and values: legacy VTK 4.1, BINARY, big-endian float32, the same sections and header lines with
the new counts; BGEO version 5 as partio writes it (big-endian records, no primitives, the
0x00 0xff trailer), gzip-compressed (mtime 0, so the output is reproducible).

    .venv/bin/python tests/data/make_dambreak_subset.py [SOURCE_DIR]
"""

from __future__ import annotations

import gzip
import hashlib
import json
import struct
import sys
from pathlib import Path

import numpy as np
import numpy.typing as npt

HERE = Path(__file__).resolve().parent
OUT = HERE / "dambreak-splishsplash"
SOURCE = HERE.parents[2] / "shared" / "data" / "dambreak-splishsplash"
VTK_FRAMES = (1, 5, 11)
BGEO_FRAMES = (5, 11)
SLAB_HALF_WIDTH = 0.12  # metres; the particle spacing is 0.03

Mask = npt.NDArray[np.bool_]


class _Reader:
    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def line(self, expected_start: bytes) -> bytes:
        end = self.data.index(b"\n", self.pos)
        text = self.data[self.pos : end]
        if not text.startswith(expected_start):
            raise ValueError(f"expected {expected_start!r} at {self.pos}, found {text[:40]!r}")
        self.pos = end + 1
        return text

    def block(self, size: int) -> bytes:
        chunk = self.data[self.pos : self.pos + size]
        if len(chunk) != size:
            raise ValueError("file ends inside a data block")
        self.pos += size
        if self.data[self.pos : self.pos + 1] == b"\n":  # each block ends with a newline
            self.pos += 1
        return chunk


def _rows(block: bytes, row_bytes: int, keep: Mask) -> bytes:
    table = np.frombuffer(block, dtype=np.uint8).reshape(-1, row_bytes)
    return bytes(table[keep].tobytes())


def subset_vtk(data: bytes) -> tuple[bytes, Mask]:
    """The slab of one SPlisHSPlasH legacy VTK file, and the mask of the kept particles."""
    r = _Reader(data)
    head = [r.line(b"# vtk DataFile"), r.line(b"SPlisHSPlasH"), r.line(b"BINARY")]
    head.append(r.line(b"DATASET UNSTRUCTURED_GRID"))
    n = int(r.line(b"POINTS ").split()[1])
    points = r.block(12 * n)
    z = np.frombuffer(points, dtype=">f4").reshape(n, 3)[:, 2]
    keep: Mask = np.abs(z.astype(np.float64)) <= SLAB_HALF_WIDTH
    m = int(keep.sum())
    if r.line(b"CELLS ") != f"CELLS {n} {2 * n}".encode():
        raise ValueError("unexpected CELLS header")
    r.block(8 * n)  # (1, i) per vertex cell: rewritten with the new indices
    r.line(b"CELL_TYPES ")
    r.block(4 * n)
    r.line(b"POINT_DATA ")
    scalars, lookup = r.line(b"SCALARS id"), r.line(b"LOOKUP_TABLE")
    ids = r.block(4 * n)
    if r.line(b"FIELD ") != b"FIELD FieldData 2":
        raise ValueError("unexpected FIELD header")
    density_name = r.line(b"density ").split()[0]
    density = r.block(4 * n)
    velocity_name = r.line(b"velocity ").split()[0]
    velocity = r.block(12 * n)
    if r.pos != len(data):
        raise ValueError(f"{len(data) - r.pos} unexpected bytes at the end")

    cells = np.empty((m, 2), dtype=">i4")
    cells[:, 0] = 1
    cells[:, 1] = np.arange(m)
    out = b"\n".join(head) + b"\n"
    out += f"POINTS {m} float\n".encode() + _rows(points, 12, keep) + b"\n"
    out += f"CELLS {m} {2 * m}\n".encode() + cells.tobytes() + b"\n"
    out += f"CELL_TYPES {m}\n".encode() + np.ones(m, dtype=">i4").tobytes() + b"\n"
    out += f"POINT_DATA {m}\n".encode() + scalars + b"\n" + lookup + b"\n"
    out += _rows(ids, 4, keep) + b"\n"
    out += b"FIELD FieldData 2\n"
    out += density_name + f" 1 {m} float\n".encode() + _rows(density, 4, keep) + b"\n"
    out += velocity_name + f" 3 {m} float\n".encode() + _rows(velocity, 12, keep) + b"\n"
    return out, keep


def subset_bgeo(compressed: bytes, keep: Mask) -> bytes:
    """The same particles of a partio BGEO v5 file (gzip), by the VTK frame's mask."""
    raw = gzip.decompress(compressed)
    if raw[:5] != b"BgeoV" or struct.unpack_from(">i", raw, 5)[0] != 5:
        raise ValueError("not a BGEO version 5 file")
    counts = list(struct.unpack_from(">8i", raw, 9))
    n, n_prims, n_attributes = counts[0], counts[1], counts[4]
    if n != keep.size or n_prims != 0 or any(counts[5:]) or any(counts[2:4]):
        raise ValueError(f"unexpected BGEO header counts {counts}")
    pos = 41
    record = 16  # P: x, y, z, w
    for _ in range(n_attributes):
        (length,) = struct.unpack_from(">H", raw, pos)
        pos += 2 + length
        size, kind = struct.unpack_from(">Hi", raw, pos)
        if kind not in (0, 1, 5):
            raise ValueError(f"attribute type {kind} not handled")
        pos += 6 + 4 * size
        record += 4 * size
    definitions = raw[41:pos]
    body = raw[pos : pos + n * record]
    trailer = raw[pos + n * record :]
    if trailer != b"\x00\xff":
        raise ValueError(f"unexpected BGEO trailer {trailer[:8]!r}")
    counts[0] = int(keep.sum())
    out = raw[:9] + struct.pack(">8i", *counts) + definitions + _rows(body, record, keep) + trailer
    return gzip.compress(out, compresslevel=9, mtime=0)


def main(source: Path = SOURCE) -> None:
    manifest: dict[str, dict[str, object]] = {}
    masks: dict[int, Mask] = {}
    for frame in VTK_FRAMES:
        name = f"vtk/ParticleData_Fluid_{frame}.vtk"
        data, masks[frame] = subset_vtk((source / name).read_bytes())
        (OUT / "vtk").mkdir(parents=True, exist_ok=True)
        (OUT / name).write_bytes(data)
        manifest[name] = {"particles": int(masks[frame].sum()), "sha256": _sha(data)}
    for frame in BGEO_FRAMES:
        name = f"bgeo/ParticleData_Fluid_{frame}.bgeo"
        data = subset_bgeo((source / name).read_bytes(), masks[frame])
        (OUT / "bgeo").mkdir(parents=True, exist_ok=True)
        (OUT / name).write_bytes(data)
        manifest[name] = {"particles": int(masks[frame].sum()), "sha256": _sha(data)}
    (OUT / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else SOURCE)
