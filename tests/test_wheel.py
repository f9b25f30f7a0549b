"""The wheel ships the product and nothing else: every module of core/, client/ and server/, every
shader and the configs, and none of this repository's studies (benchmarks/studies/), benchmark
shaders, benchmarks, tests or images.

The wheel is built from a copy of the source tree (so no build/ or egg-info lands in the
checkout) with the test extra's setuptools and wheel, without build isolation or the network.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: Source folder -> its folder in the wheel (pyproject's package-dir).
PRODUCT = {"core": "core", "client": "client", "server": "server", "shaders": "shaders"}
#: Modules that must never ship: the studies and a test-only helper, by file name.
NOT_SHIPPED = (
    *("dam_frames.py", "jitter_readings.py", "closeup_crop.py", "sphere_union.py"),
    *("host_time.py", "report_studies.py", "study_shaders.py", "single_passes.py"),
)


def build_wheel(tmp_path: Path) -> list[str]:
    source = tmp_path / "source"
    ignore = shutil.ignore_patterns(
        ".venv", ".git", "build", "dist", "*.egg-info", "__pycache__", ".*_cache", ".reference-*"
    )
    shutil.copytree(REPO, source, ignore=ignore)
    dist = tmp_path / "dist"
    args = ["--no-deps", "--no-build-isolation", "--no-index", "-q", "-w", str(dist)]
    result = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", *args, str(source)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    (wheel,) = dist.glob("sphrender-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        return archive.namelist()


def test_the_wheel_holds_the_product_and_no_study(tmp_path: Path) -> None:
    names = build_wheel(tmp_path)
    shipped = set(names)
    expected = [
        f"sphrender/{PRODUCT[folder]}/{path.relative_to(REPO / folder).as_posix()}"
        for folder in PRODUCT
        for path in sorted((REPO / folder).rglob("*"))
        if path.suffix in (".py", ".glsl", ".cl") and "__pycache__" not in path.parts
    ]
    assert len(expected) > 150
    missing = [name for name in expected if name not in shipped]
    assert not missing, missing
    assert any(name.startswith("sphrender/configs/") and name.endswith(".toml") for name in names)
    assert "sphrender/server/bench/run.py" in shipped  # `sphrender bench` stays
    for name in names:
        top = name.split("/", 1)[0]
        assert top == "sphrender" or top.endswith(".dist-info"), name
        assert not name.startswith("sphrender/shaders/bench/"), name
        assert "/studies/" not in name and "benchmarks" not in name, name
        assert not name.endswith((".png", *NOT_SHIPPED)), name
