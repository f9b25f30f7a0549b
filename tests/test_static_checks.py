"""ruff (lint + format) and mypy run as part of the test suite.

mypy cannot follow setuptools' editable-install finder (top-level `server/` is imported as
`sphrender.server`), so the check builds a throw-away tree of symlinks with the import layout,
`sphrender/{server,client,shaders,configs}`, and points MYPYPATH at it.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
PACKAGE_FOLDERS = ("core", "server", "client", "shaders", "configs")


def run(args: list[str], **kwargs: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        args, cwd=REPO, capture_output=True, text=True, timeout=300, check=False, **kwargs
    )  # type: ignore[call-overload]


def test_ruff_lint() -> None:
    result = run([str(BIN / "ruff"), "check", "."])
    assert result.returncode == 0, result.stdout + result.stderr


def test_ruff_format() -> None:
    result = run([str(BIN / "ruff"), "format", "--check", "."])
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy(tmp_path: Path) -> None:
    package = tmp_path / "sphrender"
    package.mkdir()
    for folder in PACKAGE_FOLDERS:
        (package / folder).symlink_to(REPO / folder, target_is_directory=True)
    env = {**os.environ, "MYPYPATH": str(tmp_path)}
    result = run(
        [
            str(BIN / "mypy"),
            "--cache-dir",
            str(tmp_path / "cache"),
            "-p",
            "sphrender.server",
            "-p",
            "sphrender.client",
            "-p",
            "sphrender.core",
        ],
        env=env,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    # the tests, and this repository's studies (benchmarks/studies/, not in the wheel)
    cache = str(tmp_path / "cache")
    tests = run([str(BIN / "mypy"), "--cache-dir", cache, "tests", "benchmarks/studies"], env=env)
    assert tests.returncode == 0, tests.stdout + tests.stderr
