"""Scene keys and values renamed or removed, and what reading an old scene does about them.

A renamed key or value is still accepted for one release: it is read under its new name and the
scene carries a `SceneNote` saying so (logged once, and reported with each frame's notes). A
removed key is refused with an error that names it and says why.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

from sphrender.core.errors import InputError
from sphrender.server.scene.fields import SceneNote

log = logging.getLogger(__name__)

#: (section, old key) -> new key.
RENAMED_KEYS: dict[tuple[str, str], str] = {
    ("quality", "eq25_sigma_px"): "falloff_sigma_px",
    ("quality", "eq25_threshold"): "falloff_depth",
    ("quality", "eq25_decline"): "falloff_rate",
    ("shading", "eq55_k"): "direct_weight",
}

#: (section, key, old value) -> new value.
RENAMED_VALUES: dict[tuple[str, str, str], str] = {
    ("quality", "kernel_size", "eq25"): "depth_falloff",
    ("shading", "g_term", "eq37"): "cook_torrance",
    ("shading", "combine", "eq55"): "weighted",
}

#: (section, key) -> why it is gone.
REMOVED_KEYS: dict[tuple[str, str], str] = {
    ("quality", "keep_features"): "an experiment that kept no feature better than none "
    "(exact_droplets keeps droplets round)",
}

_logged: set[str] = set()


def upgrade_scene_dict(data: Mapping[str, Any]) -> tuple[dict[str, Any], tuple[SceneNote, ...]]:
    """`data` with renamed keys and values under their new names (a new mapping; `data` is not
    modified), and a note for each; a removed key raises `InputError` naming it, as does a key
    given under both its old and its new name."""
    out = dict(data)
    notes: list[SceneNote] = []
    for (section, key), reason in REMOVED_KEYS.items():
        table = out.get(section)
        if isinstance(table, Mapping) and key in table:
            raise InputError(f"{section}.{key}", f"was removed: {reason}")
    for (section, old), new in RENAMED_KEYS.items():
        table = out.get(section)
        if not isinstance(table, Mapping) or old not in table:
            continue
        if new in table:
            raise InputError(
                f"{section}.{old}", f"is the old name of {section}.{new}; give only {new}"
            )
        out[section] = {(new if k == old else k): v for k, v in table.items()}
        notes.append(_note(f"{section}.{old}", f"renamed to {section}.{new}"))
    for (section, key, old), new in RENAMED_VALUES.items():
        table = out.get(section)
        if isinstance(table, Mapping) and isinstance(table.get(key), str) and table[key] == old:
            out[section] = {**table, key: new}
            notes.append(_note(f"{section}.{key}", f'"{old}" renamed to "{new}"'))
    for note in notes:
        if note.field not in _logged:
            log.warning("%s: %s", note.field, note.message)
            _logged.add(note.field)
    return out, tuple(notes)


def _note(key: str, renamed: str) -> SceneNote:
    return SceneNote(key, f"{renamed}; the old name is accepted until the next release")
