"""Running the installed `sphrender` command from tests, and the small dam-break scene they
share."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

#: The console script installed next to this interpreter.
SPHRENDER = str(Path(sys.executable).with_name("sphrender"))

#: A 64x40 view of the SPlisHSPlasH dam break (particle radius 0.015 m): fast to render.
DAMBREAK_SCENE_TOML = """
[image]
width = 64
height = 40
[camera]
eye = [0.0, 2.5, 5.0]
target = [0.0, 0.5, 0.0]
[particles]
radius = 0.015
"""


def run_sphrender(
    *args: str, env: dict[str, str] | None = None, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    """`sphrender ARGS...` with output captured; never raises on a non-zero exit."""
    return subprocess.run(
        [SPHRENDER, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, **(env or {})},
        check=False,
    )
