"""The wire codec (core/protocol.py) on its own: framing, FRAME arrays and .npz bodies.

The byte layouts asserted here are the ones PROTOCOL.md documents; a C# or C++ frontend that
follows the document produces exactly these bytes.
"""

from __future__ import annotations

import io
import json
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sphrender.core.errors import InputError
from sphrender.core.protocol import (
    PREFIX_SIZE,
    LimitError,
    MessageType,
    ProtocolError,
    decode_frame_arrays,
    decode_npz_frame,
    encode_frame,
    encode_message,
    encode_npz_frame,
    parse_prefix,
    read_message,
)

LIMITS = {"max_header_bytes": 4096, "max_payload_bytes": 1 << 20}


def reader(data: bytes):
    stream = io.BytesIO(data)

    def recv_exact(n: int) -> bytes:
        chunk = stream.read(n)
        if len(chunk) != n:
            raise EOFError
        return chunk

    return recv_exact


def test_prefix_layout_matches_protocol_md() -> None:
    message = encode_message(MessageType.BYE, {})
    # magic "SPHR", version 1, type 0x03, flags 0, header length 2 ("{}"), payload length 0
    assert message[:PREFIX_SIZE].hex(" ") == "53 50 48 52 01 03 00 00 02 00 00 00 00 00 00 00"
    assert message[PREFIX_SIZE:] == b"{}"


def test_frame_roundtrip_keeps_float64_positions_and_order() -> None:
    positions = np.array([[1e5 + 0.25, 2.0, 3.0], [4.0, 5.0, 6.0]])
    radii = np.array([0.5, 0.25], dtype=np.float32)
    data = encode_frame(7, positions, radii=radii, scene={"camera": {"fov_y": 30.0}})
    message = read_message(reader(data), **LIMITS)
    assert message.type == MessageType.FRAME
    assert message.header["id"] == 7
    assert message.header["scene"] == {"camera": {"fov_y": 30.0}}
    assert [a["name"] for a in message.header["arrays"]] == ["positions", "radii"]
    arrays = decode_frame_arrays(message.header["arrays"], message.payload, max_particles=10)
    np.testing.assert_array_equal(arrays["positions"], positions)  # bit-exact float64
    np.testing.assert_array_equal(arrays["radii"], radii)
    # Payload = positions (2*3*8 bytes, little-endian f8) then radii (2*4 bytes, f4), no padding.
    assert bytes(message.payload[:8]) == struct.pack("<d", 1e5 + 0.25)
    assert len(message.payload) == 2 * 3 * 8 + 2 * 4


@pytest.mark.parametrize(
    ("mutate", "code", "field"),
    [
        (lambda b: b"XPHR" + b[4:], "protocol", "magic"),
        (lambda b: b[:4] + b"\x02" + b[5:], "unsupported_version", "version"),
        (lambda b: b[:5] + b"\x7f" + b[6:], "protocol", "type"),
        (lambda b: b[:6] + b"\x01\x00" + b[8:], "protocol", "flags"),
        (lambda b: b[:8] + struct.pack("<I", 10**6) + b[12:], "too_large", "header_length"),
        (lambda b: b[:12] + struct.pack("<I", 2**32 - 1), "too_large", "payload_length"),
    ],
)
def test_bad_prefixes_name_the_field(mutate, code: str, field: str) -> None:
    prefix = mutate(encode_message(MessageType.BYE, {})[:PREFIX_SIZE])
    with pytest.raises(ProtocolError) as info:
        parse_prefix(prefix, **LIMITS)
    assert (info.value.code, info.value.field) == (code, field)


@pytest.mark.parametrize(
    "header", [b"not json", b"[1, 2]", b'{"a": NaN}', b"\xff\xfe", b"[" * 5000]
)
def test_headers_must_be_json_objects(header: bytes) -> None:
    prefix = struct.pack("<4sBBHII", b"SPHR", 1, 2, 0, len(header), 0)
    with pytest.raises(ProtocolError) as info:
        read_message(reader(prefix + header), max_header_bytes=1 << 16, max_payload_bytes=10)
    assert info.value.field == "header"


def _specs(n: int = 2) -> list[dict[str, object]]:
    return [{"name": "positions", "dtype": "<f4", "shape": [n, 3]}]


@pytest.mark.parametrize(
    ("specs", "payload_len", "field"),
    [
        ([], 24, "arrays"),
        ([{"name": "colour", "dtype": "<f4", "shape": [2]}], 8, "arrays[0].name"),
        ([{"name": "positions", "dtype": "<i8", "shape": [2, 3]}], 48, "arrays[0].dtype"),
        ([{"name": "positions", "dtype": ">f4", "shape": [2, 3]}], 24, "arrays[0].dtype"),
        ([{"name": "positions", "dtype": "<f4", "shape": [2, 4]}], 32, "arrays[0].shape"),
        ([{"name": "positions", "dtype": "<f4", "shape": [-1, 3]}], 24, "arrays[0].shape"),
        ([{"name": "positions", "dtype": "<f4", "shape": [2, 3], "x": 1}], 24, "arrays[0].x"),
        # lying sizes: the shape claims more bytes than the payload has, or fewer
        (_specs(1000), 24, "arrays[0].shape"),
        (_specs(2), 25, "payload_length"),
        (
            [*_specs(2), {"name": "radii", "dtype": "<f4", "shape": [3]}],
            24 + 12,
            "arrays[1].shape",
        ),
        ([*_specs(2), *_specs(2)], 48, "arrays[1].name"),
        ([{"name": "radii", "dtype": "<f4", "shape": [2]}], 8, "arrays"),
    ],
)
def test_frame_array_errors_name_the_field(specs, payload_len: int, field: str) -> None:
    with pytest.raises(InputError) as info:
        decode_frame_arrays(specs, bytes(payload_len), max_particles=100)
    assert info.value.field == field


