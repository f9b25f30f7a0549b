"""Notes on a frame's input that the renderer itself finds (`RenderStats.notes`, IMAGE `notes`):
the frame renders as sent, and its answer says what looks wrong. (Densities the SPH stage
replaces are noted there: sph/frame_densities.py.)

* **Temperatures that look like degrees Celsius** (`celsius_note`). The glow reads kelvin
  (PROTOCOL.md §3: "kelvin, >= 0"); a welding simulation often writes degrees Celsius. Read as
  kelvin they glow far too dim: the blackbody radiance at 600 nm of 1500 (K) is 1/11.7 of
  1773 K's (1500 degrees C), since B ~ 1 / (exp(hc / (lambda k T)) - 1) with hc / (lambda k)
  = 23,980 K there. Nothing in a weld scene is colder than its surroundings (~293 K), so a
  frame whose coldest particle is below COLDEST_KELVIN is almost surely in Celsius (its
  workpiece and spatter at room temperature read 20-25). A cryogenic simulation is kelvin
  there, so the frame renders as sent. One pass over the array on the host (~6 us per 100k
  particles), no copy. `peak_temperatures` get the same note (read as kelvin, Celsius peaks
  fall below the current temperatures and the tint reads those instead).
* **A radius that does not fit the frame's spacing** (`radius_note`). SPH fills its fluid with
  particles spaced 2r apart (SPlisHSPlasH, DualSPHysics: the particle mass is rest density x
  (2r)^3), so a frame's own particles say what `particles.radius` should be. Forgetting it
  renders with the default 0.015 against, say, a simulator's 0.02: sheets break into beads.
  The measure is the median nearest-neighbour distance s of the frame's bulk (frame_spacing.py):
  2r on a resting lattice (r/s = 0.50), somewhat less once the fluid flows. RADIUS_BAND's low end,
  just under 0.50, catches a radius 25 % too small, which breaks sheets into beads; its high end
  is lenient (a radius too large only rounds the surface, and point clouds that are not SPH
  must not be told off) but catches a diameter sent as the radius. Skipped for frames with
  per-particle radii; the sampling is seeded, so a frame always gets the same answer, and a
  stream of frames with one particle count is measured once every `SpacingCache.REUSE` frames.
* **No particle in view** (`out_of_view_note`). A blank image is what a client sees when its
  positions are in other units than the scene's camera (millimetres against a camera in
  metres) or the camera looks away; the note gives the particles' extent and the camera, so
  the fix can be read off it. Computed only for such frames.
"""

from __future__ import annotations

import logging

import numpy as np

from sphrender.core.frame import ParticleFrame
from sphrender.server.engine.frame_output import InputNote
from sphrender.server.engine.frame_spacing import typical_spacing
from sphrender.server.scene import CameraConfig, Scene

log = logging.getLogger("sphrender.render")

#: Below this (kelvin) a temperature is taken to be in degrees Celsius, for the note.
COLDEST_KELVIN = 200.0
#: The scene's radius over the frame's typical spacing that fits SPH data (see the docstring).
RADIUS_BAND = (0.48, 0.95)


def celsius_note(frame: ParticleFrame) -> InputNote | None:
    """The note of a frame whose temperatures look like degrees Celsius; None otherwise (or
    without temperatures)."""
    if frame.temperatures is None or not frame.count:
        return None
    coldest = float(np.min(frame.temperatures))
    if coldest >= COLDEST_KELVIN:
        return None
    hottest = float(np.max(frame.temperatures))
    return InputNote(
        "temperatures",
        f"read in kelvin, they run from {coldest:.4g} K to {hottest:.4g} K; below "
        f"{COLDEST_KELVIN:g} K they are likely degrees Celsius: add 273.15 (1500 degrees C is "
        "1773 K, which glows ~12x brighter at 600 nm than 1500 K); rendered as sent",
    )


