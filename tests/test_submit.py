"""The batch submitter with the embedded engine (`sphrender submit --local`): real processes,
real GL, real encoders; sequences from the vendored dam-break frames (tests/data/)."""

from __future__ import annotations

import os
import shutil
import signal
import struct
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from cli_harness import DAMBREAK_SCENE_TOML, SPHRENDER

from sphrender.client.sequences import expand_inputs, frame_stem, plan_jobs
from sphrender.core.errors import InputError
from sphrender.core.image_check import is_complete_exr, is_complete_png
from sphrender.server.output.encoders import read_exr

SCENE = DAMBREAK_SCENE_TOML


def submit(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [SPHRENDER, "submit", "--local", *args],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


@pytest.fixture
def scene_file(tmp_path: Path) -> Path:
    path = tmp_path / "scene.toml"
    path.write_text(SCENE)
    return path


def stray_files(directory: Path) -> list[str]:
    return [p.name for p in directory.iterdir() if p.name.startswith(".") or "partial" in p.name]


def test_natural_order_and_names(tmp_path: Path) -> None:
    for n in (10, 2, 1):
        (tmp_path / f"ParticleData_Fluid_{n}.npy").write_bytes(b"")
    (tmp_path / "notes.txt").write_text("not a frame")
    found = expand_inputs([str(tmp_path)])
    assert [p.name for p in found] == [
        "ParticleData_Fluid_1.npy",
        "ParticleData_Fluid_2.npy",
        "ParticleData_Fluid_10.npy",
    ]
    assert expand_inputs([str(tmp_path / "*_1*.npy")])[0].name == "ParticleData_Fluid_1.npy"
    assert frame_stem(Path("a/frame_3.bgeo.gz")) == "frame_3"
    with pytest.raises(InputError, match="matches no particle files"):
        expand_inputs([str(tmp_path / "*.vtk")])
    with pytest.raises(InputError, match="does not exist"):
        expand_inputs([str(tmp_path / "missing.vtk")])
    with pytest.raises(InputError, match="would both write"):
        plan_jobs([Path("a/f_1.vtk"), Path("b/f_1.bgeo")], tmp_path, ".png")


def test_dambreak_vtk_and_bgeo_to_exr_then_resume_changes_nothing(
    tmp_path: Path, dambreak: Path, scene_file: Path
) -> None:
    out = tmp_path / "out"
    vtk = str(dambreak / "vtk")
    bgeo = str(dambreak / "bgeo" / "*.bgeo")
    first = submit(vtk, "--scene", str(scene_file), "-o", str(out), "--format", "exr")
    assert first.returncode == 0, first.stderr
    # bgeo frames 5 and 11 share names with the VTK frames: separate directory
    second = submit(
        bgeo, "--scene", str(scene_file), "-o", str(tmp_path / "bgeo"), "--format", "exr"
    )
    assert second.returncode == 0, second.stderr
    expected = sorted(p.with_suffix(".exr").name for p in (dambreak / "vtk").glob("*.vtk"))
    assert len(expected) >= 3
    assert sorted(p.name for p in out.iterdir()) == expected
    for path in out.iterdir():
        assert is_complete_exr(path)
        channels = read_exr(path)
        assert {"R", "G", "B", "A", "Z", "N.X", "N.Y", "N.Z"} <= set(channels)
        covered = channels["A"] > 0
        assert covered.any()
        assert np.all(np.isinf(channels["Z"][~covered]))
    # the same frame from bgeo renders the same pixels as from VTK (same particles, same order)
    a = read_exr(out / "ParticleData_Fluid_5.exr")
    b = read_exr(tmp_path / "bgeo" / "ParticleData_Fluid_5.exr")
    assert np.array_equal(a["Z"], b["Z"])

    before = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.iterdir()}
    again = submit(vtk, "--scene", str(scene_file), "-o", str(out), "--format", "exr", "--resume")
    assert again.returncode == 0, again.stderr
    assert f"0 rendered, {len(expected)} skipped" in again.stderr
    after = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.iterdir()}
    assert after == before
    assert stray_files(out) == []


