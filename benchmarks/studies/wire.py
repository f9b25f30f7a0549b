"""The compact frame encoding measured (core/compact.py): bytes a particle, encode and decode
time, the image change against float32 input, and its peers at the same error bound.

Sequences (positions float64 as a simulator writes them):

* **dam break**: the real SPlisHSPlasH frames 1-15 (../shared/data, 32,768 particles, r =
  0.015, 0.2 s apart), tiled side by side to 98,304 (3 copies) and 1,015,808 (31 copies)
  particles (each copy turned by a little and holding another frame: no copy repeats
  another's numbers), with their own densities and a synthetic temperature field (smooth in
  position, 1200-1800 K, plus 1 K noise);
* **spatter**: a pool (lattice slab, r = 0.01) with a slow wave, and 5 % of the particles as
  droplets thrown from its centre on ballistic paths, 30 frames a second.

Each sequence is encoded as one session (frames predicted from the one before where smaller).
Peers on the same positions: zstd and blosc2 (shuffle + zstd) on raw float32 (lossless), Draco
(kd-tree point cloud, quantisation bits for the same bound on its bounding cube) and ZFP
(fixed-accuracy mode, tolerance = the bound, per axis).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from sphrender.core.compact import CompactDecoder
from sphrender.core.compact_encoder import CompactEncoder
from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import lattice_slab

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "dambreak-splishsplash" / "vtk"
DAM_FRAMES = (1, 3, 5, 7, 9, 11, 13, 15)
DAM_RADIUS = 0.015
SPATTER_RADIUS = 0.01
#: Error bounds measured, as fractions of the particle radius.
FRACTIONS = (1 / 25, 1 / 50, 1 / 100, 1 / 200)

Frame = dict[str, np.ndarray]
#: What a CompactEncoder carries from one frame to the next (restored between timing repeats).
_ENCODER_STATE = ("_base_id", "_base", "order", "_cell_bits", "_frames", "_ordered_won",
                  "_cells_bytes")  # fmt: skip


@dataclass(frozen=True)
class CodecRow:
    sequence: str
    particles: int
    fraction: float
    positions_bpp: float  # bytes a particle, frames after the first (the session's steady state)
    frame_bpp: float  # positions + densities + temperatures
    first_bpp: float  # the session's first frame, whole
    encode_ms: float
    decode_ms: float
    max_error_r: float  # measured, in radii
    decode_cpu_ms: float  # the CPU time of the decode (process time)


@dataclass(frozen=True)
class PeerRow:
    peer: str
    fraction: float
    positions_bpp: float
    max_error_r: float
    encode_ms: float
    decode_ms: float


def dam_sequence(copies: int) -> list[Frame] | None:
    if not DATA.is_dir():
        return None
    from sphrender.core.readers import read_particles

    source = [read_particles(DATA / f"ParticleData_Fluid_{n}.vtk") for n in DAM_FRAMES]
    rng = np.random.default_rng(0)
    # Copy k of frame i is frame i + k, turned by its own small rotation (1-4 degrees about a
    # random axis) and moved beside the others: no two copies hold the same numbers, so zstd
    # cannot match one copy against another.
    turns = [_rotation(rng) for _ in range(copies)]
    frames = []
    for i in range(len(source)):
        parts, densities = [], []
        for k in range(copies):
            frame = source[(i + k) % len(source)]
            offset = np.array([4.5 * (k % 8), 0.0, 2.0 * (k // 8)])
            parts.append(frame.positions @ turns[k].T + offset)
            assert frame.densities is not None
            densities.append(frame.densities)
        positions = np.concatenate(parts)
        x, y = positions[:, 0], positions[:, 1]
        kelvin = 1200 + 200 * (3 - y) + 20 * np.sin(5 * x) + rng.normal(0, 1, len(x))
        frames.append(
            {
                "positions": positions,
                "densities": np.concatenate(densities),
                "temperatures": kelvin.astype(np.float32),
            }
        )
    return frames


def _rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation matrix of 1-4 degrees about a random axis (Rodrigues)."""
    axis = rng.normal(size=3)
    x, y, z = axis / np.linalg.norm(axis)
    k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    angle = np.radians(rng.uniform(1, 4))
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def spatter_sequence(count: int, frames: int = 8) -> list[Frame]:
    r = SPATTER_RADIUS
    drops = count // 20
    side = math.sqrt((count - drops) / 4) * 2 * r
    pool = lattice_slab(side, side, 4, r)[: count - drops]
    rng = np.random.default_rng(1)
    start = rng.normal(0, 0.02, (drops, 3)) * [1, 0, 1]
    direction = rng.normal(0, 1, (drops, 3)) * [0.5, 0, 0.5] + [0, 1, 0]
    velocity = (
        direction / np.linalg.norm(direction, axis=1)[:, None] * rng.uniform(1, 3, (drops, 1))
    )
    out = []
    for k in range(frames):
        t = k / 30
        wave = pool.copy()
        wave[:, 1] += 0.002 * np.sin(20 * pool[:, 0] + 10 * t)
        flying = start + velocity * t + 0.5 * np.array([0, -9.81, 0]) * t * t
        positions = np.concatenate([wave, flying])
        kelvin = np.concatenate([1800 - 300 * np.hypot(pool[:, 0], pool[:, 2]) / side,
                                 2600 - 900 * t + rng.normal(0, 5, drops)])  # fmt: skip
        out.append(
            {
                "positions": positions,
                "densities": (1000 + rng.normal(0, 3, len(positions))).astype(np.float32),
                "temperatures": kelvin.astype(np.float32),
            }
        )
    return out


