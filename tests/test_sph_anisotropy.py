"""Anisotropic particles (issue 12, Yu & Turk 2013) on OpenCL (real PoCL) against float64 numpy.

Tolerances, derived (u = 2^-24, float32's unit roundoff):
* Eigen-solver (`eigen_sym3_test` runs the kernel's own `eigen_sym3`): cyclic Jacobi with 6
  sweeps applies 18 rotations, each an orthogonal similarity computed with O(u) ||A|| backward
  error (Golub & Van Loan 8.5.4), so the result is the exact decomposition of A + E with ||E||
  <~ 18 u ||A||; by Weyl the eigenvalues err by at most ||E||, the residual ||A v - lambda v||
  by about as much, and V^T V - I by O(18 u). The bound used is 32 u (||A|| = the largest
  |eigenvalue|); measured worst: 6 u (values), 12 u (orthonormality), 7 u (residual) over random,
  rank-1, rank-2, zero and repeated-eigenvalue matrices at scales 1e-30 .. 1e20. Eigenvectors
  of repeated eigenvalues are not unique, so vectors are checked through residual and
  orthonormality, not against numpy's.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest
from scipy.spatial.transform import Rotation

from sphrender.server.engine.sph.engine import SphEngine

U = 2.0**-24
EIGEN_BOUND = 32 * U


def rotated(diagonal: tuple[float, float, float], count: int, seed: int) -> npt.NDArray[np.float64]:
    """`count` matrices R diag(d) R^T with random rotations R."""
    rotations = Rotation.random(count, random_state=seed).as_matrix()
    return np.einsum("nij,j,nkj->nik", rotations, np.asarray(diagonal), rotations)


def symmetric_cases(seed: int = 1) -> dict[str, npt.NDArray[np.float64]]:
    rng = np.random.default_rng(seed)
    random = rng.normal(size=(500, 3, 3))
    return {
        "random": random + random.transpose(0, 2, 1),
        "repeated 1,1,2": rotated((1.0, 1.0, 2.0), 200, seed),
        "repeated 2,1,1": rotated((2.0, 1.0, 1.0), 200, seed + 1),
        "nearly repeated": rotated((1.0, 1.0 + 1e-6, 2.0), 200, seed + 2),
        "isotropic": rotated((1.5, 1.5, 1.5), 50, seed + 3),
        "rank 1": rotated((0.0, 0.0, 1.0), 200, seed + 4),
        "rank 2": rotated((0.0, 1.0, 3.0), 200, seed + 5),
        "rank 2 repeated": rotated((0.0, 1.0, 1.0), 200, seed + 6),
        "indefinite": rotated((1.0, -1.0, 0.0), 200, seed + 7),
        "zero": np.zeros((4, 3, 3)),
        "diagonal": np.diag([3.0, 1.0, 2.0])[None],
    }


@pytest.mark.parametrize("scale", [1.0, 1e-30, 1e-20, 1e20])
@pytest.mark.parametrize("case", list(symmetric_cases()))
def test_eigen_solver_matches_numpy(sph_engine: SphEngine, case: str, scale: float) -> None:
    # the float32 matrix the device sees is the one numpy decomposes (input rounding is not
    # the solver's error)
    a32 = (symmetric_cases()[case] * scale).astype(np.float32)
    a = a32.astype(np.float64)
    values, vectors = sph_engine.anisotropy_kernels().eigen_sym3(a32)
    assert np.isfinite(values).all() and np.isfinite(vectors).all()
    expected = np.linalg.eigh(a)[0][:, ::-1]  # descending, as the kernel
    norm = np.abs(expected).max(axis=1)
    norm = np.where(norm > 0.0, norm, 1.0)  # the zero matrix: absolute errors (all are 0)
    assert (np.abs(values - expected).max(axis=1) <= EIGEN_BOUND * norm).all()
    assert (np.diff(values, axis=1) <= 0.0).all(), "eigenvalues must come sorted descending"
    v = vectors.astype(np.float64)
    gram = np.einsum("nji,njk->nik", v, v)
    assert np.abs(gram - np.eye(3)).max() <= EIGEN_BOUND
    assert np.linalg.det(v).min() > 0.0, "eigenvectors must form a proper rotation"
    residual = np.einsum("nij,njk->nik", a, v) - v * values[:, None, :].astype(np.float64)
    assert (np.linalg.norm(residual, axis=1).max(axis=1) <= EIGEN_BOUND * norm).all()


def test_eigen_solver_zero_matrix_gives_identity(sph_engine: SphEngine) -> None:
    values, vectors = sph_engine.anisotropy_kernels().eigen_sym3(np.zeros((1, 3, 3)))
    assert (values == 0.0).all()
    assert (vectors[0] == np.eye(3, dtype=np.float32)).all()


def test_eigen_solver_no_matrices(sph_engine: SphEngine) -> None:
    values, vectors = sph_engine.anisotropy_kernels().eigen_sym3(np.zeros((0, 3, 3)))
    assert values.shape == (0, 3) and vectors.shape == (0, 3, 3)
