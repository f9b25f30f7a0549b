"""Tests for sphrender.core.readers: round trips, the real SPlisHSPlasH data, and bad input."""

from __future__ import annotations

import gzip
import hashlib
import json
import pickle
import struct
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import meshio
import numpy as np
import numpy.typing as npt
import pytest

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame
from sphrender.core.readers import (
    SUPPORTED_SUFFIXES,
    natural_sort_key,
    read_npz_scene_json,
    read_particles,
)

#: Real SPlisHSPlasH frames vendored with the tests (a slab of each frame, tests/data/README.md);
#: their particle counts and checksums are in the manifest.
DATA = Path(__file__).resolve().parent / "data" / "dambreak-splishsplash"
MANIFEST: dict[str, dict[str, Any]] = json.loads((DATA / "manifest.json").read_text())
VTK_FILES = sorted((DATA / "vtk").glob("*.vtk"), key=natural_sort_key)
BGEO_FRAMES = (5, 11)

# Documented in the source data's README.md and scene.json.
PARTICLE_RADIUS = 0.015
EXTENT_LOW = np.array([-2.0, 0.0, -0.75]) - PARTICLE_RADIUS
EXTENT_HIGH = np.array([2.0, 3.0, 0.75]) + PARTICLE_RADIUS
REST_DENSITY = 1000.0

FLOAT_TYPES = [np.float32, np.float64]


def random_particles(
    n: int, dtype: type[np.floating], seed: int = 0
) -> dict[str, npt.NDArray[np.floating]]:
    rng = np.random.default_rng(seed)
    return {
        "positions": rng.uniform(-2.0, 2.0, size=(n, 3)).astype(dtype),
        "densities": rng.uniform(900.0, 1100.0, size=n).astype(dtype),
        "radii": rng.uniform(0.01, 0.02, size=n).astype(dtype),
        "temperatures": rng.uniform(300.0, 1800.0, size=n).astype(dtype),
    }


def assert_native(frame: ParticleFrame) -> None:
    for array in (frame.positions, frame.densities, frame.radii, frame.temperatures):
        if array is not None:
            assert array.dtype.byteorder in "=|<", array.dtype
            assert array.flags.c_contiguous


def assert_matches(frame: ParticleFrame, expected: dict[str, npt.NDArray[np.floating]]) -> None:
    """Exact up to the frame's storage types (positions float64, attributes float32)."""
    assert_native(frame)
    np.testing.assert_array_equal(frame.positions, expected["positions"].astype(np.float64))
    for name in ("densities", "radii", "temperatures"):
        got = getattr(frame, name)
        if name in expected:
            assert got is not None, name
            np.testing.assert_array_equal(got, expected[name].astype(np.float32))
        else:
            assert got is None, name


def save_npz(path: Path, **arrays: Any) -> None:
    """np.savez with a keyword dict (its stubs reserve a bool keyword, which trips mypy)."""
    np.savez(path, **arrays)


def read_error(path: Path, **kwargs: Any) -> InputError:
    with pytest.raises(InputError) as info:
        read_particles(path, **kwargs)
    return info.value


# ----------------------------------------------------------------------------------------------
# A minimal BGEO writer following partio's writeBGEO (big-endian, version 5), for synthetic files.

BgeoAttr = tuple[str, int, npt.NDArray[np.generic], Sequence[str]]  # name, houdini type, values


