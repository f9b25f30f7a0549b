"""The scene: what to render and how, as typed, documented, validated configuration.

* `schema.py`: every section and field, typed and documented in one place (the reference for
  TOML files and for JSON scenes over the wire);
* `validate.py`: mappings -> dataclasses, errors that name the dotted key and the allowed range;
* `files.py`: TOML files; `layering.py`: one scene mapping over another, a preset's sections;
* `export.py`: `Scene` -> plain JSON-safe mapping, defaults filled (`scene_to_dict`);
* `json_schema.py`: the scene's JSON Schema (2020-12), generated from `schema.py`
  (committed as ``schema/scene.schema.json``, served at ``GET /v1/schema``);
* `presets.py`: the quality presets of `configs/quality-*.toml` laid under a scene file (and
  `quality.preset` under any scene, by validation);
* `renames.py`: old key names read under their new ones (with a note), removed keys refused.

Import from the package: ``from sphrender.server.scene import Scene, scene_from_dict``.
"""

from sphrender.server.scene.export import scene_to_dict
from sphrender.server.scene.files import load_scene, merge_scene_dicts, read_scene_toml
from sphrender.server.scene.schema import (
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_SIDE,
    MAX_LIGHTS,
    AovName,
    CameraConfig,
    EnvironmentConfig,
    EnvironmentPreset,
    FilterName,
    FinishConfig,
    ImageConfig,
    ImageFormatName,
    LightConfig,
    LightType,
    MaterialConfig,
    MaterialPreset,
    OutputConfig,
    ParticlesConfig,
    QualityConfig,
    Scene,
    SceneNote,
    ShadingConfig,
    SolidsConfig,
    SphConfig,
    Vec3,
    spec,
)
from sphrender.server.scene.validate import scene_from_dict, section_from_dict

__all__ = [
    "MAX_IMAGE_PIXELS",
    "MAX_IMAGE_SIDE",
    "MAX_LIGHTS",
    "AovName",
    "CameraConfig",
    "EnvironmentConfig",
    "EnvironmentPreset",
    "FilterName",
    "FinishConfig",
    "ImageConfig",
    "ImageFormatName",
    "LightConfig",
    "LightType",
    "MaterialConfig",
    "MaterialPreset",
    "OutputConfig",
    "ParticlesConfig",
    "QualityConfig",
    "Scene",
    "SceneNote",
    "ShadingConfig",
    "SolidsConfig",
    "SphConfig",
    "Vec3",
    "load_scene",
    "merge_scene_dicts",
    "read_scene_toml",
    "scene_from_dict",
    "scene_to_dict",
    "section_from_dict",
    "spec",
]
