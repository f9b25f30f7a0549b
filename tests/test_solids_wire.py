"""The `solid` array over every transport that carries arrays (stream FRAME, HTTP .npz through
the client) to a real `sphrender serve`: the image equals the in-process render bit for bit, and
bad flags are refused with the array's name."""

from __future__ import annotations

import json

import numpy as np
from service_harness import SMALL_SCENE, ServerProcess

from sphrender.client.api import Client, decode_raw
from sphrender.core.frame import make_frame
from sphrender.core.protocol import MessageType, encode_npz_frame
from sphrender.server.bench.solid_scenes import plate_scene
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

PLATE = plate_scene(radius=0.05, counts=(12, 2, 12))
SCENE = {
    **SMALL_SCENE,
    "camera": {"eye": [1.2, 1.0, 1.6], "target": [0.0, 0.0, 0.0]},
    "particles": {"radius": 0.05},
    "output": {"format": "raw", "raw_type": "float32"},
}


def _flags() -> np.ndarray:
    flags = np.ones(len(PLATE.positions), np.uint8)
    flags[::7] = 0  # some fluid among them: both paths and the compose run
    return flags


def test_solid_flags_over_stream_and_http(
    service: ServerProcess, renderer: SurfaceRenderer
) -> None:
    positions, flags = PLATE.positions, _flags()
    expected, _ = renderer.render(make_frame(positions, solid=flags), scene_from_dict(SCENE))
    plain, _ = renderer.render(make_frame(positions), scene_from_dict(SCENE))
    assert expected.rgba.tobytes() != plain.rgba.tobytes()  # the flags change the image
    with service.stream() as client:
        client.hello(SCENE)
        client.frame(1, positions, solid=flags)
        client.frame(2, positions, solid=flags.astype(np.bool_))
        for _ in range(2):
            kind, header, payload = client.receive()
            assert kind == MessageType.IMAGE, header
            assert (
                decode_raw(header["arrays"], payload)["rgba"].tobytes() == expected.rgba.tobytes()
            )
    http = Client(f"http://127.0.0.1:{service.http_port}")
    for sent in (flags, flags.astype(np.bool_)):  # an .npz entry of dtype |u1 or |b1
        decoded = http.render_raw(positions, SCENE, solid=sent)
        assert decoded["rgba"].tobytes() == expected.rgba.tobytes()


def test_bad_solid_flags_are_refused_by_name(service: ServerProcess) -> None:
    positions = PLATE.positions[:10]
    flags = np.zeros(10, np.uint8)
    flags[3] = 2
    body = encode_npz_frame(positions, solid=flags, scene=SCENE)
    status, _headers, data = service.request("POST", "/v1/render", body)
    error = json.loads(data)
    assert (status, error["field"], error["code"]) == (400, "solid[3]", "bad_input")
    assert "must be 0 or 1, got 2" in error["error"]
    floats = encode_npz_frame(positions, solid=np.ones(10, np.float32), scene=SCENE)
    status, _headers, data = service.request("POST", "/v1/render", floats)
    assert status == 400 and json.loads(data)["field"] == "solid"