def bgeo_bytes(
    positions: npt.NDArray[np.floating],
    attributes: Sequence[BgeoAttr] = (),
    *,
    version: int = 5,
    magic: bytes = b"Bgeo",
) -> bytes:
    n = positions.shape[0]
    out = bytearray(magic + b"V" + struct.pack(">i", version))
    out += struct.pack(">8i", n, 0, 0, 0, len(attributes), 0, 0, 0)
    columns: list[npt.NDArray[np.generic]] = [
        positions.astype(">f4"),
        np.ones((n, 1), dtype=">f4"),  # homogeneous w
    ]
    for name, kind, values, strings in attributes:
        size = 1 if values.ndim == 1 else values.shape[1]
        out += struct.pack(">H", len(name)) + name.encode()
        out += struct.pack(">Hi", size, kind)
        if kind == 4:
            out += struct.pack(">i", len(strings))
            for text in strings:
                out += struct.pack(">H", len(text)) + text.encode()
        else:
            out += b"\0" * (4 * size)
        columns.append(values.reshape(n, size).astype(">i4" if kind in (1, 4) else ">f4"))
    records = np.empty((n, 4 * sum(c.shape[1] for c in columns)), dtype=np.uint8)
    offset = 0
    for column in columns:
        width = 4 * column.shape[1]
        records[:, offset : offset + width] = np.ascontiguousarray(column).view(np.uint8)
        offset += width
    out += records.tobytes()
    out += b"\x00\xff"  # no primitives and no detail attributes; then partio's "extra" bytes
    return bytes(out)


# ----------------------------------------------------------------------------------------------
# Round trips


@pytest.mark.parametrize("dtype", FLOAT_TYPES)
def test_npz_round_trip(tmp_path: Path, dtype: type[np.floating]) -> None:
    arrays = random_particles(257, dtype)
    path = tmp_path / "frame.npz"
    save_npz(path, **arrays, velocity=np.zeros((257, 3)))  # unknown entries are ignored
    assert_matches(read_particles(path), arrays)


def test_npz_positions_only_and_compressed_and_upper_case(tmp_path: Path) -> None:
    arrays = random_particles(10, np.float64)
    path = tmp_path / "FRAME.NPZ"
    with path.open("wb") as handle:  # np.savez would append ".npz" to an upper-case name
        np.savez_compressed(handle, positions=arrays["positions"])
    assert_matches(read_particles(path), {"positions": arrays["positions"]})


def test_npz_big_endian_arrays_come_back_native(tmp_path: Path) -> None:
    arrays = random_particles(50, np.float64)
    big = {name: value.astype(value.dtype.newbyteorder(">")) for name, value in arrays.items()}
    path = tmp_path / "big.npz"
    save_npz(path, **big)
    assert_matches(read_particles(path), arrays)


def test_npz_scene_entry(tmp_path: Path) -> None:
    arrays = random_particles(5, np.float32)
    scene = '{"camera": {"fov_y": 40}, "name": "Düsseldorf"}'
    with_scene = tmp_path / "with_scene.npz"
    save_npz(with_scene, **arrays, scene=np.array(scene))
    assert_matches(read_particles(with_scene), arrays)
    assert read_npz_scene_json(with_scene) == scene

    as_bytes = tmp_path / "bytes_scene.npz"
    save_npz(as_bytes, **arrays, scene=np.array(scene.encode("utf-8")))
    assert read_npz_scene_json(as_bytes) == scene

    without = tmp_path / "without.npz"
    save_npz(without, **arrays)
    assert read_npz_scene_json(without) is None


@pytest.mark.parametrize("dtype", FLOAT_TYPES)
def test_npy_round_trip(tmp_path: Path, dtype: type[np.floating]) -> None:
    positions = random_particles(100, dtype)["positions"]
    path = tmp_path / "positions.npy"
    np.save(path, positions)
    assert_matches(read_particles(path), {"positions": positions})


@pytest.mark.parametrize("dtype", FLOAT_TYPES)
def test_csv_round_trip(tmp_path: Path, dtype: type[np.floating]) -> None:
    arrays = random_particles(64, dtype)
    # Columns in an unusual order plus an unknown column, written with round-trip precision.
    columns = {
        "temperature": arrays["temperatures"],
        "z": arrays["positions"][:, 2],
        "id": np.arange(64),
        "x": arrays["positions"][:, 0],
        "density": arrays["densities"],
        "y": arrays["positions"][:, 1],
        "radius": arrays["radii"],
    }
    lines = [", ".join(columns)]  # spaces after commas are tolerated in the header
    for row in range(64):
        lines.append(",".join(repr(float(values[row])) for values in columns.values()))
    path = tmp_path / "frame.csv"
    path.write_text("\n".join(lines) + "\n")
    assert_matches(read_particles(path), arrays)


