"""The C example client (examples/c_client/, written from PROTOCOL.md alone) against a real
server: compiled with gcc here, run as a process, its stdout and the pixels it wrote checked.

Its raw frame must be the server's render of the particles it sent, byte for byte: the same
engine renders them here (raw rgba8 = the PNG's 8-bit codes, `encode_for_scene`). Its compact
frame (PROTOCOL.md §4.7, written with libzstd) likewise: the server's render of the positions
the C encoder says it encoded, which lie within its bound of the particles it was given. Its
order-free frame (``predict: "cells"``) too, which it decodes itself before sending: the server's
render of the positions in the order the C client sent them, a permutation of the particles.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
from service_harness import ServerProcess

from sphrender.core.frame import make_frame
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.output.local import encode_for_scene
from sphrender.server.scene import scene_from_dict

SOURCE = Path(__file__).resolve().parent.parent / "examples" / "c_client" / "sphr_client.c"
FLAGS = ["-std=c11", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-ffp-contract=off"]
LIBS = ["-lzstd", "-lm"]  # libzstd-dev, deploy/apt/tests.txt
SCENE = {
    "image": {"width": 64, "height": 48},
    "camera": {"eye": [0.6, 0.5, 0.9], "target": [0, 0, 0], "fov_y": 40},
    "particles": {"radius": 0.02},
    "output": {"format": "raw"},
}


def test_c_client_against_a_real_server(
    service: ServerProcess, renderer: SurfaceRenderer, tmp_path: Path
) -> None:
    gcc = shutil.which("gcc")
    assert gcc is not None, (
        "gcc not found: install the packages in deploy/apt/tests.txt (see the README)"
    )
    binary = tmp_path / "sphr_client"
    subprocess.run([gcc, *FLAGS, "-o", str(binary), str(SOURCE), *LIBS], check=True, timeout=120)
    prefix = tmp_path / "out"
    result = subprocess.run(
        [str(binary), "127.0.0.1", str(service.stream_port), str(prefix)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    assert lines[0] == "WELCOME max_in_flight=8"
    assert lines[1].startswith("CELLS cells=") and lines[1].endswith(" roundtrip ok")
    lines = lines[:1] + lines[2:]
    assert lines[1] == f"IMAGE id=1 format=raw 64x48 bytes={64 * 48 * 4}"
    assert lines[2].startswith("IMAGE id=2 format=jpeg 64x48 bytes=")
    assert lines[3] == "JPEG markers ok"
    assert lines[4] == "ERROR id=3 code=bad_input field=radii[17] fatal=false"
    assert lines[5] == f"IMAGE id=4 format=raw 64x48 bytes={64 * 48 * 4}"
    assert lines[6] == f"IMAGE id=5 format=raw 64x48 bytes={64 * 48 * 4}"
    assert lines[7:] == ["GOODBYE reason=bye", "OK"]

    positions = np.fromfile(prefix.with_suffix(".positions"), dtype="<f8").reshape(300, 3)
    assert np.all(np.linalg.norm(positions, axis=1) <= 0.15)
    radii = np.full(300, 0.02, np.float32)
    scene = scene_from_dict(SCENE)
    rendered, _ = renderer.render(make_frame(positions, radii=radii), scene)
    expected = encode_for_scene(rendered, scene, "raw")
    got = prefix.with_suffix(".rgba").read_bytes()
    assert np.count_nonzero(np.frombuffer(expected, np.uint8)[3::4]) > 100  # a visible ball
    assert got == expected
    decoded = np.fromfile(f"{prefix}.compact.positions", dtype="<f8").reshape(300, 3)
    assert np.abs(decoded - positions).max() <= 0.0002  # the C encoder's bound
    assert not np.array_equal(decoded, positions)
    rendered, _ = renderer.render(make_frame(decoded, radii=radii), scene)
    assert Path(f"{prefix}.compact.rgba").read_bytes() == encode_for_scene(rendered, scene, "raw")
    # The order-free frame: a permutation of the particles, each within the bound.
    order = np.fromfile(f"{prefix}.cells.order", dtype="<i4")
    assert sorted(order.tolist()) == list(range(300)) and not np.array_equal(order, np.arange(300))
    sent = np.fromfile(f"{prefix}.cells.positions", dtype="<f8").reshape(300, 3)
    assert np.abs(sent - positions[order]).max() <= 0.0002
    rendered, _ = renderer.render(make_frame(sent, radii=radii), scene)
    assert Path(f"{prefix}.cells.rgba").read_bytes() == encode_for_scene(rendered, scene, "raw")
    jpeg = prefix.with_suffix(".jpg").read_bytes()
    assert jpeg[:2] == b"\xff\xd8" and jpeg[-2:] == b"\xff\xd9"
