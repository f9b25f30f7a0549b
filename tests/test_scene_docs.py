"""The scene's field docs are what users read (`sphrender schema`, schema/scene.schema.json):
short, free of measurements, and each surface-quality knob either set by a preset or saying when
a user would change it."""

from __future__ import annotations

import re
import tomllib
import typing
from dataclasses import fields
from importlib import resources
from typing import get_args, get_origin

from sphrender.server.scene import QualityConfig, Scene, ShadingConfig, SphConfig
from sphrender.server.scene.fields import is_bench_only
from sphrender.server.scene.presets import PRESETS, preset_sections
from sphrender.server.scene.schema import scene_sections

MAX_DOC = 300
KNOB_SECTIONS = {"quality": QualityConfig, "sph": SphConfig, "shading": ShadingConfig}
#: Before/after figures, timings and angle errors belong in benchmarks/, not in a field's doc.
MEASUREMENT = re.compile(r"->|\d\s*(ms|deg|dB)\b|\d+(\.\d+)?\s*%|\d+x\d+")


def _all_fields() -> list[tuple[str, str]]:
    """(dotted key, doc) of every field of every section."""
    hints = typing.get_type_hints(Scene)
    out = []
    for section in scene_sections():
        hint = hints[section.name]
        cls = get_args(hint)[0] if get_origin(hint) is tuple else hint
        out += [(f"{section.name}.{f.name}", f.metadata["doc"]) for f in fields(cls)]
    return out


def test_every_field_doc_is_short_and_free_of_measurements() -> None:
    docs = _all_fields()
    assert len(docs) > 80
    for key, doc in docs:
        assert doc, key
        assert len(doc) <= MAX_DOC, f"{key}: {len(doc)} characters"
        assert not MEASUREMENT.search(doc), f"{key}: {MEASUREMENT.search(doc)}"


def test_every_knob_is_set_by_a_preset_or_says_when_to_change_it() -> None:
    in_presets = {
        (section, key)
        for name in PRESETS
        for section, table in preset_sections(name).items()
        for key in table
    }
    for section, cls in KNOB_SECTIONS.items():
        for f in fields(cls):
            if is_bench_only(f):
                continue
            doc = f.metadata["doc"]
            if (section, f.name) in in_presets:
                assert "Presets:" in doc, f"{section}.{f.name}"
            else:
                assert "No preset sets it; " in doc, f"{section}.{f.name}"


def test_the_presets_set_only_user_knobs() -> None:
    for name in PRESETS:
        for section, table in preset_sections(name).items():
            user = {f.name for f in fields(KNOB_SECTIONS[section]) if not is_bench_only(f)}
            assert set(table) <= user, (name, section)


def test_preset_files_have_at_most_one_comment_line_per_setting() -> None:
    for name in PRESETS:
        text = resources.files("sphrender.configs").joinpath(f"quality-{name}.toml").read_text()
        settings = len([k for t in tomllib.loads(text).values() for k in t])
        comments = [line for line in text.splitlines() if line.lstrip().startswith("#")]
        assert len(comments) <= settings, name
        assert not any(MEASUREMENT.search(line) for line in comments), name
