"""Each session's thermal history: the running maximum of every particle's temperature, by id.

A frame that carries `temperatures` and `ids` but no `peak_temperatures`, in a session whose
scene asks for `material.heat_tint`, leaves the service's main process with `peak_temperatures`
= max(the id's peak so far, its temperature now): the render child sees an ordinary frame with
peaks. Where it lives: on the `Session`, in the main process, applied in `RenderService.submit`
in the order frames arrive (a frame dropped later in latest mode still counts: the metal was
that hot). Rules: an id seen for the first time starts its history at its temperature; an id
absent from a frame loses its history (the history holds exactly the last frame's ids, so it is
bounded by the server's max_particles); a frame with its own peaks uses them and they become the
history (max with the current temperatures). One-shot renders (no session) keep none.

Cost: ids in the same order as the last frame (the usual simulation output) cost one comparison
and one maximum, O(N); otherwise ids are matched through a table when they are dense (max id <
8 N) or by sorting, O(N log N). Frames without temperatures or ids, or whose scene has no heat
tint, cost nothing.
"""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from sphrender.core.frame import ParticleFrame
from sphrender.server.scene import Scene


class PeakHistory:
    """The running maximum per particle id of one session (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._ids: npt.NDArray[np.int64] = np.zeros(0, np.int64)
        self._peaks: npt.NDArray[np.float32] = np.zeros(0, np.float32)

    def __len__(self) -> int:
        return int(self._ids.shape[0])

    def apply(self, frame: ParticleFrame, scene: Scene) -> ParticleFrame:
        """`frame` with its peak temperatures (module docstring); the same object when the
        history does not apply."""
        if frame.temperatures is None or frame.ids is None or not scene.material.heat_tint:
            return frame
        with self._lock:
            if frame.peak_temperatures is not None:
                peaks = np.maximum(frame.peak_temperatures, frame.temperatures)
                self._ids, self._peaks = frame.ids, peaks
                return frame
            peaks = np.maximum(self._previous(frame.ids), frame.temperatures)
            self._ids, self._peaks = frame.ids, peaks
        return replace(frame, peak_temperatures=peaks)

    def _previous(self, ids: npt.NDArray[np.int64]) -> npt.NDArray[np.float32]:
        """The history's peak of each of `ids` (0 for an id it does not hold)."""
        old_ids, old_peaks = self._ids, self._peaks
        if np.array_equal(ids, old_ids):
            return old_peaks
        if not old_ids.shape[0] or not ids.shape[0]:
            return np.zeros(ids.shape[0], np.float32)
        top = max(int(ids.max()), int(old_ids.max()))
        if top < 8 * max(ids.shape[0], old_ids.shape[0]):
            table = np.zeros(top + 1, np.float32)
            table[old_ids] = old_peaks
            return table[ids]
        order = np.argsort(old_ids)
        sorted_ids = old_ids[order]
        where = np.minimum(np.searchsorted(sorted_ids, ids), sorted_ids.shape[0] - 1)
        found = sorted_ids[where] == ids
        result: npt.NDArray[np.float32] = np.where(found, old_peaks[order][where], 0.0).astype(
            np.float32
        )
        return result
