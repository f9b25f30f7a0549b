"""When a frame's own densities are used: their peak within 0.5-1.5 x sph.rest_density and not
one value for every particle (server/engine/sph/frame_densities.py). Pure host logic; the
renders that depend on it are in test_surfaces.py (the droplet split), test_sph_cli.py
(`sphrender sph`) and test_service_stream.py (the note on the answer)."""

from __future__ import annotations

import numpy as np
import pytest

from sphrender.core.frame import make_frame
from sphrender.server.engine.sph.frame_densities import (
    FIT_RANGE,
    densities_fit,
    largest_density_ratio,
    unfit_note,
    unfit_reason,
    without_unfit_densities,
)
from sphrender.server.scene import Scene, scene_from_dict

POSITIONS = np.zeros((3, 3))


def scene(rest: float = 1000.0) -> Scene:
    return scene_from_dict({"sph": {"rest_density": rest}})


@pytest.mark.parametrize(
    ("peak", "fits"),
    [
        (1000.0, True),  # water at rest
        (1030.0, True),  # a weakly compressible solver's few per cent
        (FIT_RANGE[0] * 1000.0, True),  # the bounds are inside
        (FIT_RANGE[1] * 1000.0, True),
        (0.49 * 1000.0, False),  # spray alone: computed instead, harmlessly
        (1.51 * 1000.0, False),
        (7000.0, False),  # molten steel in kg/m^3
        (1.0, False),  # normalised, or g/cm^3
    ],
)
def test_the_peak_decides(peak: float, fits: bool) -> None:
    frame = make_frame(POSITIONS, densities=np.array([0.3 * peak, peak, 0.5 * peak]))
    assert densities_fit(frame, scene()) is fits
    ratio = largest_density_ratio(frame, scene())
    assert ratio is not None and ratio == pytest.approx(peak / 1000.0, rel=1e-6)
    reason = unfit_reason(frame, scene())
    assert (reason is None) is fits
    if reason is not None:
        assert f"{peak / 1000.0:.3g} x sph.rest_density (1000)" in reason


def test_the_rest_density_sets_the_units() -> None:
    steel = make_frame(POSITIONS, densities=np.array([7100.0, 6900.0, 5000.0]))
    assert not densities_fit(steel, scene())
    assert densities_fit(steel, scene(7000.0))


def test_one_density_for_every_particle_tells_nothing() -> None:
    """An exporter writing its rest density for every particle: in the right units, yet no
    droplet can be told from the bulk; one particle alone is no such case."""
    constant = make_frame(POSITIONS, densities=np.full(3, 1000.0))
    reason = unfit_reason(constant, scene())
    assert reason is not None and "same density (1000)" in reason
    assert densities_fit(make_frame(POSITIONS[:1], densities=np.full(1, 1000.0)), scene())
    assert densities_fit(make_frame(POSITIONS, densities=[1000.0, 1000.0, 999.0]), scene())


def test_frames_without_densities_or_particles_have_nothing_to_distrust() -> None:
    for frame in (make_frame(POSITIONS), make_frame(np.zeros((0, 3)), densities=np.zeros(0))):
        assert largest_density_ratio(frame, scene()) is None
        assert densities_fit(frame, scene())
        same = scene()
        fitted, fitted_scene = without_unfit_densities(frame, same)
        assert fitted is frame and fitted_scene is same


def test_unfit_densities_are_dropped_and_the_split_computes_its_own() -> None:
    frame = make_frame(POSITIONS, densities=np.full(3, 7000.0), radii=np.full(3, 0.1))
    fitted, fitted_scene = without_unfit_densities(frame, scene())
    assert fitted.densities is None
    assert fitted.radii is frame.radii and fitted.positions is frame.positions
    assert fitted_scene.quality.droplet_densities == "computed"
    assert fitted_scene.sph == scene().sph  # nothing else changes
    note = unfit_note(frame, scene())
    assert note.field == "densities" and note.message.endswith("computed from the positions")
    kept = make_frame(POSITIONS, densities=np.array([1000.0, 990.0, 400.0]))
    same = scene()
    fitted, fitted_scene = without_unfit_densities(kept, same)
    assert fitted is kept and fitted_scene is same
