"""Turn command-line inputs (files, globs, directories) into an ordered list of frames.

Frames are ordered naturally by the numbers in their names (``ParticleData_Fluid_2`` before
``ParticleData_Fluid_10``), within each glob or directory; explicit files keep the order given.
Each frame's output is named after its input with every particle suffix removed
(``frame_3.bgeo.gz`` -> ``frame_3.png``).
"""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from sphrender.core.errors import InputError
from sphrender.core.readers import SUPPORTED_SUFFIXES, natural_sort_key

_GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class FrameJob:
    """One frame to render: its position in the sequence, input file and final output path."""

    index: int
    input: Path
    output: Path


def _is_particle_file(path: Path) -> bool:
    name = path.name.lower()
    return path.is_file() and any(name.endswith(suffix) for suffix in SUPPORTED_SUFFIXES)


def expand_inputs(items: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """Files, globs and directories -> particle files, each path once, in sequence order."""
    found: list[Path] = []
    for item in items:
        text = os.fspath(item)
        path = Path(text)
        if path.is_dir():
            matches = sorted(
                (p for p in path.iterdir() if _is_particle_file(p)), key=natural_sort_key
            )
            if not matches:
                raise InputError("inputs", f"directory {text} holds no particle files")
            found.extend(matches)
        elif _GLOB_CHARS & set(text) and not path.exists():
            matches = sorted(
                (Path(p) for p in glob.glob(text, recursive=True) if _is_particle_file(Path(p))),
                key=natural_sort_key,
            )
            if not matches:
                raise InputError("inputs", f"pattern {text} matches no particle files")
            found.extend(matches)
        elif path.is_file():
            found.append(path)
        else:
            raise InputError("inputs", f"{text} does not exist")
    unique: dict[Path, None] = {}
    for path in found:
        unique.setdefault(path.resolve(), None)
    return list(unique)


def frame_stem(path: Path) -> str:
    """The input's name without its particle suffix(es): ``a/frame_3.bgeo.gz`` -> ``frame_3``."""
    name = path.name
    lower = name.lower()
    for suffix in sorted(SUPPORTED_SUFFIXES, key=len, reverse=True):
        if lower.endswith(suffix):
            return name[: -len(suffix)]
    return path.stem


def plan_jobs(inputs: Sequence[Path], out_dir: Path, image_suffix: str) -> list[FrameJob]:
    """One job per input; two inputs that would write the same output are an error."""
    jobs: list[FrameJob] = []
    owners: dict[str, Path] = {}
    for index, path in enumerate(inputs):
        name = frame_stem(path) + image_suffix
        if name in owners:
            raise InputError(
                "inputs", f"{owners[name]} and {path} would both write {out_dir / name}"
            )
        owners[name] = path
        jobs.append(FrameJob(index, path, out_dir / name))
    return jobs
