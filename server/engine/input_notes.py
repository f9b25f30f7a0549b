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
  particles), no copy.
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
from sphrender.server.scene import CameraConfig

log = logging.getLogger("sphrender.render")

#: Below this (kelvin) a temperature is taken to be in degrees Celsius, for the note.
COLDEST_KELVIN = 200.0


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

    def of(self, frame: ParticleFrame, camera: CameraConfig, visible: int) -> list[InputNote]:
        """The notes of `frame`, of which `visible` particles are in view of `camera`."""
        notes = [note for note in (celsius_note(frame),) if note is not None]
        if not visible and frame.count:
            notes.append(out_of_view_note(frame, camera))
        for note in notes:
            if note.field not in self._logged:
                log.warning("%s: %s", note.field, note.message)
                self._logged.add(note.field)
        return notes
