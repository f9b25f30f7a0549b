"""Writes the bench's solid workpieces as particle files with their `solid` flags and a scene
for each: a yawed plate, and a single-V butt joint (two plates with 30-degree bevels, a root face
and a root gap of 4 r) with a small molten bead in the groove, flagged fluid.

    cd examples/workpieces && ../../.venv/bin/python make_frames.py
    ../../.venv/bin/sphrender render plate.npz --scene plate.toml -o plate.png
    ../../.venv/bin/sphrender render bevel_joint.npz --scene bevel_joint.toml -o joint.png
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sphrender.server.bench.solid_scenes import bevel_joint_scene, plate_scene

HERE = Path(__file__).resolve().parent


def _toml(camera: dict[str, list[float] | float], radius: float) -> str:
    eye = ", ".join(f"{v:.4f}" for v in camera["eye"])  # type: ignore[union-attr]
    target = ", ".join(f"{v:.4f}" for v in camera["target"])  # type: ignore[union-attr]
    return (
        "# A solid workpiece: the frame's `solid` flags pick the particles drawn with flat faces.\n"
        "[image]\nwidth = 960\nheight = 540\n\n"
        f"[camera]\neye = [{eye}]\ntarget = [{target}]\nfov_y = 40.0\n\n"
        f"[particles]\nradius = {radius}\n\n"
        '[solids]\nsource = "flag"\n\n'
        "[[lights]]\ndirection = [-0.4, -1.0, -0.6]\nintensity = 2.0\n"
    )


def main() -> None:
    plate = plate_scene()
    np.savez(
        HERE / "plate.npz", positions=plate.positions, solid=np.ones(len(plate.positions), np.uint8)
    )
    (HERE / "plate.toml").write_text(_toml(plate.camera, plate.radius))
    joint = bevel_joint_scene()
    r = joint.radius
    along = np.arange(-20, 21) * 2 * r
    bead = np.stack(np.meshgrid([-2 * r, 0.0, 2 * r], [4 * r, 6 * r], along, indexing="ij"), -1)
    bead = bead.reshape(-1, 3)
    positions = np.concatenate([joint.positions, bead])
    solid = np.concatenate([np.ones(len(joint.positions), np.uint8), np.zeros(len(bead), np.uint8)])
    temperatures = np.concatenate(
        [np.full(len(joint.positions), 900.0), np.full(len(bead), 1900.0)]
    )
    np.savez(HERE / "bevel_joint.npz", positions=positions, solid=solid, temperatures=temperatures)
    (HERE / "bevel_joint.toml").write_text(_toml(joint.camera, r))


if __name__ == "__main__":
    main()