def test_csv_header_only_is_an_empty_frame(tmp_path: Path) -> None:
    path = tmp_path / "empty.csv"
    path.write_text("x,y,z,density\n")
    frame = read_particles(path)
    assert frame.count == 0
    assert frame.positions.shape == (0, 3)
    assert frame.densities is not None and frame.densities.shape == (0,)


def vertex_mesh(arrays: dict[str, npt.NDArray[np.floating]], **names: str) -> meshio.Mesh:
    n = arrays["positions"].shape[0]
    point_data = {names.get(key, key): arrays[key] for key in arrays if key != "positions"}
    return meshio.Mesh(
        arrays["positions"], [("vertex", np.arange(n).reshape(-1, 1))], point_data=point_data
    )


@pytest.mark.parametrize("suffix", [".ply", ".vtu", ".vtk"])
@pytest.mark.parametrize("dtype", FLOAT_TYPES)
def test_meshio_round_trip(tmp_path: Path, suffix: str, dtype: type[np.floating]) -> None:
    arrays = random_particles(300, dtype)
    mesh = vertex_mesh(arrays, densities="density", radii="radius", temperatures="temperature")
    path = tmp_path / f"frame{suffix}"
    meshio.write(path, mesh, binary=True)
    assert_matches(read_particles(path), arrays)


def test_meshio_plural_and_rho_aliases(tmp_path: Path) -> None:
    arrays = random_particles(20, np.float32)
    path = tmp_path / "aliases.vtu"
    meshio.write(path, vertex_mesh(arrays, densities="rho"))  # radii, temperatures stay plural
    assert_matches(read_particles(path), arrays)


def test_ply_with_2d_points_is_padded_with_z_zero(tmp_path: Path) -> None:
    path = tmp_path / "flat.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float density\nend_header\n0 1 1000\n2 3 1001\n4.5 5 999\n"
    )
    frame = read_particles(path)
    np.testing.assert_array_equal(frame.positions, [[0, 1, 0], [2, 3, 0], [4.5, 5, 0]])
    assert frame.densities is not None
    np.testing.assert_array_equal(frame.densities, [1000, 1001, 999])


def test_attribute_map_renames_in_every_format(tmp_path: Path) -> None:
    arrays = random_particles(40, np.float32)
    rho0 = arrays["densities"]
    expected = {"positions": arrays["positions"], "densities": rho0}

    vtu = tmp_path / "m.vtu"
    meshio.write(
        vtu, vertex_mesh({"positions": arrays["positions"], "densities": rho0}, densities="rho0")
    )
    npz = tmp_path / "m.npz"
    np.savez(npz, positions=arrays["positions"], rho0=rho0)
    csv = tmp_path / "m.csv"
    rows = np.column_stack([arrays["positions"], rho0]).astype(np.float64)
    csv.write_text("x,y,z,rho0\n" + "\n".join(",".join(map(repr, r.tolist())) for r in rows))
    bgeo = tmp_path / "m.bgeo"
    bgeo.write_bytes(bgeo_bytes(arrays["positions"], [("rho0", 0, rho0, ())]))

    for path in (vtu, npz, csv, bgeo):
        for key in ("density", "densities"):
            assert_matches(read_particles(path, attribute_map={key: "rho0"}), expected)
        # Without the map the attribute is not recognised.
        assert read_particles(path).densities is None


# ----------------------------------------------------------------------------------------------
# BGEO (synthetic files)


def test_bgeo_synthetic_with_all_attribute_types(tmp_path: Path) -> None:
    arrays = random_particles(33, np.float32, seed=3)
    n = 33
    attributes: list[BgeoAttr] = [
        ("id", 1, np.arange(n, dtype=np.int32), ()),
        ("name", 4, np.zeros(n, dtype=np.int32), ("fluid", "wall")),
        ("velocity", 5, np.ones((n, 3), dtype=np.float32), ()),
        ("density", 0, arrays["densities"], ()),
        ("radius", 0, arrays["radii"], ()),
        ("temperature", 0, arrays["temperatures"], ()),
    ]
    path = tmp_path / "synthetic.bgeo.gz"
    path.write_bytes(gzip.compress(bgeo_bytes(arrays["positions"], attributes)))
    assert_matches(read_particles(path), arrays)
    # The indexed-string attribute is not offered as a number.
    assert read_error(path, attribute_map={"temperature": "name"}).field == (
        "attribute_map.temperature"
    )