def test_frame_over_the_particle_limit_is_a_limit_error_before_any_allocation() -> None:
    specs = [{"name": "positions", "dtype": "<f8", "shape": [10**12, 3]}]
    with pytest.raises(LimitError) as info:
        decode_frame_arrays(specs, b"", max_particles=1000)
    assert info.value.field == "arrays[0].shape"


# -- .npz bodies -------------------------------------------------------------------------------


def test_npz_roundtrip_with_scene() -> None:
    positions = np.arange(12, dtype=np.float64).reshape(4, 3)
    body = encode_npz_frame(positions, radii=np.ones(4), scene={"image": {"width": 8}})
    frame = decode_npz_frame(body, max_particles=10, max_uncompressed_bytes=1 << 20)
    np.testing.assert_array_equal(frame.arrays["positions"], positions)
    assert json.loads(frame.scene_json or "") == {"image": {"width": 8}}


def test_npz_fortran_order_and_compression_are_read_correctly() -> None:
    positions = np.asfortranarray(np.random.default_rng(1).normal(size=(50, 3)))
    buffer = io.BytesIO()
    np.savez_compressed(buffer, positions=positions)
    frame = decode_npz_frame(buffer.getvalue(), max_particles=50, max_uncompressed_bytes=1 << 20)
    np.testing.assert_array_equal(frame.arrays["positions"], positions)


def test_npz_object_arrays_are_refused_without_unpickling() -> None:
    buffer = io.BytesIO()
    # An object array: its data is a pickle. We never get that far.
    np.savez(buffer, positions=np.zeros((2, 3)), scene=np.array([{"a": 1}], dtype=object))
    with pytest.raises(InputError) as info:
        decode_npz_frame(buffer.getvalue(), max_particles=10, max_uncompressed_bytes=1 << 20)
    assert info.value.field == "scene"
    assert "not allowed" in info.value.message


def test_compressed_bomb_is_refused_by_declared_size() -> None:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, positions=np.zeros((1_000_000, 3)))  # 24 MB -> ~25 kB
    body = buffer.getvalue()
    assert len(body) < 100_000
    with pytest.raises(LimitError) as info:
        decode_npz_frame(body, max_particles=10**7, max_uncompressed_bytes=1 << 20)
    assert info.value.field == "positions"


def test_npz_entry_whose_header_lies_about_its_shape_is_refused() -> None:
    header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000, 3), }"
    header = header + " " * (63 - len(header) % 64) + "\n"
    npy = b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + bytes(48)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("positions.npy", npy)
    with pytest.raises(InputError) as info:
        decode_npz_frame(buffer.getvalue(), max_particles=10**7, max_uncompressed_bytes=1 << 30)
    assert info.value.field == "positions"
    assert "declares shape" in info.value.message


@pytest.mark.parametrize(
    ("body", "field"),
    [
        (b"", "body"),
        (b"positions,1,2,3", "body"),
        (b"PK\x03\x04" + bytes(40), "body"),
    ],
)
def test_npz_garbage_bodies(body: bytes, field: str) -> None:
    with pytest.raises(InputError) as info:
        decode_npz_frame(body, max_particles=10, max_uncompressed_bytes=1 << 20)
    assert info.value.field == field


def test_npz_truncated_body_is_an_input_error() -> None:
    body = encode_npz_frame(np.zeros((100, 3)))
    for cut in (len(body) // 3, len(body) // 2, len(body) - 10):
        with pytest.raises(InputError):
            decode_npz_frame(body[:cut], max_particles=1000, max_uncompressed_bytes=1 << 20)


def test_npz_without_positions_names_what_it_has() -> None:
    buffer = io.BytesIO()
    np.savez(buffer, points=np.zeros((2, 3)))
    with pytest.raises(InputError) as info:
        decode_npz_frame(buffer.getvalue(), max_particles=10, max_uncompressed_bytes=1 << 20)
    assert info.value.field == "positions"
    assert "points" in info.value.message


def _doc_example(name: str) -> bytes:
    """The bytes of a hex example in PROTOCOL.md (`<!-- example: name -->` + a hexdump)."""
    text = (Path(__file__).resolve().parents[1] / "PROTOCOL.md").read_text()
    block = text.split(f"<!-- example: {name} -->", 1)[1].split("```text\n", 1)[1]
    block = block.split("```", 1)[0]
    return bytes.fromhex("".join(line[6:54] for line in block.splitlines()))


def test_protocol_md_examples_are_what_the_codec_writes() -> None:
    hello = {"scene": {"image": {"width": 64, "height": 48}}, "mode": "queue"}
    hello["token"] = "0123456789abcdef"
    assert _doc_example("hello") == encode_message(MessageType.HELLO, hello)
    positions = np.array([[0.0, 0.5, -1.0], [1.0, 2.0, 3.0]])
    radii = np.array([0.02, 0.03], dtype=np.float32)
    assert _doc_example("frame") == encode_frame(7, positions, radii=radii)
    dropped = {"id": 7, "reason": "superseded"}
    assert _doc_example("dropped") == encode_message(MessageType.DROPPED, dropped)
    assert _doc_example("bye") == encode_message(MessageType.BYE, {})
