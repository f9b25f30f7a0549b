"""The compact frame encoding (core/compact.py, PROTOCOL.md §4.7) without a server: the error
bound holds exactly on random and adversarial values, frame prediction round-trips, and every
malformed header or payload is refused with an error naming the field, in plain words."""

from __future__ import annotations

import copy
import json
from typing import Any

import numpy as np
import pytest
import zstandard
from error_texts import text_faults
from test_protocol import _doc_example

from sphrender.core.compact import CompactDecoder
from sphrender.core.compact_encoder import CompactEncoder
from sphrender.core.errors import InputError
from sphrender.core.protocol import (
    PREFIX_SIZE,
    MessageType,
    encode_message,
    parse_header,
    parse_prefix,
)

MAX = 1_000_000


def roundtrip(arrays: dict[str, np.ndarray], error: float, **kw: Any) -> dict[str, np.ndarray]:
    """Encoded, decoded and put back in the given order by the encoder's `order`."""
    encoder = CompactEncoder(position_error=error, **kw)
    header, payload = encoder.encode(1, arrays)
    json.loads(json.dumps(header))  # the header is plain JSON
    return as_given(CompactDecoder().decode(header, payload, max_particles=MAX), encoder.order)


def as_given(decoded: dict[str, np.ndarray], order: np.ndarray | None) -> dict[str, np.ndarray]:
    """Decoded arrays with particle ``order[j]`` (sent j-th) back at index ``order[j]``."""
    if order is None:
        return decoded
    assert sorted(order.tolist()) == list(range(len(order)))  # a permutation
    back = {}
    for name, array in decoded.items():
        back[name] = np.empty_like(array)
        back[name][order] = array
    return back


def max_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.float64) - b.astype(np.float64)).max(initial=0.0))