def test_bgeo_zero_points(tmp_path: Path) -> None:
    path = tmp_path / "empty.bgeo"
    path.write_bytes(bgeo_bytes(np.zeros((0, 3)), [("density", 0, np.zeros(0), ())]))
    frame = read_particles(path)
    assert frame.count == 0 and frame.positions.shape == (0, 3)


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"magic": b"Bgex"}, "not a BGEO"),
        ({"magic": b"\x7fNSJ"}, "new (Houdini 12+)"),
        ({"version": 4}, "unsupported BGEO version"),
    ],
)
def test_bgeo_bad_header(tmp_path: Path, kwargs: dict[str, object], words: str) -> None:
    path = tmp_path / "bad.bgeo"
    path.write_bytes(bgeo_bytes(np.zeros((2, 3)), **kwargs))  # type: ignore[arg-type]
    error = read_error(path)
    assert error.field == "file"
    assert words in error.message and str(path) in error.message


def test_bgeo_unsupported_attribute_type(tmp_path: Path) -> None:
    path = tmp_path / "string.bgeo"
    path.write_bytes(bgeo_bytes(np.zeros((2, 3)), [("label", 2, np.zeros(2), ())]))
    error = read_error(path)
    assert error.field == "file" and "type 2" in error.message


def test_bgeo_particle_limit_is_checked_before_reading_points(tmp_path: Path) -> None:
    path = tmp_path / "many.bgeo"
    path.write_bytes(bgeo_bytes(np.zeros((10, 3)))[:100])  # truncated, but the limit comes first
    assert read_error(path, max_particles=5).field == "positions"


# ----------------------------------------------------------------------------------------------
# Real data (SPlisHSPlasH dam break)


def test_vendored_files_match_the_manifest() -> None:
    """Every vendored file is there, unchanged (SHA-256), and nothing else is."""
    found = sorted(
        str(p.relative_to(DATA)) for p in DATA.glob("*/*") if p.suffix in (".vtk", ".bgeo")
    )
    assert found == sorted(MANIFEST)
    for name, entry in MANIFEST.items():
        assert hashlib.sha256((DATA / name).read_bytes()).hexdigest() == entry["sha256"], name
    assert len(VTK_FILES) >= 2, f"expected VTK frames in {DATA / 'vtk'}"
    frames = [int(p.stem.rsplit("_", 1)[1]) for p in VTK_FILES]
    assert frames == sorted(frames)  # natural order: 1, 5, 11


@pytest.mark.parametrize("path", VTK_FILES, ids=lambda p: p.name)
def test_real_vtk_frame(path: Path) -> None:
    frame = read_particles(path)
    assert frame.count == MANIFEST[f"vtk/{path.name}"]["particles"]
    assert_native(frame)
    assert np.isfinite(frame.positions).all()
    assert (frame.positions >= EXTENT_LOW).all() and (frame.positions <= EXTENT_HIGH).all()
    assert frame.densities is not None
    assert frame.radii is None and frame.temperatures is None
    median = float(np.median(frame.densities))
    assert abs(median - REST_DENSITY) < 0.05 * REST_DENSITY, median
    # An isolated (splash) particle only sees itself: m W(0) with SPlisHSPlasH's cubic kernel
    # (support h = 4r, W(0) = 8 / (pi h^3)) and particle volume (2r)^3 gives rest density / pi.
    # Nothing can be lighter than that; DFSPH keeps compression to a few percent.
    assert frame.densities.min() >= REST_DENSITY / np.pi * (1 - 1e-5)
    assert frame.densities.max() <= 1.25 * REST_DENSITY


def test_real_vtk_is_big_endian_in_meshio_but_native_from_reader() -> None:
    raw = meshio.read(VTK_FILES[0])
    assert raw.points.dtype.byteorder == ">"  # what the README warns about
    frame = read_particles(VTK_FILES[0])
    assert_native(frame)
    np.testing.assert_array_equal(frame.positions, raw.points.astype(np.float64))
    assert frame.densities is not None
    np.testing.assert_array_equal(frame.densities, raw.point_data["density"])


