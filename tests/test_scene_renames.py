"""Old scene key names and values are read under their new names for one release, with a note on
the scene; removed keys and the benchmark's own settings are refused with an error naming them."""

from __future__ import annotations

from dataclasses import fields
from typing import Any

import numpy as np
import pytest

from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.server.bench.sweep import bench_scene_from_dict
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import QualityConfig, Scene, scene_from_dict, scene_to_dict
from sphrender.server.scene.fields import is_bench_only
from sphrender.server.scene.json_schema import scene_json_schema
from sphrender.server.scene.renames import REMOVED_KEYS, RENAMED_KEYS, RENAMED_VALUES

#: A value other than the default for each renamed key (so the test sees it arrive).
KEY_VALUES: dict[str, Any] = {
    "falloff_sigma_px": 3.5,
    "falloff_depth": 2.5,
    "falloff_rate": 0.75,
    "direct_weight": 0.25,
}

BENCH_ONLY = [f.name for f in fields(QualityConfig) if is_bench_only(f)]


def _notes(scene: Scene) -> dict[str, str]:
    return {note.field: note.message for note in scene.notes}


def test_every_renamed_key_has_a_test_value() -> None:
    assert set(KEY_VALUES) == set(RENAMED_KEYS.values())


@pytest.mark.parametrize(("section", "old"), sorted(RENAMED_KEYS))
def test_an_old_key_reads_as_the_new_one_with_a_note(section: str, old: str) -> None:
    new = RENAMED_KEYS[section, old]
    value = KEY_VALUES[new]
    assert getattr(getattr(Scene(), section), new) != value
    old_scene = scene_from_dict({section: {old: value}})
    new_scene = scene_from_dict({section: {new: value}})
    assert old_scene == new_scene
    assert getattr(getattr(old_scene, section), new) == value
    message = _notes(old_scene)[f"{section}.{old}"]
    assert f"{section}.{new}" in message and "renamed" in message
    assert new_scene.notes == ()
    assert scene_to_dict(old_scene) == scene_to_dict(new_scene)  # written under the new name


@pytest.mark.parametrize(("section", "key", "old"), sorted(RENAMED_VALUES))
def test_an_old_value_reads_as_the_new_one_with_a_note(section: str, key: str, old: str) -> None:
    new = RENAMED_VALUES[section, key, old]
    old_scene = scene_from_dict({section: {key: old}})
    new_scene = scene_from_dict({section: {key: new}})
    assert old_scene == new_scene
    assert getattr(getattr(old_scene, section), key) == new
    message = _notes(old_scene)[f"{section}.{key}"]
    assert f'"{old}"' in message and f'"{new}"' in message
    assert new_scene.notes == ()


def test_old_names_together_with_their_sections_other_keys() -> None:
    """A thesis-style scene written with every old name reads as the new one, one note each."""
    old = {
        "quality": {"kernel_size": "eq25", "eq25_sigma_px": 3.5, "iterations": 3},
        "shading": {"g_term": "eq37", "combine": "eq55", "eq55_k": 0.25},
    }
    new = {
        "quality": {"kernel_size": "depth_falloff", "falloff_sigma_px": 3.5, "iterations": 3},
        "shading": {"g_term": "cook_torrance", "combine": "weighted", "direct_weight": 0.25},
    }
    scene = scene_from_dict(old)
    assert scene == scene_from_dict(new)
    assert len(scene.notes) == 5
    assert old["quality"]["kernel_size"] == "eq25"  # the caller's mapping is left alone


def test_a_key_under_both_names_is_refused() -> None:
    with pytest.raises(InputError) as exc:
        scene_from_dict({"shading": {"eq55_k": 0.2, "direct_weight": 0.3}})
    assert exc.value.field == "shading.eq55_k" and "direct_weight" in str(exc.value)


@pytest.mark.parametrize(("section", "key"), sorted(REMOVED_KEYS))
def test_a_removed_key_is_refused_naming_it(section: str, key: str) -> None:
    with pytest.raises(InputError) as exc:
        scene_from_dict({section: {key: "none"}})
    assert exc.value.field == f"{section}.{key}"
    assert "removed" in str(exc.value)
    assert not hasattr(getattr(Scene(), section), key)


@pytest.mark.parametrize("key", BENCH_ONLY)
def test_a_bench_only_key_is_refused_in_a_scene_and_read_by_the_bench(key: str) -> None:
    value = {
        "occlusion_culling": False,
        "normal_rules": "hard",
    }[key]
    with pytest.raises(InputError) as exc:
        scene_from_dict({"quality": {key: value}})
    assert exc.value.field == f"quality.{key}"
    assert "removed" in str(exc.value) and "bench" in str(exc.value)
    scene = bench_scene_from_dict({"quality": {key: value}})
    assert getattr(scene.quality, key) == value
    assert key not in scene_to_dict(scene)["quality"]


def test_bench_only_keys_are_exactly_these() -> None:
    assert sorted(BENCH_ONLY) == [
        "normal_rules",
        "occlusion_culling",
    ]


def test_the_json_schema_shows_no_old_removed_or_bench_only_key() -> None:
    defs = scene_json_schema()["$defs"]
    gone = {(s, k) for s, k in RENAMED_KEYS} | set(REMOVED_KEYS)
    gone |= {("quality", key) for key in BENCH_ONLY}
    for section, key in gone:
        name = {"quality": "QualityConfig", "shading": "ShadingConfig"}[section]
        assert key not in defs[name]["properties"], f"{section}.{key}"
    for section, key, old in RENAMED_VALUES:
        name = {"quality": "QualityConfig", "shading": "ShadingConfig"}[section]
        assert old not in defs[name]["properties"][key]["enum"]
    assert "notes" not in scene_json_schema()["properties"]


def test_notes_are_no_section() -> None:
    with pytest.raises(InputError) as exc:
        scene_from_dict({"notes": []})
    assert exc.value.field == "notes"
    assert "notes" not in scene_to_dict(scene_from_dict({"quality": {"eq25_decline": 1.0}}))


def test_the_renames_notes_come_with_each_rendered_frame(renderer: SurfaceRenderer) -> None:
    """The notes reach the frame's `RenderStats.notes`: what the service answers as IMAGE
    notes (X-Sphrender-Notes) and the CLI logs."""
    scene = scene_from_dict(
        {"image": {"width": 32, "height": 24}, "shading": {"combine": "eq55", "eq55_k": 0.25}}
    )
    frame = make_frame(np.zeros((1, 3)), radii=np.full(1, 0.1, dtype=np.float32))
    for _ in range(2):
        _image, stats = renderer.render(frame, scene)
        fields_noted = [note.field for note in stats.notes]
        assert "shading.eq55_k" in fields_noted and "shading.combine" in fields_noted
    _image, stats = renderer.render(frame, scene_from_dict({"image": {"width": 32, "height": 24}}))
    assert not any(note.field.startswith("shading.") for note in stats.notes)
