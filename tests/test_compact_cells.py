"""Order-free positions in the compact encoding (``predict: "cells"``, core/compact_cells.py,
PROTOCOL.md §4.7): the cell coding round-trips exactly, every array travels with its particle,
sessions predict from the frame as the server decoded it, malformed cell layouts are refused
naming the field, and a reordered frame renders as the same particles sent in order."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest
import zstandard
from error_texts import text_faults
from test_protocol import _doc_example

from sphrender.core.compact import CompactDecoder, _planes
from sphrender.core.compact_cells import CellLayout, cells_layout, decode_cells, encode_cells
from sphrender.core.compact_encoder import CompactEncoder
from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.core.protocol import (
    PREFIX_SIZE,
    MessageType,
    encode_message,
    parse_header,
    parse_prefix,
)
from sphrender.server.bench.surface_quality import flicker_deg
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

RADIUS = 0.02
ERROR = RADIUS / 100
MAX = 1_000_000


def fluid(n: int = 6000, seed: int = 0) -> np.ndarray:
    """A block of SPH-like fluid: a lattice of spacing 2r, each particle jittered by 0.3 r."""
    side = int(np.ceil(n ** (1 / 3)))
    grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:n]
    rng = np.random.default_rng(seed)
    return grid * 2 * RADIUS + rng.normal(0, 0.3 * RADIUS, (n, 3)) + [0.1, -0.2, 0.3]


def every_array(positions: np.ndarray, seed: int = 1) -> dict[str, np.ndarray]:
    n, rng = len(positions), np.random.default_rng(seed)
    return {
        "positions": positions,
        "densities": (1000 + rng.normal(0, 5, n)).astype(np.float32),
        "temperatures": (1500 + 300 * positions[:, 1]).astype(np.float32),
        "velocities": rng.normal(0, 1, (n, 3)).astype(np.float32),
        "radii": np.full(n, RADIUS, np.float32),
        "ids": rng.permutation(10 * n)[:n].astype(np.int64),
        "solid": (rng.random(n) < 0.1).astype(np.uint8),
    }


def test_the_cell_coding_round_trips_quantised_positions_exactly() -> None:
    """From cells of one quantum (one particle each) to cells holding everything (counts > 1),
    on random, clustered and coincident integers: decode(encode(q)) is q in the order sent."""
    rng = np.random.default_rng(2)
    cases = [
        rng.integers(0, 2**20, (3, 3000)),
        rng.integers(0, 40, (3, 3000)),  # many particles per cell at every size
        np.repeat(rng.integers(0, 2**30, (3, 1)), 50, axis=1),  # one point 50 times
        np.array([[0], [2**40], [5]]),
    ]
    for q in cases:
        for bits in (1, 3, 7, 8, 12, 16):
            made = encode_cells(q.astype(np.int64), bits)
            if made is None:  # refused only when the cell numbers would pass 62 bits
                assert sum(int(v >> bits).bit_length() for v in q.max(axis=1)) > 62
                continue
            order, spec, raw = made
            assert sorted(order.tolist()) == list(range(q.shape[1]))
            layout = _layout(spec, q.shape[1])
            assert len(raw) == layout.raw_size(q.shape[1])
            assert np.array_equal(decode_cells(layout, 0, raw, q.shape[1]), q[:, order])


def _layout(spec: dict[str, Any], particles: int) -> CellLayout:
    return cells_layout("arrays[0]", spec, particles)


def test_a_fluid_goes_out_order_free_and_every_array_travels_with_its_particle() -> None:
    arrays = every_array(fluid())
    encoder = CompactEncoder(position_error=ERROR)
    header, payload = encoder.encode(0, arrays)
    assert header["arrays"][0]["predict"] == "cells"
    in_order = CompactEncoder(position_error=ERROR, reorder=False).encode(0, arrays)
    assert len(payload) < len(in_order[1])
    decoded = CompactDecoder().decode(header, payload, max_particles=MAX)
    order = encoder.order
    assert order is not None and sorted(order.tolist()) == list(range(len(order)))
    # Lossless arrays are the given ones, permuted; lossy ones within their bounds of them.
    for name in ("ids", "radii", "solid"):
        assert decoded[name].tobytes() == arrays[name][order].tobytes(), name
    for name, bound in (("positions", ERROR), ("densities", 0.05), ("temperatures", 0.05),
                        ("velocities", 1e-3)):  # fmt: skip
        assert np.abs(decoded[name] - arrays[name][order]).max() <= bound, name
    # The same quantisation as the ordered coding: the same values, in another order.
    ordered = CompactDecoder().decode(*in_order, max_particles=MAX)
    assert np.array_equal(ordered["positions"][order], decoded["positions"])


def test_reorder_false_keeps_the_order() -> None:
    encoder = CompactEncoder(position_error=ERROR, reorder=False)
    header, _payload = encoder.encode(0, every_array(fluid()))
    assert header["arrays"][0]["predict"] == "particle" and encoder.order is None


def test_a_session_predicts_from_the_frame_as_the_server_decoded_it() -> None:
    """Frame 0 goes out order-free; frames 1-3 move a little and are predicted from the frame
    before in its sent order; frame 4 is another fluid (no prediction pays): reordered afresh."""
    rng = np.random.default_rng(3)
    positions = fluid(4000)
    encoder, decoder = CompactEncoder(position_error=ERROR), CompactDecoder()
    kinds = []
    for frame_id in range(5):
        if frame_id == 4:
            positions = fluid(4000, seed=9)[::-1]
        positions = positions + rng.normal(0, 0.02 * ERROR, positions.shape)
        arrays = every_array(positions, seed=frame_id)
        header, payload = encoder.encode(frame_id, arrays)
        kinds.append(header["arrays"][0]["predict"])
        decoded = decoder.decode(header, payload, max_particles=MAX)
        order = encoder.order
        assert order is not None
        assert np.abs(decoded["positions"] - positions[order]).max() <= ERROR
        assert np.array_equal(decoded["ids"], arrays["ids"][order])
    assert kinds[0] == "cells" and kinds[4] == "cells"
    assert all(kind in ("frame", "motion") for kind in kinds[1:4]), kinds


def cells_frame(n: int = 500) -> tuple[dict[str, Any], bytes]:
    header, payload = CompactEncoder(position_error=ERROR).encode(3, {"positions": fluid(n)})
    assert header["arrays"][0]["predict"] == "cells"
    assert header["arrays"][0]["cells"] == n - 1  # one cell holds two particles
    return header, payload


def refused(header: dict[str, Any], payload: bytes) -> str:
    with pytest.raises(InputError) as caught:
        CompactDecoder().decode(header, payload, max_particles=MAX)
    assert not text_faults(caught.value.message), caught.value.message
    return f"{caught.value.field}: {caught.value.message}"


def edited(header: dict[str, Any], **changes: Any) -> dict[str, Any]:
    copied = copy.deepcopy(header)
    copied["arrays"][0].update(changes)
    return copied


@pytest.mark.parametrize(
    ("changes", "field", "words"),
    [
        ({"cell_bits": 0}, "arrays[0].cell_bits", "from 1 to 16"),
        ({"cell_bits": 17}, "arrays[0].cell_bits", "from 1 to 16"),
        ({"cell_bits": "6"}, "arrays[0].cell_bits", "integer"),
        ({"grid_bits": [4, 4]}, "arrays[0].grid_bits", "3 integers"),
        ({"grid_bits": [40, 40, -1]}, "arrays[0].grid_bits[2]", "from 0 to"),
        ({"grid_bits": [30, 30, 30]}, "arrays[0].grid_bits", "at most 62"),
        ({"cells": 501}, "arrays[0].cells", "from 1 to 500"),
        ({"count_width": None}, "arrays[0].count_width", "when cells < particles"),
        ({"cells": 500}, "arrays[0].count_width", "only for fewer cells"),
        ({"predict": "particle"}, "arrays[0].cell_bits", "only for predict cells"),
    ],
)
def test_malformed_cell_layouts_are_named(changes: dict[str, Any], field: str, words: str) -> None:
    header, payload = cells_frame()
    message = refused(edited(header, **changes), payload)
    assert message.startswith(f"{field}: ") and words in message, message


def test_cells_on_an_array_that_is_not_positions_is_refused() -> None:
    header, payload = CompactEncoder(position_error=ERROR).encode(
        0, {"positions": fluid(50), "densities": np.full(50, 1000.0, np.float32)}
    )
    message = refused(edited_at(header, 1, predict="cells", cell_bits=4, grid_bits=[1, 1, 1],
                                cells=50), payload)  # fmt: skip
    assert message.startswith("arrays[1].predict: cells codes [N, 3] positions only"), message


def edited_at(header: dict[str, Any], index: int, **changes: Any) -> dict[str, Any]:
    copied = copy.deepcopy(header)
    copied["arrays"][index].update(changes)
    return copied


def _section(gaps: list[int], counts: list[int] | None, offsets: np.ndarray) -> bytes:
    raw = _planes(np.array(gaps), 1)
    if counts is not None:
        raw += _planes(np.array(counts), 1)
    return zstandard.ZstdCompressor(write_checksum=True).compress(raw + _planes(offsets, 1))


def _hand_made(gaps: list[int], counts: list[int] | None, offsets: np.ndarray,
               grid: list[int], hi: float = 1.0) -> tuple[dict[str, Any], bytes]:  # fmt: skip
    """A 4-particle cells frame built by hand (cell_bits 2, step 0.01)."""
    payload = _section(gaps, counts, offsets)
    spec: dict[str, Any] = {
        "name": "positions", "dtype": "<f8", "shape": [4, 3], "coding": "quantized",
        "step": 0.01, "bounds": [[0.0] * 3, [hi] * 3], "predict": "cells", "cell_bits": 2,
        "grid_bits": grid, "cells": len(gaps), "width": 1, "bytes": len(payload),
    }  # fmt: skip
    if counts is not None:
        spec["count_width"] = 1
    return {"id": 1, "encoding": "compact", "arrays": [spec]}, payload


def test_hand_made_cell_sections_decode_or_are_refused_naming_the_field() -> None:
    offsets = np.array([[0, 1, 2, 3], [3, 2, 1, 0], [1, 1, 1, 1]])
    # Cells 1 (z = 1) holding two particles and 3 (y = 1, z = 1) holding two: q = c * 4 + o.
    header, payload = _hand_made([1, 2], [2, 2], offsets, [1, 1, 1])
    decoded = CompactDecoder().decode(header, payload, max_particles=MAX)["positions"]
    cells = np.array([[0, 0, 1], [0, 0, 1], [0, 1, 1], [0, 1, 1]])
    assert np.array_equal(decoded, (cells * 4 + offsets.T) * 0.01)
    cases = [
        (([1, 2], [1, 2], offsets, [1, 1, 1]), "arrays[0].cells", "sum to 4 particles"),
        (([1, 2], [0, 4], offsets, [1, 1, 1]), "arrays[0].cells", "each be >= 1"),
        (([1, 7], [2, 2], offsets, [1, 1, 1]), "arrays[0].cells", "past the grid's 3 bits"),
        (([1, 2], [2, 2], offsets + 4, [1, 1, 1]), "arrays[0].cell_bits", "not below 2^2"),
        (([1, 2, 1, 1], None, offsets, [1, 1, 2]), "positions[", "outside arrays[0].bounds"),
    ]
    for (gaps, counts, offs, grid), field, words in cases:
        header, payload = _hand_made(gaps, counts, offs, grid, hi=0.05)
        message = refused(header, payload)
        assert message.startswith(field) and words in message, message


def test_a_reordered_frame_renders_as_the_same_particles(renderer: SurfaceRenderer) -> None:
    """The decoded set equals the ordered coding's (same quantisation): rendered, the two differ
    only by the order of float sums (at most one 8-bit code on a few pixels, measured 0). Against
    the raw float64 frame the normals turn by the quantisation: an impostor's normal turns by
    d/r for a centre moved d across the view, and a uniform error in [-b, b] per axis gives a
    mean |d| of 0.765 b, 0.44 degrees at b = r/100; twice that is the tolerance."""
    positions = fluid(4000)
    scene = scene_from_dict({
        "image": {"width": 128, "height": 96}, "particles": {"radius": RADIUS},
        "camera": {"eye": [0.9, 0.6, 1.3], "target": [0.4, 0.1, 0.6], "fov_y": 40},
    })  # fmt: skip
    encoder = CompactEncoder(position_error=ERROR)
    header, payload = encoder.encode(0, {"positions": positions})
    assert header["arrays"][0]["predict"] == "cells"
    reordered = CompactDecoder().decode(header, payload, max_particles=MAX)["positions"]
    in_order = CompactEncoder(position_error=ERROR, reorder=False).encode(
        0, {"positions": positions}
    )
    ordered = CompactDecoder().decode(*in_order, max_particles=MAX)["positions"]

    def render(p: np.ndarray) -> Any:
        return renderer.render(make_frame(p), scene, depth=True, normals=True)[0]

    raw, a, b = render(positions), render(reordered), render(ordered)
    assert (raw.rgba[..., 3] > 0.5).mean() > 0.2  # the block fills a good part of the image
    codes = [np.round(np.clip(x.rgba, 0, 1) * 255) for x in (a, b)]
    assert np.abs(codes[0] - codes[1]).max() <= 1
    assert (codes[0] != codes[1]).mean() <= 0.01
    mean, _p99 = flicker_deg(raw, a)
    assert mean <= 2 * np.degrees(0.765 / 100), mean


#: PROTOCOL.md §4.7's cells example: four particles whose quantised positions are A (0, 0, 0),
#: B (5, 1, 0), C (1, 2, 3) and D (6, 5, 2) at step 2 x 0.001 x (1 - 2^-30).
EXAMPLE_Q = np.array([[0, 0, 0], [5, 1, 0], [1, 2, 3], [6, 5, 2]])


def cells_example_message() -> bytes:
    """The example as the codec writes it: cells of 2^2 quanta, every zstd frame as the
    encoder compresses it."""
    step = 2 * 0.001 * (1 - 2.0**-30)
    positions = EXAMPLE_Q * step
    made = encode_cells(EXAMPLE_Q.T.astype(np.int64), 2)
    assert made is not None
    order, spec, raw = made
    assert order.tolist() == [0, 2, 1, 3]
    packed = zstandard.ZstdCompressor(level=3, write_content_size=True, write_checksum=True)
    section = packed.compress(raw)
    lo, hi = positions.min(axis=0).tolist(), positions.max(axis=0).tolist()
    descriptor = {"name": "positions", "dtype": "<f8", "shape": [4, 3], "coding": "quantized",
                  "step": step, "bounds": [lo, hi], **spec, "bytes": len(section)}  # fmt: skip
    header = {"id": 8, "encoding": "compact", "arrays": [descriptor]}
    return encode_message(MessageType.FRAME, header, section)


def test_protocol_md_cells_example_decodes_as_documented() -> None:
    data = _doc_example("compact-cells")
    assert data == cells_example_message()
    _kind, header_len, _payload_len = parse_prefix(
        data[:PREFIX_SIZE], max_header_bytes=1 << 16, max_payload_bytes=1 << 20
    )
    header = parse_header(data[PREFIX_SIZE : PREFIX_SIZE + header_len])
    decoded = CompactDecoder().decode(header, data[PREFIX_SIZE + header_len :], max_particles=MAX)[
        "positions"
    ]
    step = header["arrays"][0]["step"]
    # Sent in the order A, C, B, D: cell 0 holds A and C, cell 2 holds B, cell 3 holds D.
    assert np.array_equal(decoded, EXAMPLE_Q[[0, 2, 1, 3]] * step)


def test_the_same_particles_come_out_in_the_same_order_whatever_their_given_order() -> None:
    """Sorted by cell and then by offset: a solid part sent in any order (and among any fluid)
    decodes to the same bytes, so the server's surfel cache, keyed on them, still hits."""
    solid = fluid(600, seed=4)
    bounds = (np.full(3, -1.0), np.full(3, 2.0))  # fixed: the quantisation does not move
    decoded = []
    for seed in (5, 6):
        rng = np.random.default_rng(seed)
        spray = rng.uniform(0, 1, (300, 3))
        positions = np.concatenate([solid, spray])[rng.permutation(900)]
        flags = np.isin(np.arange(900), np.flatnonzero(np.isin(positions, solid).all(axis=1)))
        encoder = CompactEncoder(position_error=ERROR, bounds=bounds)
        header, payload = encoder.encode(0, {"positions": positions, "solid": flags.astype("u1")})
        assert header["arrays"][0]["predict"] == "cells"
        arrays = CompactDecoder().decode(header, payload, max_particles=MAX)
        decoded.append(arrays["positions"][arrays["solid"] == 1])
    assert len(decoded[0]) == 600 and decoded[0].tobytes() == decoded[1].tobytes()