@pytest.mark.parametrize("frame_number", BGEO_FRAMES)
def test_real_bgeo_equals_vtk(frame_number: int) -> None:
    vtk = read_particles(DATA / "vtk" / f"ParticleData_Fluid_{frame_number}.vtk")
    bgeo_path = DATA / "bgeo" / f"ParticleData_Fluid_{frame_number}.bgeo"
    assert bgeo_path.read_bytes()[:2] == b"\x1f\x8b"  # the shipped files are gzip-compressed
    bgeo = read_particles(bgeo_path)
    assert_native(bgeo)
    assert bgeo.count == vtk.count == MANIFEST[f"bgeo/{bgeo_path.name}"]["particles"]
    np.testing.assert_array_equal(bgeo.positions, vtk.positions)
    assert bgeo.densities is not None and vtk.densities is not None
    np.testing.assert_array_equal(bgeo.densities, vtk.densities)


def test_real_bgeo_plain_and_gzip_and_bgeo_gz_suffix(tmp_path: Path) -> None:
    original = DATA / "bgeo" / f"ParticleData_Fluid_{BGEO_FRAMES[0]}.bgeo"
    raw = gzip.decompress(original.read_bytes())
    assert raw[:5] == b"BgeoV"
    plain = tmp_path / "plain.bgeo"
    plain.write_bytes(raw)
    named_gz = tmp_path / "named.BGEO.GZ"
    named_gz.write_bytes(original.read_bytes())
    plain_named_gz = tmp_path / "plain_named.bgeo.gz"  # the content decides, not the name
    plain_named_gz.write_bytes(raw)
    reference = read_particles(original)
    for path in (plain, named_gz, plain_named_gz):
        frame = read_particles(path)
        np.testing.assert_array_equal(frame.positions, reference.positions)
        assert frame.densities is not None and reference.densities is not None
        np.testing.assert_array_equal(frame.densities, reference.densities)


