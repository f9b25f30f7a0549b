"""The system packages are listed once, in deploy/apt/ (render.txt, tests.txt, nvidia.txt), and
everything that installs them reads those files: the README's two commands, .ci/run and both
Dockerfiles. These tests keep it that way and keep render.txt equal to the engine's own list of
Mesa packages (which its errors and .ci/run's probe use). What the set is was found on clean
Debian roots by docker/check-images.sh; these tests need no network and no root."""

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
TEST_COMMAND = (
    "python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && .venv/bin/python -m pytest"
)
DEMO_COMMAND = (
    "python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/sphrender demo -o demo.png"
)
TOOL_TESTS = (
    "tests/browser_harness.py",
    "tests/test_replicas_haproxy.py",
    "tests/test_c_client.py",
)


def package_list(name: str) -> list[str]:
    return (REPO / "deploy/apt" / name).read_text().split()


def install_arguments(text: str) -> list[str]:
    """The words after every `apt-get install` in `text` (continuation lines joined), options
    left out."""
    joined = text.replace("\\\n", " ")
    words: list[str] = []
    for match in re.finditer(r"apt-get install ([^&\n]*)", joined):
        words += [word for word in match.group(1).split() if not word.startswith("-")]
    return words


def readme_commands() -> list[list[str]]:
    """The lines of the README's first two ```sh blocks: set up + demo, set up + tests."""
    blocks = re.findall(r"^```sh\n(.*?)^```$", (REPO / "README.md").read_text(), re.M | re.S)
    return [block.splitlines() for block in blocks[:2]]


def test_each_list_is_package_names_one_a_line() -> None:
    for name in ("render.txt", "tests.txt", "nvidia.txt"):
        lines = (REPO / "deploy/apt" / name).read_text().splitlines()
        assert lines and all(re.fullmatch(r"[a-z0-9][a-z0-9.+-]*", line) for line in lines), name
        assert len(set(lines)) == len(lines), name


def test_the_lists_are_python_mesa_pocl_and_what_the_tests_drive() -> None:
    assert set(package_list("render.txt")) == PYTHON | set(MESA_PACKAGES) | {"pocl-opencl-icd"}
    # libzstd-dev: the C example client's compact frames (tests/test_c_client.py).
    tests = {"chromium", "haproxy", "gcc", "libc6-dev", "libzstd-dev"}
    assert set(package_list("tests.txt")) == tests
    assert set(package_list("nvidia.txt")) == PYTHON | {"libegl1", "libopengl0"}


def test_the_readme_opens_with_the_two_commands_reading_the_lists() -> None:
    readme = (REPO / "README.md").read_text()
    assert readme.index("```sh") < readme.index("\n## ")  # before the first section
    demo, tests = readme_commands()
    apt = "sudo apt-get update && sudo apt-get install -y --no-install-recommends "
    assert demo == [apt + "$(cat deploy/apt/render.txt)", DEMO_COMMAND]
    assert tests == [apt + "$(cat deploy/apt/render.txt deploy/apt/tests.txt)", TEST_COMMAND]
    assert all(word.startswith("$(cat") or word.startswith("deploy/apt/")
               for word in install_arguments(readme))  # fmt: skip


def test_ci_installs_both_lists_and_ends_with_the_readme_test_command() -> None:
    ci = (REPO / ".ci/run").read_text()
    assert "cat deploy/apt/render.txt deploy/apt/tests.txt" in ci
    assert install_arguments(ci) == ['"${missing[@]}"']
    assert "python3 server/engine/gpu/gl_libraries.py" in ci
    assert ci.rstrip().splitlines()[-1] == TEST_COMMAND


def test_the_images_install_their_list_and_no_package_of_their_own() -> None:
    for dockerfile, name in (("cpu.Dockerfile", "render.txt"), ("nvidia.Dockerfile", "nvidia.txt")):
        text = (REPO / "docker" / dockerfile).read_text()
        assert " ".join(install_arguments(text)) == f"$(cat deploy/apt/{name})", dockerfile
        steps = chroot_image.parse(text)
        copy = next(i for i, s in enumerate(steps) if s.argument == "deploy/apt deploy/apt")
        install = next(i for i, s in enumerate(steps) if "apt-get install" in s.argument)
        assert steps[copy].keyword == "COPY" and copy < install, dockerfile


def test_the_nvidia_image_has_glvnd_but_no_cpu_renderer() -> None:
    text = (REPO / "docker/nvidia.Dockerfile").read_text()
    assert not {"libgl1-mesa-dri", "pocl-opencl-icd"} & set(package_list("nvidia.txt"))
    assert "NVIDIA_DRIVER_CAPABILITIES=graphics,compute" in text
    assert '"library_path": "libEGL_nvidia.so.0"' in text and "10_nvidia.json" in text
    assert "libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd" in text


def test_a_missing_system_tool_fails_naming_the_list() -> None:
    for path in TOOL_TESTS:
        text = (REPO / path).read_text()
        assert "install the packages in deploy/apt/tests.txt" in text, path
        assert "skipif" not in text and "pytest.skip" not in text, path


def test_every_mesa_package_is_one_the_errors_can_name() -> None:
    assert set(MESA_PACKAGES) <= set(PACKAGE_OF.values())
    assert package_for("/some/where/libGL.so.1") == "libgl1"
    assert package_for("libOpenGL.so.0") == "libopengl0"
    assert package_for("libEGL_mesa.so.0") == "libegl-mesa0"


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