def _best_ms(
    function: Callable[[], Any], repeats: int = 3, clock: Callable[[], float] = time.perf_counter
) -> tuple[float, Any]:
    """The best time of `repeats` calls on `clock` (wall by default; `time.process_time` for
    the CPU time this process spent, which the machine's other load does not inflate)."""
    best, value = math.inf, None
    for _ in range(repeats):
        start = clock()
        value = function()
        best = min(best, (clock() - start) * 1e3)
    return best, value


def _timed_frame(
    encoder: CompactEncoder, decoder: CompactDecoder, frame_id: int, frame: Frame, repeats: int
) -> tuple[float, float, float, dict[str, Any], bytes, Frame]:
    """One frame of a session, encoded and decoded `repeats` times from the same state
    (timings: the best), leaving both sides as after one pass."""
    state = {key: getattr(encoder, key) for key in _ENCODER_STATE}
    # copies: the held integers' buffers go back to the decoder's pool after the first decode
    held = (decoder.base_id, {k: v.copy() for k, v in decoder.base_q.items()})

    def encode() -> tuple[dict[str, Any], bytes]:
        for key, value in state.items():
            setattr(encoder, key, dict(value) if isinstance(value, dict) else value)
        return encoder.encode(frame_id, frame)

    encode_ms, (header, payload) = _best_ms(encode, repeats)

    def decode() -> Frame:
        decoder.base_id, decoder.base_q = held
        return decoder.decode(header, payload, max_particles=10**8)

    decode_ms, arrays = _best_ms(decode, repeats)
    cpu_ms, _ = _best_ms(decode, repeats, time.process_time)
    return encode_ms, decode_ms, cpu_ms, header, payload, arrays


def codec_rows(name: str, frames: list[Frame], radius: float, fractions: tuple[float, ...],
               repeats: int = 3, reorder: bool = True) -> Iterator[CodecRow]:  # fmt: skip
    """The session encoding of `frames` at each bound (timings: the best of `repeats`);
    `reorder` False keeps the particles' order (the coding before order-free positions)."""
    n = len(frames[0]["positions"])
    for fraction in fractions:
        encoder = CompactEncoder(position_error=fraction * radius, reorder=reorder)
        decoder = CompactDecoder()
        sizes, positions_sizes, enc, dec, cpu, worst = [], [], [], [], [], 0.0
        for frame_id, frame in enumerate(frames):
            ms_e, ms_d, ms_cpu, header, payload, arrays = _timed_frame(
                encoder, decoder, frame_id, frame, repeats
            )
            enc.append(ms_e)
            dec.append(ms_d)
            cpu.append(ms_cpu)
            order = encoder.order if encoder.order is not None else slice(None)
            sent = frame["positions"][order]
            worst = max(worst, float(np.abs(arrays["positions"] - sent).max()))
            sizes.append(len(payload))
            positions_sizes.append(header["arrays"][0]["bytes"])
        later = slice(1, None)
        yield CodecRow(
            name, n, fraction,
            float(np.mean(positions_sizes[later])) / n, float(np.mean(sizes[later])) / n,
            sizes[0] / n, float(np.median(enc)), float(np.median(dec)), worst / radius,
            float(np.median(cpu)),
        )  # fmt: skip