def test_real_bgeo_truncated(tmp_path: Path) -> None:
    original = DATA / "bgeo" / f"ParticleData_Fluid_{BGEO_FRAMES[0]}.bgeo"
    compressed = original.read_bytes()
    raw = gzip.decompress(compressed)
    # Cuts in the header, the attribute definitions, the first record and the last record.
    for cut in (3, 20, 60, 120, len(raw) - 3):
        path = tmp_path / f"cut{cut}.bgeo"
        path.write_bytes(raw[:cut])
        error = read_error(path)
        assert error.field == "file" and "truncated" in error.message, error
    gz_cut = tmp_path / "cut.bgeo.gz"
    gz_cut.write_bytes(compressed[: len(compressed) // 2])
    assert read_error(gz_cut).field == "file"


def test_real_attribute_map_missing_attribute() -> None:
    error = read_error(VTK_FILES[0], attribute_map={"temperature": "T"})
    assert error.field == "attribute_map.temperature"
    assert "'T'" in error.message and "density" in error.message  # lists what is there
    bgeo = DATA / "bgeo" / f"ParticleData_Fluid_{BGEO_FRAMES[0]}.bgeo"
    assert read_error(bgeo, attribute_map={"radius": "pscale"}).field == "attribute_map.radius"


# ----------------------------------------------------------------------------------------------
# Bad input


class _CreatesFileWhenUnpickled:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Callable[..., object], tuple[object, ...]]:
        return (Path.touch, (self.marker,))


@pytest.mark.parametrize("entry", ["positions", "densities"])
def test_npz_object_array_is_rejected_without_unpickling(tmp_path: Path, entry: str) -> None:
    marker = tmp_path / "unpickled"
    payload = np.empty(3, dtype=object)
    payload[:] = [_CreatesFileWhenUnpickled(marker) for _ in range(3)]
    # Sanity check: unpickling this payload really would create the marker.
    pickle.loads(pickle.dumps(payload))
    assert marker.exists()
    marker.unlink()

    arrays: dict[str, object] = {"positions": np.zeros((3, 3)), "densities": np.ones(3)}
    arrays[entry] = payload.reshape(3, 1) if entry == "positions" else payload
    path = tmp_path / "pickled.npz"
    save_npz(path, **arrays)
    error = read_error(path)
    assert error.field == entry
    assert "object" in error.message
    assert not marker.exists()


def test_npy_object_array_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "pickled.npy"
    np.save(path, np.array([[1, 2, 3]], dtype=object))
    assert read_error(path).field == "positions"


@pytest.mark.parametrize("shape", [(4, 2), (12,), (2, 3, 2)])
def test_npy_wrong_shape(tmp_path: Path, shape: tuple[int, ...]) -> None:
    path = tmp_path / "bad.npy"
    np.save(path, np.zeros(shape))
    error = read_error(path)
    assert error.field == "positions" and "(N, 3)" in error.message


def test_nan_position_is_reported_with_index(tmp_path: Path) -> None:
    positions = np.zeros((6, 3))
    positions[3, 1] = np.nan
    npz = tmp_path / "nan.npz"
    np.savez(npz, positions=positions)
    assert read_error(npz).field == "positions[3]"
    csv = tmp_path / "nan.csv"
    csv.write_text("x,y,z\n0,0,0\n1,nan,0\n")
    assert read_error(csv).field == "positions[1]"


def test_bad_attribute_values_are_reported_by_make_frame(tmp_path: Path) -> None:
    path = tmp_path / "bad_radius.npz"
    np.savez(path, positions=np.zeros((4, 3)), radii=np.array([0.1, 0.1, 0.0, 0.1]))
    assert read_error(path).field == "radii[2]"
    short = tmp_path / "short.npz"
    np.savez(short, positions=np.zeros((4, 3)), densities=np.ones(3))
    assert read_error(short).field == "densities"


def test_npz_missing_positions(tmp_path: Path) -> None:
    path = tmp_path / "nopos.npz"
    np.savez(path, densities=np.ones(3))
    assert read_error(path).field == "positions"


@pytest.mark.parametrize("suffix", [".bgeo", ".bgeo.gz", ".vtk", ".vtu", ".ply", ".npz", ".npy"])
def test_garbage_bytes(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"garbage{suffix}"
    path.write_bytes(np.random.default_rng(7).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    error = read_error(path)
    assert error.field == "file"
    assert str(path) in error.message and "\n" not in error.message


@pytest.mark.parametrize("suffix", [".bgeo", ".vtk", ".vtu", ".ply", ".npz", ".npy", ".csv"])
def test_empty_file(tmp_path: Path, suffix: str) -> None:
    path = tmp_path / f"empty{suffix}"
    path.write_bytes(b"")
    assert read_error(path).field == "file"


def test_npy_content_with_npz_suffix_and_vice_versa(tmp_path: Path) -> None:
    npy_inside = tmp_path / "really_npy.npz"
    with npy_inside.open("wb") as handle:
        np.save(handle, np.zeros((2, 3)))
    assert read_error(npy_inside).field == "file"
    npz_inside = tmp_path / "really_npz.npy"
    with npz_inside.open("wb") as handle:
        np.savez(handle, positions=np.zeros((2, 3)))
    assert read_error(npz_inside).field == "file"
    with pytest.raises(InputError) as info:
        read_npz_scene_json(npy_inside)
    assert info.value.field == "file"


def test_corrupt_zip_member(tmp_path: Path) -> None:
    path = tmp_path / "corrupt.npz"
    np.savez_compressed(path, positions=np.random.default_rng(1).random((1000, 3)))
    data = bytearray(path.read_bytes())
    data[200:260] = b"\xff" * 60  # inside the deflated member
    path.write_bytes(bytes(data))
    assert read_error(path).field in {"file", "positions"}


def test_csv_problems(tmp_path: Path) -> None:
    no_z = tmp_path / "no_z.csv"
    no_z.write_text("x,y,density\n1,2,3\n")
    error = read_error(no_z)
    assert error.field == "positions" and "z" in error.message
    words = tmp_path / "words.csv"
    words.write_text("x,y,z\n1,2,three\n")
    assert read_error(words).field == "file"
    ragged = tmp_path / "ragged.csv"
    ragged.write_text("x,y,z\n1,2,3\n4,5\n")
    assert read_error(ragged).field == "file"
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00garbage\x00\x81")
    assert read_error(binary).field in {"file", "positions"}


def test_missing_file_and_directory(tmp_path: Path) -> None:
    missing = tmp_path / "nope.vtk"
    error = read_error(missing)
    assert error.field == "file" and str(missing) in error.message
    directory = tmp_path / "dir.npz"
    directory.mkdir()
    assert read_error(directory).field == "file"


def test_unknown_suffix(tmp_path: Path) -> None:
    path = tmp_path / "frame.xyz"
    path.write_text("1 2 3\n")
    error = read_error(path)
    assert error.field == "file"
    assert "unsupported format '.xyz'" in error.message
    for suffix in SUPPORTED_SUFFIXES:
        assert suffix in error.message


def test_every_supported_suffix_is_dispatched(tmp_path: Path) -> None:
    for suffix in SUPPORTED_SUFFIXES:
        error = read_error(tmp_path / f"absent{suffix.upper()}")
        assert "unsupported" not in error.message and "no such file" in error.message


def test_attribute_map_problems(tmp_path: Path) -> None:
    path = tmp_path / "frame.npz"
    np.savez(path, positions=np.zeros((2, 3)), densities=np.ones(2))
    assert read_error(path, attribute_map={"density": "rho"}).field == "attribute_map.density"
    assert read_error(path, attribute_map={"colour": "c"}).field == "attribute_map"
    assert read_error(path, attribute_map={"radius": 3}).field == "attribute_map.radius"
    clash = {"density": "densities", "densities": "rho"}
    assert read_error(path, attribute_map=clash).field == "attribute_map.densities"
    csv = tmp_path / "frame.csv"
    csv.write_text("x,y,z\n0,0,0\n")
    assert read_error(csv, attribute_map={"radii": "r"}).field == "attribute_map.radius"


def test_max_particles(tmp_path: Path) -> None:
    path = tmp_path / "frame.npz"
    np.savez(path, positions=np.zeros((10, 3)))
    assert read_error(path, max_particles=9).field == "positions"
    assert read_particles(path, max_particles=10).count == 10


def test_scene_entry_problems(tmp_path: Path) -> None:
    path = tmp_path / "scenes.npz"
    np.savez(path, positions=np.zeros((1, 3)), scene=np.array(["{}", "{}"]))
    with pytest.raises(InputError) as info:
        read_npz_scene_json(path)
    assert info.value.field == "scene"
    numeric = tmp_path / "numeric_scene.npz"
    np.savez(numeric, positions=np.zeros((1, 3)), scene=np.array(3.0))
    with pytest.raises(InputError) as info:
        read_npz_scene_json(numeric)
    assert info.value.field == "scene"
    with pytest.raises(InputError) as info:
        read_npz_scene_json(tmp_path / "missing.npz")
    assert info.value.field == "file"


# ----------------------------------------------------------------------------------------------
# Helpers and hygiene


def test_natural_sort_key() -> None:
    names = ["f_10.vtk", "f_2.vtk", "F_1.vtk", "f_1.vtk", "f_2b.vtk", "f_02.vtk", "g_0.vtk"]
    ordered = sorted(names, key=natural_sort_key)
    assert ordered == [
        "F_1.vtk",
        "f_1.vtk",
        "f_02.vtk",
        "f_2.vtk",
        "f_2b.vtk",
        "f_10.vtk",
        "g_0.vtk",
    ]
    paths = [Path("run2/frame_10.bgeo"), Path("run10/frame_1.bgeo"), Path("run2/frame_9.bgeo")]
    assert sorted(paths, key=natural_sort_key) == [paths[2], paths[0], paths[1]]


def test_readers_import_no_gpu_or_server_modules() -> None:
    code = (
        "import sys, sphrender.core.readers\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('moderngl', 'pyopencl', 'meshio')"
        " or m.startswith('sphrender.server')]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
