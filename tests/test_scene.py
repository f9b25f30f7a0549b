"""Scene configuration: defaults, TOML and dict loading, and errors that name the key."""

from __future__ import annotations

import importlib.resources
import tomllib
from pathlib import Path
from typing import Any

import pytest

from sphrender.client.errors import InputError
from sphrender.server.scene import Scene, load_scene, scene_from_dict, scene_to_dict

REPO = Path(__file__).resolve().parents[1]


def test_defaults_round_trip_through_dict() -> None:
    scene = Scene()
    assert scene_from_dict(scene_to_dict(scene)) == scene
    assert scene_from_dict({}) == scene


def test_every_shipped_config_loads() -> None:
    # server.toml holds server settings, not a scene (tested in test_service_units.py).
    configs = sorted(p for p in (REPO / "configs").glob("*.toml") if p.name != "server.toml")
    assert configs
    for path in configs:
        load_scene(path)


def test_shipped_configs_are_package_data() -> None:
    demo = importlib.resources.files("sphrender.configs").joinpath("demo.toml")
    scene = scene_from_dict(tomllib.loads(demo.read_text()))
    assert scene.particles.radius == pytest.approx(0.4)


def test_partial_sections_keep_other_defaults() -> None:
    scene = scene_from_dict({"camera": {"fov_y": 30}, "quality": {"filter": "gaussian"}})
    assert scene.camera.fov_y == 30.0 and isinstance(scene.camera.fov_y, float)
    assert scene.camera.near == Scene().camera.near
    assert scene.quality.filter == "gaussian"
    assert scene.quality.iterations == Scene().quality.iterations


@pytest.mark.parametrize(
    ("data", "field", "words"),
    [
        ({"imag": {}}, "imag", "unknown section"),
        ({"image": {"widht": 3}}, "image.widht", "allowed: height, width"),
        ({"image": {"width": 0}}, "image.width", "[1, 16384]"),
        ({"image": {"height": 20000}}, "image.height", "[1, 16384]"),
        ({"image": {"width": 12.5}}, "image.width", "integer"),
        ({"image": {"width": 16384, "height": 16384}}, "image", "pixels"),
        ({"image": "big"}, "image", "table"),
        ({"camera": {"fov_y": 0}}, "camera.fov_y", "(0, 180)"),
        ({"camera": {"fov_y": 180}}, "camera.fov_y", "(0, 180)"),
        ({"camera": {"fov_y": float("nan")}}, "camera.fov_y", "finite"),
        ({"camera": {"near": 0}}, "camera.near", "(0, inf]"),
        ({"camera": {"near": 1.0, "far": 0.5}}, "camera.far", "greater than camera.near"),
        ({"camera": {"eye": [1, 2]}}, "camera.eye", "3 numbers"),
        ({"camera": {"eye": [1, 2, "x"]}}, "camera.eye[2]", "number"),
        ({"camera": {"eye": [0, 0, 0], "target": [0, 0, 0]}}, "camera.target", "differ"),
        ({"camera": {"eye": [0, 0, 1], "up": [0, 0, 2]}}, "camera.up", "parallel"),
        ({"camera": {"up": [0, 0, 0]}}, "camera.up", "zero"),
        ({"particles": {"radius": 0}}, "particles.radius", "(0, inf]"),
        ({"particles": {"radius": -1}}, "particles.radius", "(0, inf]"),
        ({"quality": {"filter": "box"}}, "quality.filter", "'narrow_range'"),
        ({"quality": {"iterations": 0}}, "quality.iterations", "[1, 16]"),
        ({"quality": {"separable": 1}}, "quality.separable", "true or false"),
        ({"quality": {"kernel_max_px": 1000}}, "quality.kernel_max_px", "[1, 128]"),
        ({"output": {"format": "jpg"}}, "output.format", "'png', 'exr'"),
        ({"output": {"aovs": ["Z", "Q"]}}, "output.aovs[1]", "'Z', 'N'"),
        ({"output": {"aovs": ["Z", "Z"]}}, "output.aovs", "repeat"),
        ({"output": {"png_bits": 12}}, "output.png_bits", "8, 16"),
        ({"output": {"png_bits": True}}, "output.png_bits", "8, 16"),
    ],
)
def test_bad_values_name_the_key_and_limit(data: dict[str, Any], field: str, words: str) -> None:
    with pytest.raises(InputError) as info:
        scene_from_dict(data)
    assert info.value.field == field
    assert words in info.value.message


def test_bad_toml_files(tmp_path: Path) -> None:
    broken = tmp_path / "broken.toml"
    broken.write_text("[camera\nfov_y = 3")
    with pytest.raises(InputError) as info:
        load_scene(broken)
    assert info.value.field == "scene" and "not valid TOML" in info.value.message
    with pytest.raises(InputError) as info:
        load_scene(tmp_path / "missing.toml")
    assert info.value.field == "scene" and "cannot read" in info.value.message
