"""The scene's particle radius checked against the frame's own spacing (input_notes.radius_note,
frame_spacing.typical_spacing): a lattice of known spacing, the vendored DFSPH dam break, and
the note over both transports of a real server."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from service_harness import SMALL_SCENE, ServerProcess

from sphrender.client.api import Client
from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.core.readers import read_particles
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.frame_output import InputNote
from sphrender.server.engine.frame_spacing import typical_spacing
from sphrender.server.engine.input_notes import RADIUS_BAND, SpacingCache
from sphrender.server.engine.input_notes import radius_note as note_for_spacing

#: SPH radius of the lattice below: spacing 2r = 0.04 exactly.
R = 0.02
LATTICE = lattice_slab(0.8, 0.8, 6, R)


def radius_note(frame: ParticleFrame, radius: float) -> InputNote | None:
    return note_for_spacing(frame, radius, typical_spacing(frame.positions))


def test_spacing_of_a_lattice_is_exact_and_of_random_points_plausible() -> None:
    assert typical_spacing(LATTICE) == pytest.approx(2 * R, rel=1e-9)
    ball = jittered_lattice_ball(0.3, 0.01, jitter=0.1, seed=2)
    assert typical_spacing(ball) == pytest.approx(0.02, rel=0.1)  # jitter only shortens gaps
    uniform = np.random.default_rng(0).uniform(size=(50_000, 3))
    poisson = 0.554 * 50_000 ** (-1 / 3)  # median nearest-neighbour distance of a Poisson cloud
    assert typical_spacing(uniform) == pytest.approx(poisson, rel=0.1)
    assert typical_spacing(np.zeros((5, 3))) is None  # too few to tell
    assert typical_spacing(np.zeros((500, 3))) is None  # all in one point


def test_a_radius_25_percent_small_gets_a_note_the_right_one_none() -> None:
    frame = make_frame(LATTICE)
    assert radius_note(frame, R) is None
    note = radius_note(frame, 0.75 * R)
    assert note is not None and note.field == "particles.radius"
    assert "0.015 is 0.38 x the frame's typical particle spacing 0.04" in note.message
    assert "likely 0.02-0.024" in note.message
    assert radius_note(frame, 2 * R) is not None  # a diameter sent as the radius
    assert radius_note(frame, RADIUS_BAND[1] * 2 * R * 0.99) is None
    with_radii = make_frame(LATTICE, radii=np.full(len(LATTICE), 0.75 * R))
    assert radius_note(with_radii, 0.75 * R) is None  # per-particle radii: not checked


def test_the_spacing_is_measured_again_when_the_count_changes_or_after_its_reuse() -> None:
    cache = SpacingCache()
    frame = make_frame(LATTICE)
    assert cache.of(frame) == pytest.approx(2 * R, rel=1e-9)
    wider = make_frame(2 * LATTICE)  # same count, twice the spacing: reused until REUSE is up
    assert all(cache.of(wider) == pytest.approx(2 * R) for _ in range(SpacingCache.REUSE - 1))
    assert cache.of(wider) == pytest.approx(4 * R, rel=1e-9)
    fewer = make_frame(2 * LATTICE[:-1])
    assert cache.of(fewer) == pytest.approx(4 * R, rel=1e-2)  # a new count: measured at once
    assert cache.of(make_frame(LATTICE, radii=np.full(len(LATTICE), R))) is None


@pytest.mark.parametrize("name", ["1", "5", "11"])
def test_dambreak_frames_fit_their_radius(dambreak: Path, name: str) -> None:
    """SPlisHSPlasH's radius 0.015 at rest (t = 0) and flowing (0.4 s, 1.0 s): no note; the
    default-radius mistake of a 0.02 simulation (0.75 x) noted on every frame."""
    frame = read_particles(dambreak / "vtk" / f"ParticleData_Fluid_{name}.vtk")
    assert frame.radii is None
    assert radius_note(frame, 0.015) is None
    assert radius_note(frame, 0.75 * 0.015) is not None


def test_radius_note_over_http_and_stream(service: ServerProcess) -> None:
    client = Client(f"http://127.0.0.1:{service.http_port}")
    scene = {**SMALL_SCENE, "particles": {"radius": 0.75 * R}}
    _png, notes = client.render_frame_noted(make_frame(LATTICE), scene)
    assert [n["field"] for n in notes] == ["particles.radius"]
    _png, none = client.render_frame_noted(
        make_frame(LATTICE), {**scene, "particles": {"radius": R}}
    )
    assert none == []
    with service.stream() as stream:
        stream.hello(scene)
        stream.frame(1, LATTICE)
        stream.frame(2, LATTICE, scene={"particles": {"radius": R}})
        (_k1, noted, _p1), (_k2, plain, _p2) = stream.receive(), stream.receive()
    assert [n["field"] for n in noted["notes"]] == ["particles.radius"]
    assert "notes" not in plain
    assert json.dumps(notes[0]["message"]) == json.dumps(noted["notes"][0]["message"])
