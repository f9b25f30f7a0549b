"""The `sphrender` command as a user runs it: a real process, real EGL, real encoders."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from cli_harness import run_sphrender

from sphrender.core.frame import make_frame
from sphrender.server.engine.gpu.gl_libraries import load_error
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.encoders import read_exr
from sphrender.server.scene import load_scene

SMALL_SCENE = """
[image]
width = 120
height = 80

[camera]
eye = [0.6, 0.5, 0.9]
target = [0.0, 0.0, 0.0]
fov_y = 40.0

[particles]
radius = 0.02

[output]
format = "exr"
exr_pixel_type = "float"
"""


@pytest.fixture
def ball_npz(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    positions = rng.normal(size=(3000, 3)) * 0.15
    path = tmp_path / "ball.npz"
    np.savez(path, positions=positions)
    return path


@pytest.fixture
def scene_file(tmp_path: Path) -> Path:
    path = tmp_path / "scene.toml"
    path.write_text(SMALL_SCENE)
    return path


def read_png(path: Path) -> np.ndarray:
    image = oiio.ImageInput.open(str(path))
    assert image is not None, oiio.geterror()
    pixels = image.read_image(format="uint8")
    image.close()
    return np.asarray(pixels)


@pytest.mark.parametrize("command", [[], ["render"], ["sph"], ["demo"], ["info"], ["schema"]])
def test_help(command: list[str]) -> None:
    result = run_sphrender(*command, "--help")
    assert result.returncode == 0
    assert "usage: sphrender" in result.stdout


def test_demo_renders_a_png(tmp_path: Path) -> None:
    out = tmp_path / "demo.png"
    result = run_sphrender("demo", "-o", str(out))
    assert result.returncode == 0, result.stderr
    pixels = read_png(out).astype(np.float64) / 255.0
    assert pixels.shape == (540, 960, 4)
    # The demo shows the workshop behind the plate: opaque everywhere.
    assert np.all(pixels[:, :, 3] == 1.0)
    # The bead glows behind the arc: some pixels are near white (the pool), and a larger set is
    # clearly orange-red (R > G > B by a margin), which steel under the grey hall never is.
    r, g, b = pixels[:, :, 0], pixels[:, :, 1], pixels[:, :, 2]
    glowing = (r > 0.6) & (r > g + 0.15) & (g > b + 0.05)
    assert 0.002 < glowing.mean() < 0.1
    assert (np.minimum(r, g) > 0.95).mean() > 0.001
    # Elsewhere it is a grey scene: the median pixel is nearly neutral.
    assert abs(float(np.median(r)) - float(np.median(b))) < 0.08
    # Heat tint beside the bead: a band of temper blue, which neither the grey hall nor the glow
    # has (0.1% of the pixels without the tint, 6.7% with it).
    assert ((b > r + 0.08) & (b > 0.15)).mean() > 0.02


def test_render_exr_matches_in_process_render(
    tmp_path: Path, ball_npz: Path, scene_file: Path, renderer: SurfaceRenderer
) -> None:
    """Two renders must match: the CLI's float EXR equals the engine's arrays for the same input
    and scene (same driver, same code path), except that EXR colour is premultiplied."""
    out = tmp_path / "ball.exr"
    result = run_sphrender("render", str(ball_npz), "--scene", str(scene_file), "-o", str(out))
    assert result.returncode == 0, result.stderr
    channels = read_exr(out)
    assert set(channels) == {"R", "G", "B", "A", "Z", "N.X", "N.Y", "N.Z"}
    scene = load_scene(scene_file)
    with np.load(ball_npz) as data:
        frame, _ = renderer.render(make_frame(data["positions"]), scene, depth=True, normals=True)
    assert frame.depth is not None and frame.normals is not None
    assert np.array_equal(channels["Z"], frame.depth)
    assert np.array_equal(channels["N.Y"], frame.normals[:, :, 1])
    assert np.array_equal(channels["A"], frame.rgba[:, :, 3])
    assert np.allclose(channels["R"], frame.rgba[:, :, 0] * frame.rgba[:, :, 3])
    # Z is finite exactly where a surface is at the pixel centre; alpha (sub-pixel coverage)
    # is positive there, and may be positive just outside a silhouette too.
    surface = np.isfinite(channels["Z"])
    assert np.all(channels["A"][surface] > 0) and np.all(channels["A"][~surface] < 1)


def test_render_several_inputs_into_a_directory(
    tmp_path: Path, dambreak: Path, scene_file: Path
) -> None:
    inputs = [
        dambreak / "vtk" / "ParticleData_Fluid_1.vtk",
        dambreak / "bgeo" / "ParticleData_Fluid_5.bgeo",
    ]
    out_dir = tmp_path / "frames"
    out_dir.mkdir()
    result = run_sphrender(
        "render",
        *map(str, inputs),
        "--scene",
        str(scene_file),
        "-o",
        str(out_dir),
        "--format",
        "png",
        "-v",
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in out_dir.iterdir()) == [
        "ParticleData_Fluid_1.png",
        "ParticleData_Fluid_5.png",
    ]
    assert "GL renderer" in result.stderr and "splat=" in result.stderr
    for path in out_dir.iterdir():
        assert read_png(path).shape == (80, 120, 4)


def test_info_reports_the_renderer() -> None:
    result = run_sphrender("info")
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert info["gl_renderer"] and info["max_image_side"] >= 1024


def assert_one_line_error(result: subprocess.CompletedProcess[str], code: int, *words: str) -> None:
    assert result.returncode == code, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for word in words:
        assert word in lines[0]


def test_nan_positions_give_a_one_line_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.npz"
    np.savez(bad, positions=np.array([[0.0, 0.0, 0.0], [np.nan, 0.0, 0.0]]))
    result = run_sphrender("render", str(bad), "-o", str(tmp_path / "out.png"))
    assert_one_line_error(result, 2, "positions[1]", "finite", "bad.npz")
    assert not (tmp_path / "out.png").exists()


def test_bad_scene_gives_a_one_line_error(tmp_path: Path, ball_npz: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text("[camera]\nfov_y = 190\n")
    result = run_sphrender(
        "render", str(ball_npz), "--scene", str(scene), "-o", str(tmp_path / "o.png")
    )
    assert_one_line_error(result, 2, "camera.fov_y", "(0, 180)")


def test_degenerate_camera_gives_a_one_line_error(tmp_path: Path, ball_npz: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text("[camera]\neye = [0, 1, 0]\ntarget = [0, 0, 0]\nup = [0, 1, 0]\n")
    result = run_sphrender(
        "render", str(ball_npz), "--scene", str(scene), "-o", str(tmp_path / "o.png")
    )
    assert_one_line_error(result, 2, "camera.up", "parallel")


def test_unreadable_input_gives_a_one_line_error(tmp_path: Path) -> None:
    garbage = tmp_path / "frame.vtk"
    garbage.write_bytes(b"\x00\x01not a vtk file")
    result = run_sphrender("render", str(garbage), "-o", str(tmp_path / "o.png"))
    assert_one_line_error(result, 2, "file", "frame.vtk")
    result = run_sphrender("render", str(tmp_path / "missing.npz"), "-o", str(tmp_path / "o.png"))
    assert_one_line_error(result, 2, "file", "missing.npz")


def test_missing_egl_names_the_library_and_its_package(tmp_path: Path, ball_npz: Path) -> None:
    """glcontext honours GLCONTEXT_LINUX_LIBEGL: point it at a library that does not exist, as
    on a machine without GLVND's EGL."""
    env = {"GLCONTEXT_LINUX_LIBEGL": str(tmp_path / "libEGL.so.1")}
    result = run_sphrender("render", str(ball_npz), "-o", str(tmp_path / "o.png"), env=env)
    assert_one_line_error(result, 3, "libEGL.so.1 does not load", "apt-get install libegl1")


