"""Fuzz inputs of the compact frame encoding (PROTOCOL.md §4.7), for tests/fuzz_inputs.py: a
valid compact FRAME (from the real encoder) with one thing wrong in its header or its payload:
the descriptors' keys (coding, step, bounds, predict, width, bytes, and the order-free cells'
cell_bits, grid_bits, cells, count_width), the base, the encoding's name, the zstd frames
(bytes flipped, cut, swapped for a bomb or a frame without its size or checksum, or inflated,
changed and compressed again so that the checksum holds and the decoder's own checks meet the
change: gaps, counts, offsets), the declared shapes. Seeded like the rest: a failure is
reproduced by its seed."""

from __future__ import annotations

import copy
import random
from typing import Any

import numpy as np
import zstandard

from sphrender.core.compact_encoder import CompactEncoder
from sphrender.core.frame_message import FRAME_CONTENT_TYPE
from sphrender.core.protocol import MessageType, encode_message

_KEYS = ("coding", "step", "bounds", "predict", "width", "bytes", "dtype", "shape", "name",
         "cell_bits", "grid_bits", "cells", "count_width")  # fmt: skip


def _valid(rng: random.Random, frame_id: int) -> tuple[dict[str, Any], bytes]:
    n = rng.choice((0, 1, 2, 7, 50, 300))
    numbers = np.random.default_rng(rng.randrange(1 << 30))
    arrays: dict[str, np.ndarray] = {"positions": numbers.normal(size=(n, 3)) * 0.1}
    if rng.random() < 0.5:
        arrays["densities"] = (1000 + numbers.normal(0, 5, n)).astype(np.float32)
    if rng.random() < 0.3:
        arrays["radii"] = np.full(n, 0.02, np.float32)
    if rng.random() < 0.2:
        arrays["ids"] = numbers.permutation(10 * n + 1)[:n].astype(np.int64)
    error = rng.choice((1e-4, 2e-4, 1e-3, 0.01))
    encoder = CompactEncoder(position_error=error, reorder=rng.random() < 0.8)
    if rng.random() < 0.3 and n:  # a frame predicted from one the server may not hold
        encoder.encode(frame_id - 1, arrays)
        arrays["positions"] = arrays["positions"] + 1e-5
    return encoder.encode(frame_id, arrays)


def _spoil_payload(rng: random.Random, header: dict[str, Any], payload: bytes) -> bytes:
    roll = rng.random()
    if roll < 0.4 and payload:
        spoiled = bytearray(payload)
        for _ in range(rng.randrange(1, 5)):
            spoiled[rng.randrange(len(spoiled))] = rng.randrange(256)
        return bytes(spoiled)
    if roll < 0.6:
        return payload[: rng.randrange(len(payload) + 1)] + bytes(rng.randrange(0, 9))
    if roll < 0.8:
        return _respoiled(rng, header, payload)
    # Swap the first array's zstd frame for another one, its `bytes` kept true.
    size = rng.choice((1 << 20, 1 << 24, 7))
    other = zstandard.ZstdCompressor(
        write_content_size=rng.random() < 0.7, write_checksum=rng.random() < 0.7
    ).compress(bytes(size))
    first = header["arrays"][0]["bytes"]
    header["arrays"][0]["bytes"] = len(other)
    return other + payload[first:]


def _respoiled(rng: random.Random, header: dict[str, Any], payload: bytes) -> bytes:
    """One array's zstd frame inflated, a few bytes changed, compressed again (size and
    checksum true): what gets past zstd reaches the decoder's checks of the values."""
    index = rng.randrange(len(header["arrays"]))
    start = sum(spec["bytes"] for spec in header["arrays"][:index])
    end = start + header["arrays"][index]["bytes"]
    raw = bytearray(zstandard.ZstdDecompressor().decompress(payload[start:end]))
    for _ in range(rng.randrange(1, 4) if raw else 0):
        raw[rng.randrange(len(raw))] = rng.choice((0, 1, 255, rng.randrange(256)))
    packed = zstandard.ZstdCompressor(write_checksum=True).compress(bytes(raw))
    header["arrays"][index]["bytes"] = len(packed)
    return payload[:start] + packed + payload[end:]


def compact_frame_input(rng: random.Random, frame_id: int, weird: Any) -> bytes:
    """A compact FRAME with one thing wrong (`weird(rng)` gives an odd JSON value)."""
    header, payload = _valid(rng, frame_id)
    header = copy.deepcopy(header)
    roll = rng.random()
    if roll < 0.45:
        spec = rng.choice(header["arrays"])
        spec[rng.choice(_KEYS)] = weird(rng)
    elif roll < 0.55:
        header[rng.choice(("base", "encoding", "arrays"))] = weird(rng)
    elif roll < 0.65:
        lo, hi = header["arrays"][0]["bounds"]
        header["arrays"][0]["bounds"] = rng.choice(([hi, lo], [lo, lo], [lo], [[0, 0], hi]))
    elif roll < 0.9:
        payload = _spoil_payload(rng, header, payload)
    else:
        for spec in header["arrays"]:
            spec["shape"][0] = rng.choice((10**6, 10**9, 2**40))
    return encode_message(MessageType.FRAME, header, payload)


def compact_http_request(rng: random.Random, frame_id: int, weird: Any, scene: Any) -> bytes:
    """A POST /v1/render of a compact FRAME body (application/x-sphrender-frame)."""
    message = compact_frame_input(rng, frame_id, weird)
    if rng.random() < 0.3:  # the prefix itself wrong: type, lengths
        spoiled = bytearray(message)
        spoiled[rng.choice((5, 8, 12, 13))] = rng.randrange(256)
        message = bytes(spoiled)
    elif rng.random() < 0.5:  # valid (but for a base, which HTTP refuses), with a scene
        header, payload = _valid(rng, frame_id)
        message = encode_message(MessageType.FRAME, {**header, "scene": scene}, payload)
    head = (
        f"POST /v1/render HTTP/1.1\r\nHost: x\r\nContent-Type: {FRAME_CONTENT_TYPE}\r\n"
        f"Content-Length: {len(message)}\r\n\r\n"
    )
    return head.encode() + message
