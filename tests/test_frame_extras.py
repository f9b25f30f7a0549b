"""Velocities and ids: validated on every input path, carried on `ParticleFrame`, ignored by the
renderer while the camera's shutter is closed (an image with them equals the image without),
counted by the memory estimate; a frame's scene may open the shutter (motion blur)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from service_harness import SMALL_SCENE, ServerProcess, ball

from sphrender.client.api import Client, ServerError
from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.core.npz_body import decode_npz_frame, encode_npz_frame
from sphrender.core.protocol import decode_frame_arrays, parse_header, plan_frame_arrays
from sphrender.core.readers import read_particles
from sphrender.server.service.admission import PARTICLE_BYTES, frame_estimate

POSITIONS = np.zeros((4, 3))


@pytest.mark.parametrize(
    ("arrays", "field", "words"),
    [
        ({"ids": [1, 2, 1, 0]}, "ids[2]", "must be unique: id 1 also appears at ids[0]"),
        ({"ids": [0, 10**9, 5, 10**9]}, "ids[3]", "must be unique"),  # sparse ids: sorted check
        ({"ids": [1, -2, 3, 0]}, "ids[1]", "must be >= 0, got -2"),
        ({"ids": [0.0, 1.0, 2.0, 3.0]}, "ids", "must be an integer array"),
        ({"ids": [[0], [1], [2], [3]]}, "ids", "must have shape (N,)"),
        ({"ids": [0, 1, 2]}, "ids", "has 3 entries but positions has 4"),
        ({"ids": np.array([0, 1, 2**63, 3], np.uint64)}, "ids[2]", "at most 2**63 - 1"),
        ({"velocities": np.ones((4, 2))}, "velocities", "must have shape (N, 3)"),
        ({"velocities": np.ones((3, 3))}, "velocities", "has 3 rows but positions has 4"),
        ({"velocities": [[0, 0, 0]] * 3 + [[0, np.nan, 0]]}, "velocities[3]", "must be finite"),
        ({"velocities": [[1e300, 0, 0]] * 4}, "velocities[0]", "beyond float32's range"),
        ({"velocities": np.array(["a"] * 12).reshape(4, 3)}, "velocities", "numeric array"),
    ],
)
def test_make_frame_refuses_bad_velocities_and_ids(
    arrays: dict[str, object], field: str, words: str
) -> None:
    with pytest.raises(InputError) as caught:
        make_frame(POSITIONS, **arrays)  # type: ignore[arg-type]
    assert caught.value.field == field
    assert words in caught.value.message


def test_make_frame_carries_velocities_and_ids() -> None:
    frame = make_frame(POSITIONS, velocities=np.ones((4, 3)), ids=np.array([7, 3, 0, 1], np.uint8))
    assert frame.velocities is not None and frame.velocities.dtype == np.float32
    assert frame.ids is not None and frame.ids.dtype == np.int64
    assert frame.ids.tolist() == [7, 3, 0, 1]
    empty = make_frame(np.zeros((0, 3)), velocities=np.zeros((0, 3)), ids=np.zeros(0, np.int32))
    assert empty.ids is not None and empty.ids.shape == (0,)


def test_frame_header_dtypes_and_shapes() -> None:
    def plan(name: str, dtype: str, shape: list[int]) -> None:
        specs = [
            {"name": "positions", "dtype": "<f4", "shape": [2, 3]},
            {"name": name, "dtype": dtype, "shape": shape},
        ]
        nbytes = 24 + int(np.prod(shape)) * int(dtype[-1])
        plan_frame_arrays(specs, nbytes, max_particles=10)

    plan("velocities", "<f4", [2, 3])
    plan("ids", "<u4", [2])
    plan("ids", "<i8", [2])
    with pytest.raises(InputError, match="must be one of the strings <i4, <u4, <i8, <u8 for ids"):
        plan("ids", "<f4", [2])
    with pytest.raises(InputError, match="must be one of the strings <f4, <f8 for velocities"):
        plan("velocities", "<i4", [2, 3])
    with pytest.raises(InputError, match=r"must be \[N, 3\]"):
        plan("velocities", "<f4", [2])


def test_encode_frame_and_npz_round_trip() -> None:
    from sphrender.core.protocol import PREFIX_SIZE, encode_frame, parse_prefix

    positions = ball(50)
    velocities = np.random.default_rng(1).normal(size=(50, 3))
    ids = np.arange(50, dtype=np.int32)[::-1]
    message = encode_frame(1, positions, velocities=velocities, ids=ids)
    _kind, header_len, _payload_len = parse_prefix(
        message[:PREFIX_SIZE], max_header_bytes=1 << 16, max_payload_bytes=1 << 20
    )
    header = parse_header(message[PREFIX_SIZE : PREFIX_SIZE + header_len])
    assert [a["dtype"] for a in header["arrays"]] == ["<f8", "<f4", "<i4"]
    arrays = decode_frame_arrays(
        header["arrays"], message[PREFIX_SIZE + header_len :], max_particles=100
    )
    assert np.array_equal(arrays["ids"], ids)
    assert np.allclose(arrays["velocities"], velocities, atol=1e-6)

    seen: list[tuple[str, ...]] = []
    body = encode_npz_frame(positions, velocities=velocities, ids=ids)
    npz = decode_npz_frame(
        body,
        max_particles=100,
        max_uncompressed_bytes=1 << 20,
        admit=lambda _scene, _n, names: seen.append(names),
    )
    assert seen == [("positions", "velocities", "ids")]
    assert np.array_equal(npz.arrays["ids"], ids)


def test_memory_estimate_counts_velocities_and_ids() -> None:
    plain = frame_estimate(1000, 100, 10)
    assert plain == 1000 + 100 * PARTICLE_BYTES + 10 * 120
    assert frame_estimate(1000, 100, 10, ["positions", "velocities", "ids"]) == plain + 100 * 32


def test_readers_take_velocities_and_ids(tmp_path: Path, dambreak: Path) -> None:
    simulated = read_particles(dambreak / "bgeo" / "ParticleData_Fluid_5.bgeo")
    assert simulated.ids is not None and simulated.velocities is not None  # partio's id and v
    assert simulated.velocities.shape == (simulated.count, 3)

    positions = ball(20)
    velocities = np.arange(60, dtype=np.float64).reshape(20, 3)
    ids = np.arange(20)[::-1]
    np.savez(tmp_path / "frame.npz", positions=positions, velocities=velocities, ids=ids)
    frame = read_particles(tmp_path / "frame.npz")
    assert frame.ids is not None and frame.ids.tolist() == ids.tolist()
    assert frame.velocities is not None and np.array_equal(frame.velocities, velocities)

    rows = ["x,y,z,vx,vy,vz,id"] + [
        ",".join(map(str, [*p, *v, i])) for p, v, i in zip(positions, velocities, ids, strict=True)
    ]
    (tmp_path / "frame.csv").write_text("\n".join(rows) + "\n")
    frame = read_particles(tmp_path / "frame.csv")
    assert frame.ids is not None and frame.ids.tolist() == ids.tolist()
    assert frame.velocities is not None and np.array_equal(frame.velocities, velocities)

    import meshio

    cells = [("vertex", np.arange(20).reshape(-1, 1))]
    split = {f"v{a}": velocities[:, i].astype(np.float32) for i, a in enumerate("xyz")}
    meshio.write(tmp_path / "frame.ply", meshio.Mesh(positions, cells, point_data=split))
    frame = read_particles(tmp_path / "frame.ply")
    assert frame.velocities is not None and np.array_equal(frame.velocities, velocities)
    vectors = {"velocity": velocities, "id": ids.astype(np.int32)}
    meshio.write(tmp_path / "frame.vtu", meshio.Mesh(positions, cells, point_data=vectors))
    frame = read_particles(tmp_path / "frame.vtu")
    assert frame.ids is not None and frame.ids.tolist() == ids.tolist()
    assert frame.velocities is not None and np.array_equal(frame.velocities, velocities)

    (tmp_path / "half.csv").write_text("x,y,z,id\n0,0,0,1.5\n")
    with pytest.raises(InputError, match="must be an integer array"):
        read_particles(tmp_path / "half.csv")


def test_velocities_and_ids_over_http_and_stream(service: ServerProcess) -> None:
    positions = ball(600, seed=4)
    velocities = np.random.default_rng(2).normal(size=(600, 3)).astype(np.float32)
    ids = np.random.default_rng(3).permutation(600)
    client = Client(f"http://127.0.0.1:{service.http_port}")
    plain = client.render(positions, SMALL_SCENE, format="raw")
    carried = client.render(positions, SMALL_SCENE, velocities=velocities, ids=ids, format="raw")
    assert carried == plain  # the renderer ignores them

    twice = ids.copy()
    twice[5] = twice[9]
    with pytest.raises(ServerError) as caught:
        client.render(positions, SMALL_SCENE, ids=twice)
    assert caught.value.field == "ids[9]" and caught.value.status == 400
    assert "must be unique" in str(caught.value)

    # Raw frames, to compare bytes with the HTTP render (tests/test_service_compact.py carries
    # velocities and ids in compact frames).
    with client.stream(SMALL_SCENE, compact=False) as session:
        session.send(positions, velocities=velocities, ids=ids, scene={"output": {"format": "raw"}})
        session.send(positions, velocities=velocities[:, :2].copy())
        session.send(positions, ids=twice)
        image, bad_shape, bad_ids = session.receive(), session.receive(), session.receive()
    assert image.kind == "image" and image.data == plain
    assert bad_shape.kind == "error" and bad_shape.header["field"] == "arrays[1].shape"
    assert "[N, 3]" in bad_shape.header["error"]
    assert bad_ids.kind == "error" and bad_ids.header["field"] == "ids[9]"


def test_a_frame_opens_the_shutter_over_stream_and_http(service: ServerProcess) -> None:
    """The shutter is a camera key, so a frame's partial scene sets it like any other; the
    service's blurred image equals the in-process renderer's (HTTP and stream alike)."""
    positions = ball(600, seed=4)
    velocities = np.random.default_rng(2).normal(size=(600, 3)).astype(np.float32)
    client = Client(f"http://127.0.0.1:{service.http_port}")
    raw = {"output": {"format": "raw"}}
    with client.stream(SMALL_SCENE, compact=False) as session:
        session.send(positions, velocities=velocities, scene=raw)
        session.send(positions, velocities=velocities, scene={**raw, "camera": {"shutter": 0.1}})
        still, blurred = session.receive(), session.receive()
    assert still.kind == "image" and blurred.kind == "image"
    assert blurred.data != still.data
    open_scene = {**SMALL_SCENE, "camera": {**SMALL_SCENE["camera"], "shutter": 0.1}}
    over_http = client.render(positions, open_scene, velocities=velocities, format="raw")
    assert over_http == blurred.data
