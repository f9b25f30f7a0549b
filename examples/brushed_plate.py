"""Writes the particles of examples/brushed_plate.toml: a flat plate of lattice particles
(1.6 x 1.0, three layers 2 r apart, r = 0.01; 12393 particles) as an .npz file.

    python examples/brushed_plate.py plate.npz
"""

from __future__ import annotations

import sys

import numpy as np

from sphrender.server.content.lattice import lattice_slab


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit("usage: python examples/brushed_plate.py OUTPUT.npz")
    positions = lattice_slab(1.6, 1.0, 3, 0.01)
    np.savez(sys.argv[1], positions=positions)
    print(f"{len(positions)} particles -> {sys.argv[1]}")


if __name__ == "__main__":
    main()
