"""Peers measured in the same run, on the same particles, camera and resolution.

Each GL peer runs in a child process (`python -m sphrender.server.bench.peers NAME ...`) so its
own GL context (VTK's EGL window) never meets ours, and a peer that cannot be installed or
started is skipped with the reason instead of stopping the benchmark. Per frame, every GL peer
is timed from "render" to "pixels in host memory, PNG encoded" — what `sphrender render` does
for a PNG.

* `vtk_fluid_narrow_range`, `vtk_fluid_bilateral`: VTK's vtkOpenGLFluidMapper (screen-space
  fluid, Truong & Yuksel's narrow-range filter or its bilateral Gaussian), opaque filtered
  surface, 3 filter iterations, filter radius 5 px (VTK's example values);
* `pyvista_spheres_pbr`: PyVista points rendered as spheres with PBR (metallic 1, roughness
  0.35), point size = the particle's projected diameter at the target;
* `sphrender_render`: the `sphrender render` command itself, PNG output, several frames in one
  process; its log says when each frame's PNG was written, and the steady per-frame time is
  the median spacing of those (it encodes frame N while rendering N + 1).
The CPU peers (pysplashsurf reconstruction, the scipy SPH reference) run in-process (no GL).
"""

from __future__ import annotations

import json
import math
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PeerResult:
    name: str
    ms: float | None  # steady per-frame (or per-run) milliseconds; None = skipped
    note: str

    @property
    def ran(self) -> bool:
        return self.ms is not None


def _vtk_points(positions: F64) -> Any:
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk

    points = vtk.vtkPoints()
    points.SetData(numpy_to_vtk(np.ascontiguousarray(positions, np.float32), deep=True))
    poly = vtk.vtkPolyData()
    poly.SetPoints(points)
    return poly


def _vtk_window(width: int, height: int, camera: dict[str, Any]) -> tuple[Any, Any]:
    import vtk

    renderer = vtk.vtkRenderer()
    window = vtk.vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.AddRenderer(renderer)
    window.SetSize(width, height)
    cam = renderer.GetActiveCamera()
    cam.SetPosition(*camera["eye"])
    cam.SetFocalPoint(*camera["target"])
    cam.SetViewUp(0.0, 1.0, 0.0)
    cam.SetViewAngle(float(camera.get("fov_y", 40.0)))
    return renderer, window


def _vtk_frame_timer(window: Any) -> Callable[[], None]:
    """Render, read the pixels back and encode a PNG in memory."""
    import vtk

    def frame() -> None:
        window.Render()
        grab = vtk.vtkWindowToImageFilter()
        grab.SetInput(window)
        grab.ReadFrontBufferOff()
        writer = vtk.vtkPNGWriter()
        writer.WriteToMemoryOn()
        writer.SetInputConnection(grab.GetOutputPort())
        writer.Write()

    return frame


def _child_vtk_fluid(
    positions: F64, radius: float, width: int, height: int, camera: dict[str, Any], method: str
) -> Callable[[], None]:
    import vtk

    mapper = vtk.vtkOpenGLFluidMapper()
    mapper.SetInputData(_vtk_points(positions))
    mapper.SetParticleRadius(radius)
    mapper.SetSurfaceFilterIterations(3)
    mapper.SetSurfaceFilterRadius(5)
    mapper.SetSurfaceFilterMethod(
        vtk.vtkOpenGLFluidMapper.NarrowRange
        if method == "narrow_range"
        else vtk.vtkOpenGLFluidMapper.BilateralGaussian
    )
    mapper.SetDisplayMode(vtk.vtkOpenGLFluidMapper.FilteredOpaqueSurface)
    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    renderer, window = _vtk_window(width, height, camera)
    renderer.AddVolume(volume)
    renderer.ResetCameraClippingRange()
    print(f"vtk {vtk.vtkVersion.GetVTKVersion()} {window.GetClassName()}", file=sys.stderr)
    return _vtk_frame_timer(window)


def _child_pyvista(
    positions: F64, radius: float, width: int, height: int, camera: dict[str, Any]
) -> Callable[[], None]:
    import pyvista as pv

    eye, target = np.asarray(camera["eye"], float), np.asarray(camera["target"], float)
    fov = math.radians(float(camera.get("fov_y", 40.0)))
    point_px = 2 * radius * (height / 2) / math.tan(fov / 2) / float(np.linalg.norm(eye - target))
    plotter = pv.Plotter(off_screen=True, window_size=[width, height])
    plotter.add_points(
        pv.PolyData(np.ascontiguousarray(positions, np.float32)),
        render_points_as_spheres=True,
        point_size=max(point_px, 1.0),
        pbr=True,
        metallic=1.0,
        roughness=0.35,
        color=(0.56, 0.57, 0.58),
    )
    plotter.camera_position = [tuple(eye), tuple(target), (0.0, 1.0, 0.0)]
    plotter.camera.view_angle = float(camera.get("fov_y", 40.0))
    return _vtk_frame_timer(plotter.render_window)


def _child_vtk_narrow_range(
    positions: F64, radius: float, width: int, height: int, camera: dict[str, Any]
) -> Callable[[], None]:
    return _child_vtk_fluid(positions, radius, width, height, camera, "narrow_range")


def _child_vtk_bilateral(
    positions: F64, radius: float, width: int, height: int, camera: dict[str, Any]
) -> Callable[[], None]:
    return _child_vtk_fluid(positions, radius, width, height, camera, "bilateral")


CHILD_PEERS: dict[str, Callable[[F64, float, int, int, dict[str, Any]], Callable[[], None]]] = {
    "vtk_fluid_narrow_range": _child_vtk_narrow_range,
    "vtk_fluid_bilateral": _child_vtk_bilateral,
    "pyvista_spheres_pbr": _child_pyvista,
}


