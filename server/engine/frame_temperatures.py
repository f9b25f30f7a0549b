"""Whether a frame's temperatures look like kelvin, the unit the glow reads them in (PROTOCOL.md
§3: "kelvin, >= 0").

A welding simulation often writes degrees Celsius. Read as kelvin they glow far too dim: the
blackbody radiance at 600 nm of 1500 (K) is 1/11.7 of 1773 K's (1500 degrees C), since B ~
1 / (exp(hc / (lambda k T)) - 1) with hc / (lambda k) = 23,980 K there. Nothing in a weld
scene is colder than its surroundings (~293 K), so a frame whose coldest particle is below
COLDEST_KELVIN is almost surely in Celsius (its workpiece and spatter at room temperature
read 20-25). The frame renders as sent (a cryogenic simulation is kelvin there), and its answer
carries a note saying what to add. One pass over the array on the host (~6 us per 100k
particles), no copy.
"""

from __future__ import annotations

import numpy as np

from sphrender.client.frame import ParticleFrame
from sphrender.server.engine.frame_output import InputNote

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
