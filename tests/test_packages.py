"""The system packages, written down in four places, say the same thing: the README's install
line, the CPU image, the NVIDIA image and the engine's own list (which its errors and .ci/run's
probe use). What the set is was found on clean Debian roots by docker/check-images.sh; these
tests only keep the copies from drifting apart (no network, no root)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from sphrender.server.engine.gpu.gl_libraries import MESA_PACKAGES, PACKAGE_OF, package_for

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "docker"))
import chroot_image  # noqa: E402  (docker/ is not a package)

PYTHON = {"python3", "python3-venv"}


def apt_packages(text: str) -> set[str]:
    """The package names of every `apt-get install` in `text` (continuation lines joined)."""
    joined = text.replace("\\\n", " ")
    names: set[str] = set()
    for match in re.finditer(r"apt-get install ([^&\n]*)", joined):
        names |= {word for word in match.group(1).split() if not word.startswith("-")}
    return names


def readme_install_line() -> str:
    lines = (REPO / "README.md").read_text().splitlines()
    return next(line for line in lines if line.startswith("apt-get") and "libegl1" in line)


def test_the_readme_line_is_python_plus_the_engines_mesa_packages() -> None:
    assert apt_packages(readme_install_line()) == PYTHON | set(MESA_PACKAGES)


def test_the_cpu_image_installs_the_readme_set_plus_debians_pocl() -> None:
    packages = apt_packages((REPO / "docker/cpu.Dockerfile").read_text())
    assert packages == PYTHON | set(MESA_PACKAGES) | {"pocl-opencl-icd"}


def test_the_nvidia_image_has_glvnd_but_no_cpu_renderer() -> None:
    text = (REPO / "docker/nvidia.Dockerfile").read_text()
    assert apt_packages(text) == PYTHON | {"libegl1", "libopengl0"}
    assert "NVIDIA_DRIVER_CAPABILITIES=graphics,compute" in text
    assert '"library_path": "libEGL_nvidia.so.0"' in text and "10_nvidia.json" in text
    assert "libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd" in text


def test_every_mesa_package_is_one_the_errors_can_name() -> None:
    assert set(MESA_PACKAGES) <= set(PACKAGE_OF.values())
    assert package_for("/some/where/libGL.so.1") == "libgl1"
    assert package_for("libOpenGL.so.0") == "libopengl0"
    assert package_for("libEGL_mesa.so.0") == "libegl-mesa0"


def test_ci_probes_the_libraries_and_ends_with_the_readme_test_command() -> None:
    ci = (REPO / ".ci/run").read_text()
    assert "python3 server/engine/gpu/gl_libraries.py" in ci
    readme = (REPO / "README.md").read_text()
    test_command = (
        "python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && .venv/bin/python -m pytest"
    )
    assert test_command in readme
    assert ci.rstrip().splitlines()[-1] == test_command


def test_the_probe_runs_as_a_plain_script() -> None:
    """.ci/run runs it with the system python before any venv: standard library only. Here (the
    tests render) nothing is missing."""
    probe = subprocess.run(
        [sys.executable, "-S", str(REPO / "server/engine/gpu/gl_libraries.py")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert (probe.returncode, probe.stdout) == (0, ""), probe.stderr


def test_the_images_steps_are_what_the_chroot_runner_supports() -> None:
    for name in ("cpu.Dockerfile", "nvidia.Dockerfile"):
        steps = chroot_image.parse((REPO / "docker" / name).read_text())
        assert chroot_image.suite(steps) == "bookworm"
        image = chroot_image.build(steps, Path("/nonexistent"), REPO, execute=False)
        assert (image.user, image.workdir) == ("sphrender", "/opt/sphrender")
        assert image.env["PATH"] == "/opt/venv/bin:" + chroot_image.DEFAULT_PATH