def test_killed_run_resumes_without_rendering_twice(
    tmp_path: Path, dambreak: Path, scene_file: Path
) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    source = dambreak / "vtk" / "ParticleData_Fluid_1.vtk"
    for n in range(40):
        shutil.copyfile(source, frames / f"frame_{n}.vtk")
    out = tmp_path / "out"
    process = subprocess.Popen(
        [SPHRENDER, "submit", "--local", str(frames), "--scene", str(scene_file), "-o", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        done = list(out.glob("*.png")) if out.exists() else []
        if len(done) >= 3:
            break
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=30)
    finished = {p.name: p.stat().st_mtime_ns for p in out.glob("*.png")}
    assert 3 <= len(finished) < 40, "kill landed too late to test anything"
    for name in finished:
        assert is_complete_png(out / name)

    rerun = submit(str(frames), "--scene", str(scene_file), "-o", str(out), "--resume")
    assert rerun.returncode == 0, rerun.stderr
    assert f"{40 - len(finished)} rendered, {len(finished)} skipped" in rerun.stderr
    for name, mtime in finished.items():
        assert (out / name).stat().st_mtime_ns == mtime  # not rendered twice
    assert len(list(out.glob("*.png"))) == 40
    assert stray_files(out) == []


def test_corrupt_frame_is_reported_and_others_render(
    tmp_path: Path, dambreak: Path, scene_file: Path
) -> None:
    frames = tmp_path / "frames"
    frames.mkdir()
    for n in (1, 11):
        shutil.copyfile(dambreak / "vtk" / f"ParticleData_Fluid_{n}.vtk", frames / f"f_{n}.vtk")
    data = (dambreak / "vtk" / "ParticleData_Fluid_5.vtk").read_bytes()
    (frames / "f_2.vtk").write_bytes(data[: len(data) // 3])
    out = tmp_path / "out"
    result = submit(str(frames), "--scene", str(scene_file), "-o", str(out))
    assert result.returncode == 4
    assert "Traceback" not in result.stderr
    assert "FAILED" in result.stderr and "f_2.vtk" in result.stderr
    assert "2 rendered, 0 skipped (already complete), 1 failed" in result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["f_1.png", "f_11.png"]


def test_attribute_map_option(tmp_path: Path, scene_file: Path) -> None:
    path = tmp_path / "f_1.csv"
    path.write_text("x,y,z,rho\n0,0,0,1000\n0.05,0,0,1000\n")
    ok = submit(
        str(path),
        "--scene",
        str(scene_file),
        "-o",
        str(tmp_path / "o"),
        "--attribute",
        "density=rho",
    )
    assert ok.returncode == 0, ok.stderr
    bad = submit(
        str(path),
        "--scene",
        str(scene_file),
        "-o",
        str(tmp_path / "p"),
        "--attribute",
        "density=dens",
    )
    assert bad.returncode == 4 and "attribute_map.density" in bad.stderr


def test_image_checks_detect_truncation(tmp_path: Path) -> None:
    png = tmp_path / "a.png"
    result = subprocess.run(
        [SPHRENDER, "demo", "-o", str(png)], capture_output=True, timeout=120, check=False
    )
    assert result.returncode == 0
    assert is_complete_png(png)
    data = png.read_bytes()
    (tmp_path / "t.png").write_bytes(data[:-1])
    assert not is_complete_png(tmp_path / "t.png")
    (tmp_path / "c.png").write_bytes(data[:100] + bytes([data[100] ^ 1]) + data[101:])
    assert not is_complete_png(tmp_path / "c.png")
    assert not is_complete_exr(png)
    os.truncate(png, 0)
    assert not is_complete_png(png)


def exr_offset_table(data: bytes) -> int:
    """Byte offset of a single-part scanline EXR's chunk offset table (after the header)."""
    pos = 8  # magic + version
    while True:
        end = data.index(b"\0", pos)
        if end == pos:
            return pos + 1  # the empty name that ends the header
        type_end = data.index(b"\0", end + 1)
        (size,) = struct.unpack_from("<i", data, type_end + 1)
        pos = type_end + 5 + size


def damage(path: Path, how: str) -> None:
    """What an interrupted or broken writer can leave under a final name."""
    data = path.read_bytes()
    if how == "truncated":
        path.write_bytes(data[: len(data) * 2 // 3])
    elif how == "empty":
        path.write_bytes(b"")
    elif how == "corrupt" and path.suffix == ".png":  # one byte flipped: a chunk CRC fails
        middle = len(data) // 2
        path.write_bytes(data[:middle] + bytes([data[middle] ^ 0x5A]) + data[middle + 1 :])
    elif how == "corrupt":  # EXR: offset table still zero, as OpenEXR leaves it until close
        table = exr_offset_table(data)
        path.write_bytes(data[:table] + bytes(8) + data[table + 8 :])
    else:
        raise ValueError(how)


def ball_positions(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    positions: np.ndarray = rng.normal(size=(400, 3)) * 0.1 + np.array([0.0, 0.5, 0.0])
    return positions


@pytest.mark.parametrize("fmt", ["png", "exr"])
def test_resume_renders_again_what_is_damaged_under_its_final_name(
    tmp_path: Path, scene_file: Path, fmt: str
) -> None:
    """`--resume` skips only complete images. A truncated file, a corrupt one of the right
    length (PNG: a flipped byte, so a chunk CRC fails; EXR: the chunk offset table still zero)
    and a zero-length file, each under its final name, are rendered again, byte for byte what
    the first run wrote; intact outputs are left alone (same mtime). The atomic writer never
    leaves these itself (the kill test), but a full disk, a copy or another tool can."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for n in range(5):
        np.save(frames / f"f_{n}.npy", ball_positions(n))
    out = tmp_path / "out"
    args = [str(frames), "--scene", str(scene_file), "-o", str(out), "--format", fmt]
    first = submit(*args)
    assert first.returncode == 0, first.stderr
    fresh = {p.name: p.read_bytes() for p in out.iterdir()}
    assert len(fresh) == 5
    cases = {"f_0": "truncated", "f_1": "empty", "f_2": "corrupt"}
    for stem, how in cases.items():
        damage(out / f"{stem}.{fmt}", how)
        assert (out / f"{stem}.{fmt}").read_bytes() != fresh[f"{stem}.{fmt}"]
    intact = {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.stem not in cases}
    rerun = submit(*args, "--resume")
    assert rerun.returncode == 0, rerun.stderr
    assert "3 rendered, 2 skipped" in rerun.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == fresh
    for name, mtime in intact.items():
        assert (out / name).stat().st_mtime_ns == mtime
    assert stray_files(out) == []
