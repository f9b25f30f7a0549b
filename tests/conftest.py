"""Shared fixtures: one real EGL context and renderer, one real OpenCL (PoCL) context and SPH
engine for the whole test session.

pytest runs tests on its main thread, which creates the contexts and therefore owns them, exactly
as the render thread will in the service.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import pytest

from sphrender.server.engine.gpu.cl_context import CLContext
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.engine.sph.engine import SphEngine

if TYPE_CHECKING:
    from service_harness import ServerProcess

REPO = Path(__file__).resolve().parents[1]
#: Real SPH frames vendored with the tests (a slab of the SPlisHSPlasH dam break, tests/data/).
DAMBREAK = REPO / "tests" / "data" / "dambreak-splishsplash"
# This repository's studies (benchmarks/studies/, not in the wheel) import as `benchmarks.studies`.
if str(REPO) not in sys.path:
    sys.path.append(str(REPO))


@pytest.fixture(scope="session")
def gl_context() -> Iterator[GLContext]:
    with GLContext() as gl:
        yield gl


@pytest.fixture(scope="session")
def renderer(gl_context: GLContext) -> Iterator[SurfaceRenderer]:
    renderer = SurfaceRenderer(gl_context)
    yield renderer
    renderer.release()


@pytest.fixture(scope="session")
def cl_context() -> Iterator[CLContext]:
    with CLContext() as cl:
        yield cl


@pytest.fixture(scope="session")
def sph_engine(cl_context: CLContext) -> Iterator[SphEngine]:
    engine = SphEngine(cl_context)
    yield engine
    engine.release()


@pytest.fixture(scope="session")
def dambreak() -> Path:
    """The vendored real frames; missing data is a failure, never a skip."""
    if not (DAMBREAK / "vtk").is_dir() or not (DAMBREAK / "bgeo").is_dir():
        pytest.fail(f"vendored dam-break frames not found at {DAMBREAK} (tests/data/README.md)")
    return DAMBREAK


@pytest.fixture(scope="session")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """One real `sphrender serve` process on loopback shared by the service tests."""
    from service_harness import MAIN_CONFIG, ServerProcess

    with ServerProcess(tmp_path_factory.mktemp("service"), MAIN_CONFIG) as server:
        yield server