def test_missing_libgl_names_the_library_and_its_package(tmp_path: Path, ball_npz: Path) -> None:
    """The same for the GL library (GLCONTEXT_LINUX_LIBGL), as on a minimal Debian with EGL but
    neither libgl1 nor libopengl0 (glcontext then said only "libGL.so not loaded")."""
    env = {"GLCONTEXT_LINUX_LIBGL": str(tmp_path / "libGL.so.1")}
    result = run_sphrender("render", str(ball_npz), "-o", str(tmp_path / "o.png"), env=env)
    assert_one_line_error(result, 3, "libGL.so.1 does not load", "apt-get install libgl1")
    assert "libegl" not in result.stderr  # EGL loads: nothing else to install


@pytest.mark.parametrize(
    ("variable", "words"),
    [
        ("__EGL_VENDOR_LIBRARY_DIRS", ("no EGL vendor loads", "apt-get install libegl-mesa0")),
        ("LIBGL_DRIVERS_PATH", ("swrast_dri.so is in none of", "apt-get install libgl1-mesa-dri")),
    ],
)
def test_missing_mesa_parts_name_their_package(
    tmp_path: Path, ball_npz: Path, variable: str, words: tuple[str, ...]
) -> None:
    """GLVND finds no vendor file / Mesa finds no driver in an empty folder (real loaders; Mesa
    may warn on stderr before our line)."""
    env = {variable: str(tmp_path / "empty")}
    result = run_sphrender("render", str(ball_npz), "-o", str(tmp_path / "o.png"), env=env)
    assert result.returncode == 3 and "Traceback" not in result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("sphrender: error:") and all(word in last for word in words), last


