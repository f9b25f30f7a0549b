"""The scene key ``quality.preset`` over the wire renders what the CLI's ``--quality`` renders:
over HTTP, in HELLO, and as a frame's override (which the session's own keys still win over)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from service_harness import ServerProcess, png_pixels

from sphrender.client.api import Client
from sphrender.core.errors import InputError
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.scene import scene_from_dict

CLI = (sys.executable, "-m", "sphrender.server.cli")
SCENE_TOML = (
    "[image]\nwidth = 96\nheight = 64\n[camera]\neye = [0.25, 0.2, 0.35]\n"
    "[particles]\nradius = 0.01\n"
)
SCENE: dict[str, Any] = {
    "image": {"width": 96, "height": 64},
    "camera": {"eye": [0.25, 0.2, 0.35]},
    "particles": {"radius": 0.01},
}


def cli_png(tmp_path: Path, particles: Path, preset: str) -> np.ndarray:
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE_TOML)
    out = tmp_path / f"cli-{preset}.png"
    command = [*CLI, "render", str(particles), "--scene", str(scene), "--quality", preset]
    done = subprocess.run([*command, "-o", str(out)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return png_pixels(out.read_bytes(), tmp_path)


def test_preset_over_the_wire_matches_the_cli(service: ServerProcess, tmp_path: Path) -> None:
    positions = jittered_lattice_ball(0.1, 0.01)
    particles = tmp_path / "ball.npz"
    np.savez(particles, positions=positions)
    fast, best = cli_png(tmp_path, particles, "fast"), cli_png(tmp_path, particles, "best")
    assert not np.array_equal(fast, best)  # the presets differ on this frame

    client = Client(f"http://127.0.0.1:{service.http_port}")
    with_fast = {**SCENE, "quality": {"preset": "fast"}}
    http = client.render(positions, with_fast, format="png")
    assert np.array_equal(png_pixels(http, tmp_path), fast)

    with client.stream({**SCENE, "quality": {"preset": "best"}}, compact=False) as session:
        assert session.welcome["scene"]["quality"]["preset"] == "best"
        session.send(positions, scene={"output": {"format": "png"}})
        session.send(positions, scene={"quality": {"preset": "fast"}, "output": {"format": "png"}})
        as_best, as_fast = session.receive(), session.receive()
    assert as_best.kind == as_fast.kind == "image", (as_best.header, as_fast.header)
    assert np.array_equal(png_pixels(as_best.data, tmp_path), best)
    assert np.array_equal(png_pixels(as_fast.data, tmp_path), fast)

    status, body = service.json("POST", "/v1/sessions", {"quality": {"preset": "ultra"}})
    assert status == 400 and body["field"] == "quality.preset"
    assert body["error"] == 'must be one of "fast", "balanced", "best", got "ultra"'


def test_the_scene_keys_win_over_the_preset() -> None:
    scene = scene_from_dict({"quality": {"preset": "fast", "iterations": 3}})
    fast = scene_from_dict({"quality": {"preset": "fast"}})
    assert scene.quality.iterations == 3 and fast.quality.iterations == 1
    assert scene.shading == fast.shading and scene.sph == fast.sph
    assert scene_from_dict({"quality": {"preset": "balanced"}}) == scene_from_dict({})
    with pytest.raises(InputError) as caught:
        scene_from_dict({"quality": {"preset": None}})
    assert caught.value.field == "quality.preset" and caught.value.message.endswith("got null")