# Every case: max |decoded - original| <= the bound, exactly (no tolerance: it is a guarantee).
CASES = {
    "unit cube": (np.random.default_rng(0).random((5000, 3)), 1e-4),
    "far from the origin, 1e5": (1e5 + np.random.default_rng(1).random((5000, 3)), 1e-6),
    "mixed signs, 1e5 span": (np.random.default_rng(2).uniform(-1e5, 1e5, (5000, 3)), 1e-3),
    "one particle": (np.array([[3.0, -2.0, 1e5]]), 1e-5),
    "no particles": (np.zeros((0, 3)), 1e-3),
    "all equal": (np.full((100, 3), 7.25), 1e-3),
    "exact half steps": (np.arange(3000, dtype=np.float64).reshape(-1, 3) * 1e-4 + 5e-5, 1e-4),
    "denormals and zeros": (np.array([[0.0, 5e-324, -5e-324], [1e-300, 0.0, 1.0]]), 1e-9),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_position_error_bound_holds_exactly(name: str) -> None:
    positions, bound = CASES[name]
    decoded = roundtrip({"positions": positions}, bound)["positions"]
    assert decoded.dtype == np.float64 and decoded.shape == positions.shape
    assert max_error(decoded, positions) <= bound


def test_float32_arrays_hold_their_bound_after_the_cast() -> None:
    """Values a half step apart whose float32 rounding would push them past the bound: the
    encoder leaves room for the cast (1800.25 K at 0.05 K was such a value)."""
    rng = np.random.default_rng(3)
    temperatures = (1800 + rng.random(20000) * 10).astype(np.float32)
    temperatures[:100] = np.float32(1800.25)
    densities = (1000 + rng.normal(0, 5, 20000)).astype(np.float32)
    velocities = rng.normal(0, 2, (20000, 3)).astype(np.float32)
    arrays: dict[str, np.ndarray] = {
        "positions": rng.random((20000, 3)),
        "temperatures": temperatures,
        "densities": densities,
        "velocities": velocities,
    }
    decoded = roundtrip(arrays, 1e-4)
    assert max_error(decoded["temperatures"], temperatures) <= 0.05
    assert max_error(decoded["densities"], densities) <= 0.05
    assert max_error(decoded["velocities"], velocities) <= 1e-3
    assert decoded["temperatures"].dtype == np.float32


def test_running_sums_of_wide_residuals_hold_the_bound() -> None:
    """Particle-to-particle residuals of 4 bytes, summed in int64 (n times the largest could
    pass 2^31), and 1-byte ones beside them, summed in int32 (no sum can wrap)."""
    rng = np.random.default_rng(4)
    positions = rng.uniform(0, 1e4, (5000, 3))  # in random order: residuals up to ~1e8 steps
    temperatures = (1500 + np.cumsum(rng.normal(0, 0.2, 5000))).astype(np.float32)
    arrays: dict[str, np.ndarray] = {"positions": positions, "temperatures": temperatures}
    decoded = roundtrip(arrays, 1e-4, reorder=False)
    assert max_error(decoded["positions"], positions) <= 1e-4
    assert max_error(decoded["temperatures"], temperatures) <= 0.05


def test_an_empty_frame_round_trips_with_every_array() -> None:
    arrays: dict[str, np.ndarray] = {
        "positions": np.zeros((0, 3)),
        "densities": np.zeros(0, np.float32),
        "velocities": np.zeros((0, 3), np.float32),
        "ids": np.zeros(0, np.int64),
    }
    decoded = roundtrip(arrays, 1e-3)
    assert {k: (v.shape, v.dtype) for k, v in decoded.items()} == {
        k: (v.shape, v.dtype) for k, v in arrays.items()
    }


def test_lossless_arrays_are_bit_exact() -> None:
    rng = np.random.default_rng(4)
    arrays = {
        "positions": rng.random((500, 3)),
        "radii": rng.random(500).astype(np.float32) + 0.01,
        "ids": rng.permutation(10**6)[:500].astype(np.int64),
    }
    decoded = roundtrip(arrays, 1e-3)
    assert decoded["radii"].tobytes() == arrays["radii"].tobytes()
    assert decoded["ids"].tobytes() == arrays["ids"].tobytes()


def test_frame_prediction_round_trips_a_sequence() -> None:
    rng = np.random.default_rng(5)
    encoder, decoder = CompactEncoder(position_error=1e-4), CompactDecoder()
    positions = rng.random((4000, 3))
    predicted = 0
    for frame_id in range(5):
        positions = positions + rng.normal(0, 2e-4, positions.shape)  # small steps: predictable
        header, payload = encoder.encode(frame_id, {"positions": positions})
        predicted += header["arrays"][0]["predict"] in ("frame", "motion")
        decoded = decoder.decode(header, payload, max_particles=MAX)
        assert max_error(as_given(decoded, encoder.order)["positions"], positions) <= 1e-4
    assert predicted == 4  # every frame after the first


def test_motion_prediction_round_trips_a_flow() -> None:
    """A shear flow (up to 0.02 a frame, 100 quanta, varying along x) over particles in x
    order, plus a little noise: each particle moves as the one before it, so ``motion`` is
    chosen (a uniform translation would not do: the frame's bounds move with it)."""
    rng = np.random.default_rng(8)
    encoder, decoder = CompactEncoder(position_error=1e-4), CompactDecoder()
    positions = rng.random((4000, 3))
    positions = positions[np.argsort(positions[:, 0])]
    for frame_id in range(4):
        x = positions[:, :1]
        flow = 0.02 * np.hstack([np.zeros_like(x), np.sin(6 * x), np.cos(6 * x)])
        positions = positions + flow + rng.normal(0, 2e-5, positions.shape)
        header, payload = encoder.encode(frame_id, {"positions": positions})
        if frame_id:
            assert header["arrays"][0]["predict"] == "motion"
        decoded = decoder.decode(header, payload, max_particles=MAX)
        assert max_error(as_given(decoded, encoder.order)["positions"], positions) <= 1e-4


def encoded(n: int = 200, **kw: Any) -> tuple[dict[str, Any], bytes]:
    rng = np.random.default_rng(6)
    arrays = {"positions": rng.random((n, 3)), "densities": 1000 + rng.random(n).astype("f4")}
    return CompactEncoder(position_error=1e-4, **kw).encode(3, arrays)


def refused(header: dict[str, Any], payload: bytes, decoder: CompactDecoder | None = None) -> str:
    with pytest.raises(InputError) as caught:
        (decoder or CompactDecoder()).decode(header, payload, max_particles=MAX)
    assert not text_faults(caught.value.message), caught.value.message
    return f"{caught.value.field}: {caught.value.message}"


def edited(header: dict[str, Any], index: int, **changes: Any) -> dict[str, Any]:
    copied = copy.deepcopy(header)
    copied["arrays"][index].update(changes)
    return copied


def test_truncated_and_corrupted_payloads_are_refused() -> None:
    header, payload = encoded()
    message = refused(header, payload[:-1])  # the last array no longer fits
    assert message.startswith("arrays[1].bytes: ") and f"payload has {len(payload) - 1}" in message
    assert refused(header, payload + b"\0").startswith("payload_length: ")
    first = header["arrays"][0]["bytes"]
    damaged = bytearray(payload)
    damaged[first // 2 : first // 2 + 8] = b"\xff" * 8
    message = refused(header, bytes(damaged))
    assert message.startswith("arrays[0].bytes: ") and "damaged" in message
    garbage = edited(header, 0)
    assert refused(garbage, b"\x00" * len(payload)).startswith("arrays[0].bytes: ")


def test_bytes_after_an_arrays_zstd_frame_are_refused() -> None:
    """`bytes` is the length of the array's zstd frame (PROTOCOL.md 4.7): a section that holds
    more (junk, or a second frame) is refused naming the array, not silently cut."""
    header, payload = encoded()
    first = header["arrays"][0]["bytes"]
    for extra in (b"\x00\x01\x02", payload[:first]):
        longer = edited(header, 0, bytes=first + len(extra))
        message = refused(longer, payload[:first] + extra + payload[first:])
        assert message.startswith("arrays[0].bytes: "), message


def test_sizes_that_lie_are_refused_before_inflating() -> None:
    header, payload = encoded()
    # The header's width says fewer bytes than the zstd frame holds (and the reverse).
    width = header["arrays"][0]["width"]
    for other in {1, 2, 4, 8} - {width}:
        message = refused(edited(header, 0, width=other), payload)
        assert message.startswith("arrays[0].bytes: ") and "zstd frame declares" in message
    # A bomb: 200 particles declared, a frame that inflates to 1 GB of zeros (its size declared).
    bomb = zstandard.ZstdCompressor(write_checksum=True).compress(bytes(1 << 24))
    first = header["arrays"][0]["bytes"]
    lying = edited(header, 1, bytes=len(bomb))
    message = refused(lying, payload[:first] + bomb)
    assert message.startswith("arrays[1].bytes: ") and "declares 16777216 bytes" in message
    no_size = zstandard.ZstdCompressor(write_content_size=False, write_checksum=True)
    unsized = no_size.compress(bytes(800))
    message = refused(edited(header, 1, bytes=len(unsized)), payload[:first] + unsized)
    assert "zstd frame declares no size" in message
    unchecked = zstandard.ZstdCompressor().compress(bytes(800))
    message = refused(edited(header, 1, bytes=len(unchecked)), payload[:first] + unchecked)
    assert "no checksum" in message
    # The declared bytes of one array run past the payload.
    message = refused(edited(header, 0, bytes=len(payload) + 1), payload)
    assert message.startswith("arrays[0].bytes: ") and "payload has" in message
    # Over the particle limit: refused from the header alone.
    big = copy.deepcopy(header)
    for spec in big["arrays"]:
        spec["shape"][0] = MAX + 1
    assert refused(big, payload).startswith("arrays[0].shape: ")


@pytest.mark.parametrize("step", [0, -1e-4, float("nan"), float("inf"), "0.1", None])
def test_steps_that_are_not_positive_numbers_are_refused(step: object) -> None:
    header, payload = encoded()
    message = refused(edited(header, 0, step=step), payload)
    assert message.startswith("arrays[0].step: must be a finite number > 0")


@pytest.mark.parametrize("error", [0.0, -1e-3, float("nan"), float("inf")])
def test_encoder_refuses_error_bounds_that_are_not_positive(error: float) -> None:
    with pytest.raises(InputError) as caught:
        CompactEncoder(position_error=error)
    assert caught.value.field == "errors.positions"
    assert "must be a finite error bound > 0" in caught.value.message
    with pytest.raises(InputError) as caught:
        CompactEncoder(position_error=1e-3, errors={"densities": error})
    assert caught.value.field == "errors.densities"


def test_bounds_that_do_not_contain_the_particles_are_refused() -> None:
    header, payload = encoded()
    lo, hi = header["arrays"][0]["bounds"]
    shrunk = edited(header, 0, bounds=[lo, [hi[0] - 0.1, hi[1], hi[2]]])
    message = refused(shrunk, payload)
    assert message.startswith("positions[") and "outside arrays[0].bounds" in message
    inverted = edited(header, 0, bounds=[hi, lo])
    assert refused(inverted, payload).startswith("arrays[0].bounds[1][0]: ")
    assert refused(edited(header, 0, bounds=[lo]), payload).startswith("arrays[0].bounds: ")
    # The encoder refuses bounds given to it that leave particles out, naming the first.
    positions = np.array([[0.0, 0.0, 0.0], [2.0, 0.5, 0.5]])
    box = (np.zeros(3), np.ones(3))
    with pytest.raises(InputError) as caught:
        CompactEncoder(position_error=1e-3, bounds=box).encode(0, {"positions": positions})
    assert caught.value.field == "positions[1]" and "outside the bounds" in caught.value.message


def test_a_bound_finer_than_float64_resolves_is_refused() -> None:
    with pytest.raises(InputError) as caught:
        CompactEncoder(position_error=1e-13).encode(0, {"positions": np.full((2, 3), 1e5)})
    assert caught.value.field == "errors.positions" and "use a larger bound" in caught.value.message


def test_unknown_keys_codings_and_predictors_are_named() -> None:
    header, payload = encoded()
    assert refused(edited(header, 0, colour=1), payload).startswith("arrays[0].colour: ")
    assert refused(edited(header, 0, coding="zfp"), payload).startswith("arrays[0].coding: ")
    assert refused(edited(header, 0, predict="x"), payload).startswith("arrays[0].predict: ")
    assert refused(edited(header, 0, width=3), payload).startswith("arrays[0].width: ")
    raw_step = edited(header, 1, coding="raw")
    assert refused(raw_step, payload).startswith("arrays[1].")


def test_a_base_the_decoder_does_not_hold_is_named() -> None:
    encoder = CompactEncoder(position_error=1e-4)
    rng = np.random.default_rng(7)
    positions = rng.random((300, 3))
    first = encoder.encode(10, {"positions": positions})
    second = encoder.encode(11, {"positions": positions + 1e-5})
    assert second[0]["base"] == 10
    message = refused(*second)
    assert message.startswith("base: frame 10 is not held") and "send this frame in full" in message
    decoder = CompactDecoder()
    decoder.decode(*first, max_particles=MAX)
    wrong = {**second[0], "base": 9}
    message = refused(wrong, second[1], decoder)
    assert message.startswith("base: frame 9 is not held") and "frame 10" in message


def test_protocol_md_compact_example_decodes_as_documented() -> None:
    data = _doc_example("compact")
    kind, header_len, payload_len = parse_prefix(
        data[:PREFIX_SIZE], max_header_bytes=1 << 16, max_payload_bytes=1 << 20
    )
    assert kind == MessageType.FRAME
    header = parse_header(data[PREFIX_SIZE : PREFIX_SIZE + header_len])
    payload = data[PREFIX_SIZE + header_len :]
    assert len(payload) == payload_len
    arrays = CompactDecoder().decode(header, payload, max_particles=MAX)
    # PROTOCOL.md §7: positions (0, 0.5, -1) and (1, 2, 3) within 0.001, radii 0.02, 0.03 exact.
    expected = np.array([[0.0, 0.5, -1.0], [1.0, 2.0, 3.0]])
    assert max_error(arrays["positions"], expected) <= 0.001
    assert arrays["radii"].tolist() == np.array([0.02, 0.03], np.float32).tolist()
    assert data == example_message()


def example_message() -> bytes:
    positions = np.array([[0.0, 0.5, -1.0], [1.0, 2.0, 3.0]])
    radii = np.array([0.02, 0.03], np.float32)
    encoder = CompactEncoder(
        position_error=0.001, errors={"radii": None}, delta=False, reorder=False
    )
    header, payload = encoder.encode(7, {"positions": positions, "radii": radii})
    return encode_message(MessageType.FRAME, header, payload)
