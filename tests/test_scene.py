"""Scene configuration: defaults, TOML and dict loading, and errors that name the key."""

from __future__ import annotations

import importlib.resources
import tomllib
from pathlib import Path
from typing import Any

import pytest

from sphrender.core.errors import InputError
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
        ({"particles": {"radius": 0}}, "particles.radius", "[1e-12, 1e+12]"),
        ({"particles": {"radius": -1}}, "particles.radius", "[1e-12, 1e+12]"),
        ({"particles": {"radius": 1e308}}, "particles.radius", "[1e-12, 1e+12]"),
        ({"particles": {"radius": 1e-308}}, "particles.radius", "[1e-12, 1e+12]"),
        ({"sph": {"support_radius": 1e308}}, "sph.support_radius", "[1e-12, 1e+12]"),
        ({"quality": {"filter": "box"}}, "quality.filter", '"narrow_range"'),
        ({"quality": {"iterations": 0}}, "quality.iterations", "[1, 16]"),
        ({"quality": {"separable": 1}}, "quality.separable", "true or false"),
        ({"quality": {"kernel_max_px": 1000}}, "quality.kernel_max_px", "[1, 128]"),
        ({"output": {"format": "jpg"}}, "output.format", '"png", "exr"'),
        ({"output": {"aovs": ["Z", "Q"]}}, "output.aovs[1]", '"Z", "N"'),
        ({"output": {"aovs": ["Z", "Z"]}}, "output.aovs", "repeat"),
        ({"output": {"png_bits": 12}}, "output.png_bits", "8, 16"),
        ({"output": {"png_bits": True}}, "output.png_bits", "8, 16"),
        ({"output": {"tone_mapper": "reinhard"}}, "output.tone_mapper", '"aces"'),
        ({"material": {"preset": "brass"}}, "material.preset", '"iron"'),
        ({"material": {"roughness": 1.5}}, "material.roughness", "[0, 1]"),
        ({"material": {"f0": [0.5, 0.5, 2.0]}}, "material.f0[2]", "[0, 1.2]"),
        ({"material": {"metallic": -0.1}}, "material.metallic", "[0, 1]"),
        ({"lights": {"type": "point"}}, "lights", "array of tables"),
        ({"lights": [{"type": "spot"}]}, "lights[0].type", '"directional"'),
        ({"lights": [{"direction": [0, -1, 0]}, {"intensity": -1}]}, "lights[1].intensity", "[0, "),
        ({"lights": [{"type": "point"}]}, "lights[0].position", "needs a position"),
        ({"lights": [{"direction": [0, 0, 0]}]}, "lights[0].direction", "zero"),
        (
            {"lights": [{"direction": [0, -1, 0], "position": [0, 0, 0]}]},
            "lights[0].position",
            "only",
        ),
        ({"lights": [{"direction": [0, -1, 0]}] * 9}, "lights", "at most 8"),
        (
            {"lights": [{"direction": [0, -1, 0], "colour": [1, 1, 1]}]},
            "lights[0].colour",
            "unknown",
        ),
        ({"environment": {"preset": "beach"}}, "environment.preset", '"workshop"'),
        ({"environment": {"preset": "studio", "file": "a.exr"}}, "environment.file", "only one"),
        ({"environment": {"uniform": [1, -1, 1]}}, "environment.uniform[1]", "[0, inf]"),
        ({"environment": {"file": 3}}, "environment.file", "string"),
        ({"environment": {"file": " "}}, "environment.file", "empty"),
        ({"shading": {"ibl_mode": "cubemap"}}, "shading.ibl_mode", '"prefiltered"'),
        ({"shading": {"ibl_samples": 0}}, "shading.ibl_samples", "[1, 4096]"),
        ({"shading": {"direct_weight": 2}}, "shading.direct_weight", "[0, 1]"),
        ({"shading": {"g_term": "beckmann"}}, "shading.g_term", '"cook_torrance"'),
        ({"shading": {"emission_scale": 0}}, "shading.emission_scale", "(0, 1000000]"),
    ],
)
def test_bad_values_name_the_key_and_limit(data: dict[str, Any], field: str, words: str) -> None:
    with pytest.raises(InputError) as info:
        scene_from_dict(data)
    assert info.value.field == field
    assert words in info.value.message


def test_lights_round_trip_and_material_overrides() -> None:
    from sphrender.server.engine.lighting.materials import METAL_F0, resolve_material

    data = {
        "lights": [
            {"type": "point", "position": [1e5, 2.0, 3.0], "intensity": 4.0},
            {"direction": [0.0, -1.0, 0.0], "color": [1.0, 0.9, 0.8]},
        ],
        "material": {"preset": "copper", "roughness": 0.3},
    }
    scene = scene_from_dict(data)
    assert scene_from_dict(scene_to_dict(scene)) == scene
    assert scene.lights[0].position == (1e5, 2.0, 3.0)
    material = resolve_material(scene.material)
    assert material.f0 == METAL_F0["copper"] and material.roughness == 0.3
    assert material.metallic == 1.0 and material.diffuse_albedo == (0.0, 0.0, 0.0)
    override = resolve_material(
        scene_from_dict(
            {"material": {"preset": "copper", "f0": [0.5, 0.5, 0.5], "metallic": 0}}
        ).material
    )
    assert override.specular_f0 == (0.04, 0.04, 0.04)
    assert override.diffuse_albedo == (0.5, 0.5, 0.5)
    assert Scene().lights == ()  # no [[lights]]: no direct light


def test_bad_toml_files(tmp_path: Path) -> None:
    broken = tmp_path / "broken.toml"
    broken.write_text("[camera\nfov_y = 3")
    with pytest.raises(InputError) as info:
        load_scene(broken)
    assert info.value.field == "scene" and "not valid TOML" in info.value.message
    with pytest.raises(InputError) as info:
        load_scene(tmp_path / "missing.toml")
    assert info.value.field == "scene" and "cannot read" in info.value.message
