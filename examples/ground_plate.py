"""Writes what examples/ground_plate.toml needs: the plate's particles (as brushed_plate.py) and
a height map of grinding marks (sphrender.server.content.marks, 256 x 256, one channel) as
grinding-marks.exr in ASSETS, the directory the render then names with --env-dir.

    python examples/ground_plate.py plate.npz ASSETS
    sphrender render plate.npz --scene examples/ground_plate.toml --env-dir ASSETS -o plate.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sphrender.server.content.lattice import lattice_slab
from sphrender.server.content.marks import grinding_marks, write_height_map


def main() -> None:
    if len(sys.argv) != 3:
        sys.exit("usage: python examples/ground_plate.py OUTPUT.npz ASSETS_DIR")
    positions = lattice_slab(1.6, 1.0, 3, 0.01)
    np.savez(sys.argv[1], positions=positions)
    assets = Path(sys.argv[2])
    assets.mkdir(parents=True, exist_ok=True)
    marks = write_height_map(assets / "grinding-marks.exr", grinding_marks())
    print(f"{len(positions)} particles -> {sys.argv[1]}; marks -> {marks}")


if __name__ == "__main__":
    main()