def _child_main(argv: list[str]) -> None:
    name, npz, width, height, camera_json, radius, frames = argv
    positions = np.load(npz)["positions"]
    frame = CHILD_PEERS[name](
        positions, float(radius), int(width), int(height), json.loads(camera_json)
    )
    times = []
    for _ in range(int(frames) + 1):  # the first frame compiles shaders and uploads
        start = time.perf_counter()
        frame()
        times.append((time.perf_counter() - start) * 1e3)
    print(json.dumps({"ms": times}))


def run_child_peer(
    name: str,
    positions: F64,
    radius: float,
    width: int,
    height: int,
    camera: dict[str, Any],
    frames: int,
    timeout_s: float = 600.0,
) -> PeerResult:
    with tempfile.TemporaryDirectory(prefix="sphrender-peer-") as tmp:
        npz = Path(tmp) / "particles.npz"
        np.savez(npz, positions=positions)
        command = [
            sys.executable,
            "-m",
            "sphrender.server.bench.peers",
            name,
            str(npz),
            str(width),
            str(height),
            json.dumps(camera),
            repr(radius),
            str(frames),
        ]
        try:
            done = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return PeerResult(name, None, f"skipped: no result within {timeout_s:.0f} s")
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        return PeerResult(name, None, f"skipped: {last[:160]}")
    times = json.loads(done.stdout.strip().splitlines()[-1])["ms"]
    steady = statistics.median(times[1:])
    info = next((ln for ln in done.stderr.splitlines() if ln.startswith("vtk ")), "")
    return PeerResult(name, steady, f"first frame {times[0]:.0f} ms {info}".strip())


def run_sphrender_render(
    positions: F64,
    radius: float,
    width: int,
    height: int,
    camera: dict[str, Any],
    frames: int,
    quality: str | None = None,
) -> PeerResult:
    """`sphrender render` on `frames + 1` copies of the particles into PNGs, one process; the
    steady time is the median spacing of the frames' written times after the first."""
    with tempfile.TemporaryDirectory(prefix="sphrender-bench-render-") as tmp:
        root = Path(tmp)
        inputs = []
        for index in range(frames + 1):
            path = root / f"frame_{index:04d}.npz"
            np.savez(path, positions=positions)
            inputs.append(str(path))
        scene = root / "scene.toml"
        eye, target = camera["eye"], camera["target"]
        scene.write_text(
            f"[image]\nwidth = {width}\nheight = {height}\n"
            f"[camera]\neye = {list(eye)}\ntarget = {list(target)}\n"
            f"fov_y = {float(camera.get('fov_y', 40.0))}\n"
            f"[particles]\nradius = {radius}\n"
        )
        out = root / "out"
        command = [sys.executable, "-m", "sphrender.server.cli", "render", "-v", *inputs]
        command += ["--scene", str(scene), "-o", str(out), "--format", "png"]
        if quality:
            command += ["--quality", quality]
        done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        return PeerResult("sphrender_render", None, f"failed: {done.stderr.strip()[-200:]}")
    written = [float(t) for t in re.findall(r"written at ([0-9.]+) s", done.stderr)]
    latency = [float(t) for t in re.findall(r"total ([0-9.]+) ms", done.stderr)]
    if len(written) < 4:
        return PeerResult("sphrender_render", None, "failed: too few frame times in the log")
    # Frames are encoded on a worker thread while the next renders, so frames complete at a
    # steady spacing; the last ones come faster once rendering is done (the queue drains), so
    # the median spacing after the first frame is the steady time, not the mean.
    spacing = np.diff(written[1:]) * 1e3
    return PeerResult(
        "sphrender_render",
        float(np.median(spacing)),
        f"median spacing of written frames; first frame {latency[0]:.0f} ms (programs, IBL "
        f"caches); render-to-file latency {statistics.median(latency[1:]):.0f} ms",
    )


def run_pysplashsurf(positions: F64, radius: float) -> tuple[PeerResult, Any]:
    """Reconstruction time (the offline reference surface); returns the mesh for reuse."""
    try:
        from sphrender.server.bench.mesh_reference import reconstruct

        mesh = reconstruct(positions, radius)
    except ImportError as exc:
        return PeerResult("pysplashsurf_reconstruction", None, f"skipped: {exc}"), None
    note = f"{len(mesh.triangles)} triangles, iso 0.6, cubes 0.5 r, 25 smoothing iterations"
    return PeerResult("pysplashsurf_reconstruction", mesh.seconds * 1e3, note), mesh


def scipy_density_ms(positions: F64, support: float, mass: float) -> float:
    """The scipy SPH reference: cKDTree pairs within the support, cubic-spline density sums in
    float64 (the quantity the renderer's OpenCL pass computes first)."""
    from scipy.spatial import cKDTree

    start = time.perf_counter()
    tree = cKDTree(positions)
    pairs = tree.query_pairs(support, output_type="ndarray")
    q = np.linalg.norm(positions[pairs[:, 0]] - positions[pairs[:, 1]], axis=1) / support
    w = np.where(q <= 0.5, 6 * (q**3 - q**2) + 1, 2 * (1 - q) ** 3)
    w *= 8 / (math.pi * support**3)
    density = np.full(len(positions), mass * 8 / (math.pi * support**3))
    np.add.at(density, pairs[:, 0], mass * w)
    np.add.at(density, pairs[:, 1], mass * w)
    return (time.perf_counter() - start) * 1e3


if __name__ == "__main__":
    _child_main(sys.argv[1:])
