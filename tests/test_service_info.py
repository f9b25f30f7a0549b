"""`GET /v1/info` and WELCOME tell the truth: every image format listed renders, and the OpenCL
device named is the one the render process made its context on (the same choice as here)."""

from __future__ import annotations

from service_harness import SMALL_SCENE, ServerProcess, ball

from sphrender.client.api import Client
from sphrender.core.npz_body import encode_npz_frame
from sphrender.core.protocol import ARRAY_NAMES, IMAGE_FORMATS
from sphrender.server.engine.gpu.cl_context import CLContext

CONTENT_TYPES = {
    "png": "image/png",
    "exr": "image/x-exr",
    "jpeg": "image/jpeg",
    "raw": "application/octet-stream",
}


def test_info_lists_every_working_format_and_the_opencl_device(
    service: ServerProcess, cl_context: CLContext
) -> None:
    status, info = service.json("GET", "/v1/info")
    assert status == 200
    assert info["formats"] == list(IMAGE_FORMATS) == list(CONTENT_TYPES)
    assert info["raw_types"] == ["rgba8", "float16", "float32"]
    assert info["frame_arrays"] == list(ARRAY_NAMES)
    client = Client(f"http://127.0.0.1:{service.http_port}")
    body = encode_npz_frame(ball(300), scene=SMALL_SCENE)
    for name in info["formats"]:
        headers, data = client.request(
            "POST", f"/v1/render?format={name}", body, "application/x-npz"
        )
        assert headers["content-type"] == CONTENT_TYPES[name] and data, name
    device = cl_context.device_info
    assert info["opencl"] == {
        "platform": device.platform_name,
        "device": device.device_name,
        "type": device.device_type,
    }
    with client.stream(SMALL_SCENE) as session:
        server = session.welcome["server"]
    assert server["opencl"] == info["opencl"] and server["formats"] == info["formats"]
    assert server["frame_arrays"] == info["frame_arrays"]
    assert server["raw_types"] == info["raw_types"]
