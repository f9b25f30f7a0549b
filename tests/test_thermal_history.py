"""Thermal history: `peak_temperatures` on every input path, and the service's running maximum
per particle id (new id = new history, vanished ids dropped, reordered ids matched)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from service_harness import ServerProcess, ball

from sphrender.client.api import Client
from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.core.npz_body import decode_npz_frame, encode_npz_frame
from sphrender.core.protocol import (
    PREFIX_SIZE,
    decode_frame_arrays,
    encode_frame,
    parse_header,
    parse_prefix,
)
from sphrender.core.readers import read_particles
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict
from sphrender.server.service.thermal_history import PeakHistory

TINT = scene_from_dict({"material": {"preset": "iron", "heat_tint": True}})


@pytest.mark.parametrize(
    ("arrays", "field", "words"),
    [
        ({"peak_temperatures": [1.0, 2.0]}, "peak_temperatures", "needs temperatures"),
        (
            {"temperatures": [1.0, 2.0], "peak_temperatures": [1.0, -2.0]},
            "peak_temperatures[1]",
            "must be finite and >= 0.0",
        ),
        (
            {"temperatures": [1.0, 2.0], "peak_temperatures": [np.nan, 2.0]},
            "peak_temperatures[0]",
            "must be finite",
        ),
        (
            {"temperatures": [1.0, 2.0], "peak_temperatures": [1.0]},
            "peak_temperatures",
            "has 1 entries but positions has 2",
        ),
    ],
)
def test_make_frame_refuses_bad_peaks(arrays: dict[str, object], field: str, words: str) -> None:
    with pytest.raises(InputError) as caught:
        make_frame(np.zeros((2, 3)), **arrays)  # type: ignore[arg-type]
    assert caught.value.field == field and words in caught.value.message


def test_peaks_round_trip_every_codec_and_reader(tmp_path: Path) -> None:
    positions = np.arange(9.0).reshape(3, 3)
    current = np.array([300.0, 400.0, 500.0])
    peak = np.array([900.0, 800.0, 700.0])
    body = encode_npz_frame(positions, temperatures=current, peak_temperatures=peak)
    npz = decode_npz_frame(body, max_particles=10, max_uncompressed_bytes=1 << 20)
    assert np.array_equal(npz.arrays["peak_temperatures"], peak.astype(np.float32))
    message = encode_frame(7, positions, temperatures=current, peak_temperatures=peak)
    _kind, header_len, _payload_len = parse_prefix(
        message[:PREFIX_SIZE], max_header_bytes=1 << 16, max_payload_bytes=1 << 20
    )
    header = parse_header(message[PREFIX_SIZE : PREFIX_SIZE + header_len])
    arrays = decode_frame_arrays(
        header["arrays"], message[PREFIX_SIZE + header_len :], max_particles=10
    )
    assert np.array_equal(arrays["peak_temperatures"], peak.astype(np.float32))
    np.savez(tmp_path / "f.npz", positions=positions, temperatures=current, peak_temperatures=peak)
    read = read_particles(tmp_path / "f.npz").peak_temperatures
    assert read is not None and np.array_equal(read, peak)
    (tmp_path / "f.csv").write_text("x,y,z,temperature,peak_temperature\n0,0,0,300,900\n")
    assert read_particles(tmp_path / "f.csv").peak_temperatures.tolist() == [900.0]  # type: ignore[union-attr]


def frame(ids: list[int], kelvin: list[float]) -> object:
    return make_frame(np.zeros((len(ids), 3)), temperatures=kelvin, ids=ids)


@pytest.mark.parametrize("spread", [1, 10**12])  # dense ids (table) and sparse ids (sorted)
def test_running_maximum_follows_ids(spread: int) -> None:
    history = PeakHistory()
    a, b, c, d = (spread * k for k in (1, 2, 3, 4))
    first = history.apply(frame([a, b, c], [900.0, 500.0, 300.0]), TINT)  # type: ignore[arg-type]
    assert first.peak_temperatures.tolist() == [900.0, 500.0, 300.0]  # type: ignore[union-attr]
    # Same order, cooler: the peaks stay.
    cooled = history.apply(frame([a, b, c], [400.0, 450.0, 350.0]), TINT)  # type: ignore[arg-type]
    assert cooled.peak_temperatures.tolist() == [900.0, 500.0, 350.0]  # type: ignore[union-attr]
    # Reordered, c gone, d new: d starts at its temperature, c's history is dropped.
    moved = history.apply(frame([d, b, a], [600.0, 100.0, 100.0]), TINT)  # type: ignore[arg-type]
    assert moved.peak_temperatures.tolist() == [600.0, 500.0, 900.0]  # type: ignore[union-attr]
    assert len(history) == 3
    back = history.apply(frame([c, a], [200.0, 100.0]), TINT)  # type: ignore[arg-type]
    assert back.peak_temperatures.tolist() == [200.0, 900.0]  # type: ignore[union-attr]


def test_history_applies_only_where_it_can_matter() -> None:
    history = PeakHistory()
    no_tint = scene_from_dict({"material": {"preset": "iron"}})
    plain = frame([1, 2], [900.0, 800.0])
    assert history.apply(plain, no_tint) is plain  # type: ignore[arg-type]
    no_ids = make_frame(np.zeros((2, 3)), temperatures=[900.0, 800.0])
    assert history.apply(no_ids, TINT) is no_ids
    own = make_frame(
        np.zeros((2, 3)), temperatures=[900.0, 800.0], ids=[1, 2], peak_temperatures=[1000.0, 0.0]
    )
    assert history.apply(own, TINT) is own  # the frame's own peaks are used as sent
    later = history.apply(frame([1, 2], [300.0, 300.0]), TINT)  # type: ignore[arg-type]
    assert later.peak_temperatures.tolist() == [1000.0, 800.0]  # type: ignore[union-attr]


def test_service_keeps_the_history_of_a_stream_session(service: ServerProcess) -> None:
    """Over a real stream session: a ball hot (600 K peak) then cooled to 300 K, sent with ids
    in a shuffled order the second time: the cooled frame's image equals a one-shot HTTP render
    of the same frame with the peaks sent explicitly, and differs from it without them."""
    positions = ball(800, seed=5)
    ids = np.arange(800)
    hot = np.where(positions[:, 0] > 0.0, 600.0, 300.0)
    cold = np.full(800, 300.0)
    scene = {
        "image": {"width": 64, "height": 48},
        "camera": {"eye": [0.0, 0.0, 3.0]},
        "material": {"preset": "iron", "heat_tint": True},
        "output": {"format": "raw"},
    }
    shuffle = np.random.default_rng(1).permutation(800)
    client = Client(f"http://127.0.0.1:{service.http_port}")
    with client.stream(scene, compact=False) as session:  # raw: compared with HTTP's floats
        session.send(positions, temperatures=hot, ids=ids)
        session.send(positions[shuffle], temperatures=cold[shuffle], ids=ids[shuffle])
        _first, cooled = session.receive(), session.receive()
    assert cooled.kind == "image"
    want = client.render(
        positions[shuffle],
        scene,
        temperatures=cold[shuffle],
        format="raw",
        peak_temperatures=hot[shuffle],
    )
    without = client.render(positions[shuffle], scene, temperatures=cold[shuffle], format="raw")
    assert cooled.data == want
    assert cooled.data != without


def test_peaks_in_celsius_get_a_note(renderer: SurfaceRenderer) -> None:
    """Peaks sent in degrees Celsius (20 ... 600) beside kelvin temperatures: rendered as sent,
    with a note on `peak_temperatures` saying what to add; kelvin peaks get none."""
    positions = ball(300, seed=6)
    current = np.full(300, 300.0)
    celsius = np.linspace(20.0, 600.0, 300)
    scene = scene_from_dict({"image": {"width": 32, "height": 24}, "material": {"heat_tint": True}})
    _, stats = renderer.render(
        make_frame(positions, temperatures=current, peak_temperatures=celsius), scene
    )
    peak_notes = [n for n in stats.notes if n.field == "peak_temperatures"]
    assert len(peak_notes) == 1 and "add 273.15" in peak_notes[0].message
    _, plain = renderer.render(
        make_frame(positions, temperatures=current, peak_temperatures=celsius + 273.15), scene
    )
    assert all(n.field != "peak_temperatures" for n in plain.notes)