def peer_rows(positions: np.ndarray, radius: float, fractions: tuple[float, ...]) -> list[PeerRow]:
    """Peers on one frame's positions (float32 input for the lossless ones)."""
    import blosc2
    import DracoPy
    import zstandard

    n = len(positions)
    f32 = positions.astype(np.float32)
    rows = []
    lossless_error = float(np.abs(f32 - positions).max()) / radius
    compressor, decompressor = zstandard.ZstdCompressor(level=3), zstandard.ZstdDecompressor()
    ms_e, packed = _best_ms(lambda: compressor.compress(f32.tobytes()))
    ms_d, _ = _best_ms(lambda: decompressor.decompress(packed))
    rows.append(PeerRow("zstd, raw float32", 0.0, len(packed) / n, lossless_error, ms_e, ms_d))
    for label, filt in (
        ("shuffle", blosc2.Filter.SHUFFLE),
        ("bitshuffle", blosc2.Filter.BITSHUFFLE),
    ):
        cparams = {"codec": blosc2.Codec.ZSTD, "clevel": 5, "filters": [filt], "typesize": 4}
        ms_e, packed = _best_ms(partial(blosc2.compress2, f32.tobytes(), **cparams))
        ms_d, _ = _best_ms(partial(blosc2.decompress2, packed))
        name = f"blosc2 {label} + zstd, raw float32"
        rows.append(PeerRow(name, 0.0, len(packed) / n, lossless_error, ms_e, ms_d))
    extent = float((positions.max(0) - positions.min(0)).max())
    for fraction in fractions:
        error = fraction * radius
        bits = min(30, math.ceil(math.log2(extent / (2 * error) + 1)))
        while True:  # the fewest bits whose measured error meets the bound
            ms_e, blob = _best_ms(partial(DracoPy.encode, f32, quantization_bits=bits))
            ms_d, mesh = _best_ms(partial(DracoPy.decode, blob))
            worst = _unordered_error(np.asarray(mesh.points), positions)
            if worst <= error or bits >= 30:
                break
            bits += 1
        name = f"Draco, {bits} bits"
        rows.append(PeerRow(name, fraction, len(blob) / n, worst / radius, ms_e, ms_d))
        axes = [np.ascontiguousarray(positions[:, k]) for k in range(3)]

        ms_e, blobs = _best_ms(partial(_zfp_compress, axes, error))
        ms_d, back = _best_ms(partial(_zfp_decompress, blobs))
        worst = max(float(np.abs(b - a).max()) for a, b in zip(axes, back, strict=True))
        size = sum(len(b) for b in blobs)
        rows.append(PeerRow("ZFP, fixed accuracy", fraction, size / n, worst / radius, ms_e, ms_d))
    return rows


def _zfp_compress(axes: list[np.ndarray], error: float) -> list[bytes]:
    import zfpy

    return [zfpy.compress_numpy(a, tolerance=error) for a in axes]


def _zfp_decompress(blobs: list[bytes]) -> list[np.ndarray]:
    import zfpy

    return [zfpy.decompress_numpy(b) for b in blobs]


def _unordered_error(decoded: np.ndarray, original: np.ndarray) -> float:
    """Draco reorders points: the largest distance from an original to its nearest decoded
    point (a lower bound of Draco's true error, whose bound is half its quantum)."""
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(decoded).query(original)
    return float(np.abs(distance).max())


#: Decode timings in a process set up as the service's (server/service/heap.py): its transport
#: threads decode with every block from 128 KiB in a mapping of its own.
_SERVICE_DECODE = """
import json, resource, sys, time
sys.path.insert(0, sys.argv[1])
from sphrender.server.service.heap import configure_malloc
assert configure_malloc()
from benchmarks.studies.wire import DAM_RADIUS, dam_sequence
from sphrender.core.compact import CompactDecoder
from sphrender.core.compact_encoder import CompactEncoder
copies, count, fraction = int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
frames = dam_sequence(copies)[:count]
encoder = CompactEncoder(position_error=fraction * DAM_RADIUS)
messages = [encoder.encode(i, frame) for i, frame in enumerate(frames)]
decoder, cpu, faults = CompactDecoder(), [], []
for header, payload in messages:
    held = (decoder.base_id, {k: v.copy() for k, v in decoder.base_q.items()})
    best = float("inf")
    for _ in range(3):
        decoder.base_id, decoder.base_q = held
        before, start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt, time.process_time()
        decoder.decode(header, payload, max_particles=10**8)
        best = min(best, time.process_time() - start)
        after = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    cpu.append(best * 1e3)
    faults.append(after - before)
later = sorted(zip(cpu[1:], faults[1:]))
print(json.dumps({"particles": len(frames[0]["positions"]), "cpu_ms": later[len(later) // 2][0],
                  "faults": later[len(later) // 2][1]}))
"""


@dataclass(frozen=True)
class ServiceDecode:
    particles: int
    cpu_ms: float  # median over the frames after the first of the best of 3 decodes
    faults: int  # the minor page faults of that decode


def service_decode(copies: int, frames: int, fraction: float) -> ServiceDecode:
    """The session decode of `dam_sequence(copies)[:frames]` at the bound `fraction` x r, timed
    in a child process with the service's malloc settings."""
    import json
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    args = [str(root), str(copies), str(frames), str(fraction)]
    done = subprocess.run([sys.executable, "-c", _SERVICE_DECODE, *args], capture_output=True,
                          text=True, timeout=1800, check=True)  # fmt: skip
    return ServiceDecode(**json.loads(done.stdout))