def test_info_without_gl_still_reports_opencl(tmp_path: Path) -> None:
    env = {"GLCONTEXT_LINUX_LIBGL": str(tmp_path / "libGL.so.1")}
    result = run_sphrender("info", env=env)
    assert_one_line_error(result, 3, "libGL.so.1 does not load")
    info = json.loads(result.stdout)
    assert "libgl1" in info["gl_error"] and "gl_renderer" not in info
    assert isinstance(info["opencl_devices"], list)


@pytest.mark.skipif(
    load_error("libEGL_nvidia.so.0") is None, reason="an NVIDIA driver is installed here"
)
def test_nvidia_vendor_without_a_driver_says_there_is_no_gpu(tmp_path: Path) -> None:
    """What the NVIDIA image reports on a machine without a GPU: GLVND reads only the vendor
    file given in __EGL_VENDOR_LIBRARY_FILENAMES, which names NVIDIA's library (not there)."""
    vendor = tmp_path / "10_nvidia.json"
    vendor.write_text(
        json.dumps({"file_format_version": "1.0.0", "ICD": {"library_path": "libEGL_nvidia.so.0"}})
    )
    result = run_sphrender("info", env={"__EGL_VENDOR_LIBRARY_FILENAMES": str(vendor)})
    assert_one_line_error(result, 3, "libEGL_nvidia.so.0", "no NVIDIA GPU", "--gpus all")


def test_a_corrupt_frame_does_not_stop_the_others(tmp_path: Path, ball_npz: Path) -> None:
    corrupt = tmp_path / "frame_2.npz"
    corrupt.write_bytes(b"PK\x03\x04 truncated zip")
    second = tmp_path / "frame_3.npz"
    second.write_bytes(ball_npz.read_bytes())
    out_dir = tmp_path / "out"
    result = run_sphrender("render", str(ball_npz), str(corrupt), str(second), "-o", str(out_dir))
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "frame_2.npz" in result.stderr and "1 of 3 inputs failed" in result.stderr
    assert sorted(p.name for p in out_dir.iterdir()) == ["ball.png", "frame_3.png"]


def test_unwritable_output_is_a_clear_error(tmp_path: Path, ball_npz: Path) -> None:
    result = run_sphrender(
        "render", str(ball_npz), "-o", str(tmp_path / "no" / "such" / "dir" / "x.png")
    )
    assert_one_line_error(result, 2, "output", "cannot write")