def peak_celsius_note(frame: ParticleFrame) -> InputNote | None:
    """`celsius_note` for the frame's peak temperatures (None without them)."""
    peaks = frame.peak_temperatures
    if peaks is None or not frame.count or float(np.min(peaks)) >= COLDEST_KELVIN:
        return None
    return InputNote(
        "peak_temperatures",
        f"read in kelvin, they run from {float(np.min(peaks)):.4g} K to "
        f"{float(np.max(peaks)):.4g} K; below {COLDEST_KELVIN:g} K they are likely degrees "
        "Celsius: add 273.15 (a peak below the current temperature counts as the current one, "
        "so the heat tint reads those instead); rendered as sent",
    )


def radius_note(frame: ParticleFrame, radius: float, spacing: float | None) -> InputNote | None:
    """The note of a frame without radii whose `spacing` (`typical_spacing`) does not fit the
    scene's `radius`; None otherwise (or when the spacing could not be told)."""
    if frame.radii is not None or spacing is None:
        return None
    low, high = RADIUS_BAND
    ratio = radius / spacing
    if low <= ratio <= high:
        return None
    return InputNote(
        "particles.radius",
        f"the scene's particle radius {radius:.4g} is {ratio:.2f} x the frame's typical particle "
        f"spacing {spacing:.4g} (median nearest-neighbour distance); SPH particles sit about "
        f"two radii apart, so {low:g}-{high:g} x is expected: set particles.radius to the "
        f"simulation's (likely {0.5 * spacing:.3g}-{0.6 * spacing:.3g}) or send radii; "
        "rendered as sent",
    )


class SpacingCache:
    """A simulation's spacing changes slowly from frame to frame: frames with the particle count
    of the last one measured reuse its spacing for `REUSE` frames, so the measure costs the
    render thread one frame in `REUSE`, not every frame."""

    REUSE = 32

    def __init__(self) -> None:
        self._count = -1
        self._left = 0
        self._spacing: float | None = None

    def of(self, frame: ParticleFrame) -> float | None:
        if frame.radii is not None:
            return None
        if frame.count != self._count or self._left <= 0:
            self._count, self._left = frame.count, self.REUSE
            self._spacing = typical_spacing(frame.positions)
        self._left -= 1
        return self._spacing


def _vector(values: tuple[float, float, float]) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"


def out_of_view_note(frame: ParticleFrame, camera: CameraConfig) -> InputNote:
    """The note of a frame none of whose particles the camera sees."""
    lower, upper = frame.positions.min(axis=0), frame.positions.max(axis=0)
    extent = ", ".join(f"{axis} {lower[i]:.4g} to {upper[i]:.4g}" for i, axis in enumerate("xyz"))
    return InputNote(
        "camera",
        f"none of the frame's {frame.count} particles is in view: they lie at {extent}; the "
        f"camera looks from {_vector(camera.eye)} at {_vector(camera.target)} (fov_y "
        f"{camera.fov_y:g} deg, near {camera.near:g}"
        + (f", far {camera.far:g})" if camera.far is not None else ")"),
    )


class InputNotes:
    """The renderer's own notes on each frame (those above), each kind logged the first time
    it appears in this renderer's life."""

    def __init__(self) -> None:
        self._logged: set[str] = set()
        self._spacing = SpacingCache()

    def of(self, frame: ParticleFrame, scene: Scene, visible: int) -> list[InputNote]:
        """The notes of `frame`, of which `visible` particles are in view of the scene's camera."""
        spacing = self._spacing.of(frame)
        found = (
            celsius_note(frame),
            peak_celsius_note(frame),
            radius_note(frame, scene.particles.radius, spacing),
        )
        notes = [note for note in found if note is not None]
        if not visible and frame.count:
            notes.append(out_of_view_note(frame, scene.camera))
        for note in notes:
            if note.field not in self._logged:
                log.warning("%s: %s", note.field, note.message)
                self._logged.add(note.field)
        return notes
