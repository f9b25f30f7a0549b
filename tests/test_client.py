"""The Python client and `sphrender submit --server` against a real server on loopback."""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from cli_harness import DAMBREAK_SCENE_TOML, SPHRENDER
from service_harness import MAIN_CONFIG, SMALL_SCENE, ServerProcess, ball, reference_png

from sphrender.client.api import Client, ServerError, ServerUnavailable, decode_exr
from sphrender.core.frame import make_frame
from sphrender.core.image_check import is_complete_exr
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.encoders import read_exr

SCENE_TOML = DAMBREAK_SCENE_TOML


def url(server: ServerProcess) -> str:
    return f"http://127.0.0.1:{server.http_port}"


def test_render_matches_the_engine(service: ServerProcess, renderer: SurfaceRenderer) -> None:
    positions = ball(1500)
    png = Client(url(service)).render(positions, SMALL_SCENE)
    assert png == reference_png(renderer, positions, SMALL_SCENE)


def test_server_notes_reach_the_client_and_the_submitter_logs_them_once(
    service: ServerProcess, tmp_path: Path
) -> None:
    """Densities in other units (x 7: molten steel in kg/m^3 against sph.rest_density 1000):
    `render_frame_noted` returns the image and the server's note on `densities`; frames in
    the scene's units come back without one; `sphrender submit --server` over three such
    frames renders all three and logs the note once."""
    positions = ball(1500, seed=2)
    water = np.linspace(980.0, 1010.0, len(positions), dtype=np.float32)
    client = Client(url(service))
    png, notes = client.render_frame_noted(make_frame(positions, densities=7 * water), SMALL_SCENE)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert [n["field"] for n in notes] == ["densities"], notes
    _, none = client.render_frame_noted(make_frame(positions, densities=water), SMALL_SCENE)
    assert none == []
    frames = tmp_path / "frames"
    frames.mkdir()
    for n in range(3):
        np.savez(frames / f"f_{n}.npz", positions=positions, densities=7 * water)
    scene = tmp_path / "scene.toml"
    scene.write_text(
        "[image]\nwidth = 64\nheight = 48\n[camera]\neye = [0.0, 0.4, 1.6]\n"
        "[particles]\nradius = 0.02\n"
    )
    command = [
        SPHRENDER,
        "submit",
        str(frames),
        "--server",
        url(service),
        "-o",
        str(tmp_path / "o"),
    ]
    result = subprocess.run(
        [*command, "--scene", str(scene)], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    assert "3 rendered" in result.stderr
    assert result.stderr.count("the server noted densities") == 1, result.stderr


def test_render_arrays_decodes_exr_with_numpy_only(
    service: ServerProcess, renderer: SurfaceRenderer
) -> None:
    """The client's own EXR decoder (zlib + numpy) against the engine's arrays."""
    from sphrender.server.scene import scene_from_dict

    positions = ball(1500)
    scene = {**SMALL_SCENE, "output": {"exr_pixel_type": "float"}}
    channels = Client(url(service)).render_arrays(positions, scene)
    frame, _ = renderer.render(
        make_frame(positions), scene_from_dict(scene), depth=True, normals=True
    )
    assert frame.depth is not None and frame.normals is not None
    assert np.array_equal(channels["Z"], frame.depth)
    assert np.array_equal(channels["N.Z"], frame.normals[:, :, 2])
    assert np.array_equal(channels["A"], frame.rgba[:, :, 3])


def test_server_errors_carry_field_and_code(service: ServerProcess) -> None:
    positions = ball(100)
    positions[7, 1] = np.nan
    with pytest.raises(ServerError) as info:
        Client(url(service)).render(positions, SMALL_SCENE)
    assert (info.value.status, info.value.code, info.value.field) == (
        400,
        "bad_input",
        "positions[7]",
    )
    with pytest.raises(ServerError) as info:
        Client(url(service)).render(ball(10), {"camera": {"fov_y": 500}})
    assert info.value.field == "camera.fov_y"


def test_unreachable_server_is_retried_then_reported() -> None:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    client = Client(f"http://127.0.0.1:{port}", retries=2, backoff_s=0.01)
    start = time.monotonic()
    with pytest.raises(ServerUnavailable, match="after 3 attempts"):
        client.info()
    assert time.monotonic() - start < 5


def test_stream_session_pipelines_in_order(service: ServerProcess) -> None:
    frames = [make_frame(ball(300, seed=i)) for i in range(12)]
    client = Client(url(service))
    # Raw frames (the compact encoding, the default, moves positions by up to radius / 100:
    # tests/test_service_compact.py checks it renders its decoded particles exactly).
    with client.stream(SMALL_SCENE, max_in_flight=4, compact=False) as session:
        assert session.compact is None
        results = list(session.render_all(frames))
    assert [r.id for r in results] == list(range(12))
    assert all(r.kind == "image" and r.data.startswith(b"\x89PNG") for r in results)
    one = client.render(frames[3].positions, SMALL_SCENE)
    assert results[3].data == one  # the stream and HTTP give the same bytes


def test_submit_to_server_exr_then_resume(
    tmp_path: Path, service: ServerProcess, dambreak: Path
) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE_TOML)
    out = tmp_path / "out"
    command = [SPHRENDER, "submit", str(dambreak / "vtk"), "--server", url(service)]
    command += ["--scene", str(scene), "-o", str(out), "--format", "exr", "--jobs", "3"]
    first = subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)
    assert first.returncode == 0, first.stderr
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(p.with_suffix(".exr").name for p in (dambreak / "vtk").glob("*.vtk"))
    for name in names:
        assert is_complete_exr(out / name)
        assert {"Z", "N.X", "N.Y", "N.Z"} <= set(read_exr(out / name))
    # same pixels as the local engine
    local = tmp_path / "local"
    subprocess.run(
        [
            SPHRENDER,
            "submit",
            str(dambreak / "vtk" / "ParticleData_Fluid_5.vtk"),
            "--local",
            "--scene",
            str(scene),
            "-o",
            str(local),
            "--format",
            "exr",
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    remote_z = decode_exr((out / "ParticleData_Fluid_5.exr").read_bytes())["Z"]
    assert np.array_equal(remote_z, read_exr(local / "ParticleData_Fluid_5.exr")["Z"])

    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    again = subprocess.run([*command, "--resume"], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"0 rendered, {len(names)} skipped" in again.stderr
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_submit_survives_a_server_restart(tmp_path: Path, dambreak: Path) -> None:
    """The server is stopped after a few frames and started again on the same port: the
    submitter retries with backoff and completes every frame exactly once."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for n in range(24):
        shutil.copyfile(dambreak / "vtk" / "ParticleData_Fluid_1.vtk", frames / f"f_{n}.vtk")
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE_TOML)
    out = tmp_path / "out"
    first = ServerProcess(tmp_path / "server-1", MAIN_CONFIG)
    port = first.http_port
    submitter = subprocess.Popen(
        [
            SPHRENDER,
            "submit",
            str(frames),
            "--server",
            f"http://127.0.0.1:{port}",
            "--scene",
            str(scene),
            "-o",
            str(out),
            "--jobs",
            "1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(list(out.glob("*.png"))) < 3:
            time.sleep(0.02)
        assert first.stop() == 0
        down_at = time.monotonic()
        restarted: list[ServerProcess] = []
        thread = threading.Thread(
            target=lambda: restarted.append(
                ServerProcess(tmp_path / "server-2", MAIN_CONFIG, args=("--port", str(port)))
            )
        )
        time.sleep(1.0)  # the submitter meets a closed port meanwhile
        thread.start()
        thread.join(120)
        assert restarted, "the server did not restart"
        _stdout, stderr = submitter.communicate(timeout=300)
        assert submitter.returncode == 0, stderr
        assert "24 rendered, 0 skipped (already complete), 0 failed" in stderr
        assert len(list(out.glob("*.png"))) == 24
        assert time.monotonic() - down_at > 1.0
        restarted[0].stop()
    finally:
        if submitter.poll() is None:
            submitter.kill()
        first.stop()


def test_submit_bgeo_to_server_and_kill_then_resume(
    tmp_path: Path, service: ServerProcess, dambreak: Path
) -> None:
    """bgeo frames end to end through the server; then a run killed mid-way and resumed renders
    each remaining frame once and leaves no partial file."""
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE_TOML)
    bgeo_out = tmp_path / "bgeo"
    result = subprocess.run(
        [
            SPHRENDER,
            "submit",
            str(dambreak / "bgeo"),
            "--server",
            url(service),
            "-o",
            str(bgeo_out),
            "--scene",
            str(scene),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in bgeo_out.iterdir()) == [
        "ParticleData_Fluid_11.png",
        "ParticleData_Fluid_5.png",
    ]

    frames = tmp_path / "frames"
    frames.mkdir()
    for n in range(30):
        shutil.copyfile(dambreak / "vtk" / "ParticleData_Fluid_1.vtk", frames / f"f_{n}.vtk")
    out = tmp_path / "out"
    command = [SPHRENDER, "submit", str(frames), "--server", url(service), "-o", str(out)]
    command += ["--scene", str(scene), "--jobs", "2"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list(out.glob("*.png"))) < 3:
        time.sleep(0.02)
    process.kill()
    process.wait(30)
    finished = {p.name: p.stat().st_mtime_ns for p in out.glob("*.png")}
    assert 3 <= len(finished) < 30
    rerun = subprocess.run([*command, "--resume"], capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert f"{30 - len(finished)} rendered, {len(finished)} skipped" in rerun.stderr
    assert all((out / n).stat().st_mtime_ns == t for n, t in finished.items())
    assert len(list(out.glob("*.png"))) == 30
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_progress_bar_on_a_terminal(tmp_path: Path, service: ServerProcess, dambreak: Path) -> None:
    """On a terminal the submitter draws one updating bar (frames, fps, ETA); piped, it logs
    one line per frame (the other tests)."""
    import os
    import pty

    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE_TOML)
    leader, follower = pty.openpty()
    process = subprocess.Popen(
        [
            SPHRENDER,
            "submit",
            str(dambreak / "bgeo"),
            "--server",
            url(service),
            "-o",
            str(tmp_path / "out"),
            "--scene",
            str(scene),
        ],
        stdout=follower,
        stderr=follower,
    )
    os.close(follower)
    output = b""
    while True:
        try:
            chunk = os.read(leader, 4096)
        except OSError:  # EIO: the child closed the terminal
            break
        if not chunk:
            break
        output += chunk
    os.close(leader)
    assert process.wait(60) == 0
    text = output.decode(errors="replace")
    assert "\r[" in text and "2/2 frames" in text and "fps" in text and "ETA" in text