def decoded_positions(frame: Frame, error: float) -> np.ndarray:
    """`frame`'s positions through the compact encoding at the bound `error` (sent order)."""
    encoder = CompactEncoder(position_error=error)
    header, payload = encoder.encode(0, frame)
    return CompactDecoder().decode(header, payload, max_particles=10**8)["positions"]


def truth_change(frame: Frame, radius: float, camera: dict[str, Any],
                 fractions: tuple[float, ...], size: tuple[int, int] = (256, 160),
                 ) -> list[tuple[float, float]]:  # fmt: skip
    """(mean°, p99°) per bound (fractions of `radius`): the bench's reference surface
    (splashsurf, server/bench/mesh_reference.py) reconstructed from the decoded positions against
    the one from the float32 input, rasterised with `camera`, over the pixels both cover."""
    from concurrent.futures import ThreadPoolExecutor

    from sphrender.server.bench.mesh_reference import rasterise, reconstruct
    from sphrender.server.engine.geometry.camera import Camera
    from sphrender.server.engine.gpu.gl_context import GLContext
    from sphrender.server.engine.gpu.programs import ProgramCache
    from sphrender.server.scene import scene_from_dict

    image = {"width": size[0], "height": size[1]}
    scene = scene_from_dict({"image": image, "camera": camera, "particles": {"radius": radius}})
    view = Camera.from_config(scene.camera, *size)
    sent = frame["positions"].astype(np.float32).astype(np.float64)
    meshes = [reconstruct(sent, radius)]
    meshes += [reconstruct(decoded_positions(frame, f * radius), radius) for f in fractions]

    def draw() -> list:
        with GLContext() as gl:
            programs = ProgramCache(gl)
            try:
                return [rasterise(gl, programs, mesh, view) for mesh in meshes]
            finally:
                programs.release()

    with ThreadPoolExecutor(1) as pool:  # a thread of its own: the caller may hold a context
        reference, *decoded = pool.submit(draw).result()
    out = []
    for truth in decoded:
        both = reference.hit & truth.hit
        cosine = np.clip(np.einsum("ij,ij->i", reference.normals[both], truth.normals[both]), -1, 1)
        angles = np.degrees(np.arccos(cosine))
        out.append((float(angles.mean()), float(np.percentile(angles, 99))))
    return out


def image_change(frames: list[Frame], radius: float, camera: dict[str, Any],
                 fractions: tuple[float, ...], size: tuple[int, int] = (256, 160),
                 ) -> list[tuple[float, float, float, float, float]]:  # fmt: skip
    """(fraction, normal change mean°, p99°, coverage change mean, pixels whose coverage
    changed by > 1/255) of the decoded frame against the float32 input, rendered (balanced).
    Renders on a thread of its own: the caller's thread may own a GL context already (a full
    `sphrender bench` run holds one), and a thread owns at most one."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(1) as pool:
        return pool.submit(_image_change, frames, radius, camera, fractions, size).result()


def _image_change(frames: list[Frame], radius: float, camera: dict[str, Any],
                  fractions: tuple[float, ...], size: tuple[int, int],
                  ) -> list[tuple[float, float, float, float, float]]:  # fmt: skip
    from sphrender.server.bench.surface_quality import flicker_deg
    from sphrender.server.engine.gpu.gl_context import GLContext
    from sphrender.server.engine.renderer import SurfaceRenderer
    from sphrender.server.scene import scene_from_dict

    frame = frames[len(frames) // 2]
    scene = scene_from_dict({
        "image": {"width": size[0], "height": size[1]},
        "camera": camera, "particles": {"radius": radius}, "quality": {"preset": "balanced"},
    })  # fmt: skip
    out = []
    with GLContext() as gl:
        renderer = SurfaceRenderer(gl)

        def render(positions: np.ndarray, order: Any = slice(None)) -> Any:
            """`positions` with the frame's other arrays in the same (sent) `order`: only the
            positions' quantisation differs from the reference."""
            particles = make_frame(positions, densities=frame["densities"][order],
                                   temperatures=frame["temperatures"][order])  # fmt: skip
            return renderer.render(particles, scene, depth=True, normals=True)[0]

        reference = render(frame["positions"].astype(np.float32).astype(np.float64))
        for fraction in fractions:
            encoder = CompactEncoder(position_error=fraction * radius)
            header, payload = encoder.encode(0, frame)
            decoded = CompactDecoder().decode(header, payload, max_particles=10**8)
            order = encoder.order if encoder.order is not None else slice(None)
            image = render(decoded["positions"], order)
            mean, p99 = flicker_deg(reference, image)
            alpha = np.abs(image.rgba[..., 3] - reference.rgba[..., 3])
            out.append((fraction, mean, p99, float(alpha.mean()), float((alpha > 1 / 255).mean())))
        renderer.release()
    return out
