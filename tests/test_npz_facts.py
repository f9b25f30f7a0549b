"""Each fact PROTOCOL.md §9 states about `.npz` bodies, checked on the decoder the server uses
(`decode_npz_frame`): entry names with or without `.npy`, stored or deflated entries, the scene
as `<U` or `|S`, big-endian and integer arrays, NPY format versions 1.0-3.0 (others refused),
Fortran order, object arrays refused, unknown entries ignored."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from sphrender.core.errors import InputError
from sphrender.core.protocol import decode_npz_frame

POSITIONS = np.arange(12, dtype=np.float64).reshape(4, 3) / 10
SCENE = {"image": {"width": 32, "height": 24}}


def npy(array: np.ndarray, version: tuple[int, int] | None = None) -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array(out, array, version=version, allow_pickle=False)
    return out.getvalue()


def archive(entries: dict[str, bytes], compression: int = zipfile.ZIP_STORED) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", compression=compression) as zf:
        for name, data in entries.items():
            zf.writestr(name, data)
    return out.getvalue()


def decode(body: bytes) -> tuple[dict[str, np.ndarray], str | None]:
    frame = decode_npz_frame(body, max_particles=1000, max_uncompressed_bytes=1 << 20)
    return frame.arrays, frame.scene_json


@pytest.mark.parametrize("suffix", [".npy", ""])
@pytest.mark.parametrize("compression", [zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED])
def test_names_and_compression(suffix: str, compression: int) -> None:
    body = archive({f"positions{suffix}": npy(POSITIONS)}, compression)
    arrays, scene = decode(body)
    assert np.array_equal(arrays["positions"], POSITIONS) and scene is None


@pytest.mark.parametrize("dtype", ["<U", "|S"])
def test_scene_as_unicode_or_bytes(dtype: str) -> None:
    text = json.dumps(SCENE)
    value = np.array(text) if dtype == "<U" else np.array(text.encode("utf-8"))
    assert value.dtype.str.startswith(dtype)
    _arrays, scene = decode(archive({"positions.npy": npy(POSITIONS), "scene.npy": npy(value)}))
    assert scene is not None and json.loads(scene) == SCENE


@pytest.mark.parametrize("dtype", [">f8", ">f4", "<f4", "<i4", ">i2", "|u1"])
def test_numeric_dtypes_any_byte_order(dtype: str) -> None:
    arrays, _ = decode(archive({"positions.npy": npy(POSITIONS.astype(dtype))}))
    assert np.array_equal(arrays["positions"], POSITIONS.astype(dtype))


@pytest.mark.parametrize("version", [(1, 0), (2, 0), (3, 0)])
def test_npy_versions_accepted(version: tuple[int, int]) -> None:
    arrays, _ = decode(archive({"positions.npy": npy(POSITIONS, version)}))
    assert np.array_equal(arrays["positions"], POSITIONS)


def test_other_npy_versions_refused() -> None:
    data = bytearray(npy(POSITIONS, (1, 0)))
    data[6] = 4  # major version byte
    with pytest.raises(InputError) as caught:
        decode(archive({"positions.npy": bytes(data)}))
    assert caught.value.field == "positions"
    assert "NPY version 4.0 is not supported (1.0, 2.0 and 3.0 are)" in caught.value.message


def test_fortran_order_and_extra_entries() -> None:
    body = archive(
        {"positions.npy": npy(np.asfortranarray(POSITIONS)), "vorticity.npy": b"not even npy"}
    )
    arrays, _ = decode(body)
    assert np.array_equal(arrays["positions"], POSITIONS) and "vorticity" not in arrays


def test_object_arrays_refused() -> None:
    header = "{'descr': '|O', 'fortran_order': False, 'shape': (4, 3), }"
    data = b"\x93NUMPY\x01\x00" + len(header.ljust(117) + "\n").to_bytes(2, "little")
    data += (header.ljust(117) + "\n").encode() + bytes(96)
    with pytest.raises(InputError, match="not allowed"):
        decode(archive({"positions.npy": data}))


def _damaged(kind: str) -> bytes:
    """A one-entry archive damaged in one way a fuzzer finds (offsets from the zip format)."""
    compression = zipfile.ZIP_DEFLATED if kind in ("deflate", "method") else zipfile.ZIP_STORED
    body = bytearray(archive({"positions.npy": npy(POSITIONS)}, compression))
    name_at = 30  # the local header's fixed part, then the file name
    if kind == "name":
        body[name_at + 4] = ord("p")  # posipions.npy in the local header only
    elif kind == "crc":
        body[name_at + len("positions.npy") + 140] ^= 0xFF  # past the 128-byte npy header
    elif kind == "deflate":
        start = name_at + len("positions.npy")
        body[start + 40 : start + 48] = b"\xff" * 8
    elif kind == "method":
        body[8] = 99  # the local header's compression method
        central = body.rindex(b"PK\x01\x02")
        body[central + 10] = 99
    elif kind == "encrypted":
        body[6] |= 1  # the local header's flag bit 0
        central = body.rindex(b"PK\x01\x02")
        body[central + 8] |= 1
    return bytes(body)


@pytest.mark.parametrize("kind", ["name", "crc", "deflate", "method", "encrypted"])
def test_damaged_archives_are_answered_in_plain_words(kind: str) -> None:
    """Whatever zipfile or zlib raise, the answer is the project's sentence: no quoted bytes, no
    library text (PROTOCOL.md §1: plain words and JSON values)."""
    with pytest.raises(InputError) as caught:
        decode(_damaged(kind))
    message = caught.value.message
    assert caught.value.field == "body" and message.startswith("cannot read the .npz archive: ")
    for internal in ("b'", '"', "Error", "zipfile", "zlib", "File name in directory", "CRC-32 for"):
        assert internal not in message, (internal, message)
