"""The viewer page, /v1/status, /v1/schema and demo sessions on a real `sphrender serve`, and the
page itself in a real headless Chromium (tests/browser_harness.py).

The server runs with a token, so the page's way in is tested too: ``/?token=`` is traded for a
cookie, and the page's requests carry it.

What the browser test asserts, and why it is exact:
* the live view shows the server's frame: the page hashes the RGBA bytes of its canvas (FNV-1a)
  after drawing the PNG (decoded without colour conversion or premultiplication; the demo's
  background is the environment, so alpha is 255 everywhere and nothing is rounded), and the
  test sends the same FRAME (the page's HELLO scene, the demo's arrays, the page's camera) on
  a raw stream connection and hashes its own decode. The page streams over the WebSocket
  (/v1/stream), and /metrics must show it made no HTTP frame request.
  The renderer is deterministic for a fixed build (see test_service_http.py), so any
  difference is a real one;
* the status the page shows is the server's: each value is compared with GET /v1/status read
  just before and just after the page refreshed; a value that changed in between (the frame
  rate is over a trailing window) is compared in the next round, and every value must have been
  compared by the end;
* the screenshot's canvas region shows a picture: its pixels vary (standard deviation over
  8 levels; a blank or failed canvas is uniform) and differ from the page background.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser_harness import Browser
from service_harness import SMALL_SCENE, ServerProcess, ball, png_pixels

from sphrender.core.protocol import (
    PREFIX_SIZE,
    MessageType,
    encode_message,
    parse_header,
    parse_prefix,
)
from sphrender.server.scene import Scene, scene_to_dict
from sphrender.server.scene.json_schema import scene_json_schema_text

REPO = Path(__file__).resolve().parents[1]
TOKEN = "viewer-test-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
COOKIE = {"Cookie": f"sphrender_token={TOKEN}"}
VIEWER = {**COOKIE, "X-Sphrender-Viewer": "1"}
CONFIG: dict[str, dict[str, Any]] = {"limits": {"max_sessions": 16}}
#: Where the README's screenshot lives; rewritten when SPHRENDER_UPDATE_DOCS=1.
SCREENSHOT = REPO / "docs" / "viewer.jpg"
PAGE_BACKGROUND = (0x16, 0x18, 0x1C)  # --bg in viewer.css
#: A stream client's scene; the environment behind it keeps alpha at 255 (see above).
STREAM_SCENE = {**SMALL_SCENE, "shading": {"background": "environment"}}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    directory = tmp_path_factory.mktemp("viewer")
    with ServerProcess(directory, CONFIG, env={"SPHRENDER_TOKEN": TOKEN}) as process:
        yield process


def fnv1a(data: bytes) -> str:
    """FNV-1a, 32 bits: what viewer.js computes over its canvas's RGBA bytes."""
    value = 0x811C9DC5
    for byte in data:
        value = ((value ^ byte) * 16777619) & 0xFFFFFFFF
    return f"{value:08x}"


def test_fnv1a_matches_the_published_vectors() -> None:
    assert fnv1a(b"") == "811c9dc5" and fnv1a(b"a") == "e40c292c"
    assert fnv1a(b"foobar") == "bf9cf968"


def test_page_and_assets_are_behind_the_token(server: ServerProcess) -> None:
    assert server.request("GET", "/")[0] == 401
    assert server.request("GET", "/?token=wrong-token-wrong-token")[0] == 401
    assert server.request("GET", "/viewer/viewer.js")[0] == 401
    status, headers, _body = server.request("GET", f"/?token={TOKEN}&width=320")
    assert status == 303 and headers["Location"] == "/?width=320"
    assert headers["Set-Cookie"] == f"sphrender_token={TOKEN}; Path=/; HttpOnly; SameSite=Strict"
    status, headers, page = server.request("GET", "/", headers=COOKIE)
    assert status == 200 and headers["Content-Type"] == "text/html; charset=utf-8"
    assert b'<script src="/viewer/viewer.js"' in page
    assert "script-src 'self'" in headers["Content-Security-Policy"]
    assets = (("/viewer/viewer.js", "text/javascript"), ("/viewer/viewer.css", "text/css"))
    for path, kind in assets:
        status, headers, body = server.request("GET", path, headers=COOKIE)
        assert status == 200 and headers["Content-Type"].startswith(kind) and body
    # The cookie alone authorises reading; a POST needs the viewer's header with it, which a
    # page of another origin cannot add without a CORS preflight.
    assert server.request("POST", "/v1/demo/sessions", b"{}", COOKIE)[0] == 401
    assert server.request("GET", "/v1/status", headers={"Cookie": "sphrender_token=x"})[0] == 401


def test_schema_status_and_resolved_scenes(server: ServerProcess) -> None:
    status, headers, body = server.request("GET", "/v1/schema", headers=AUTH)
    assert status == 200 and headers["Content-Type"] == "application/schema+json"
    assert body.decode() == scene_json_schema_text()
    assert server.request("GET", "/v1/schema")[0] == 401
    status, created = server.json("POST", "/v1/sessions", {}, headers=AUTH)
    assert status == 201 and created["scene"] == scene_to_dict(Scene())
    status, described = server.json("GET", f"/v1/sessions/{created['id']}", headers=AUTH)
    assert status == 200 and described["scene"] == created["scene"] and not described["demo"]
    # A JSON frame needs server-held particles; this session has none.
    frame = json.dumps({"scene": {"camera": {"fov_y": 30}}}).encode()
    json_headers = {**AUTH, "Content-Type": "application/json"}
    status, _h, error = server.request(
        "POST", f"/v1/sessions/{created['id']}/frames", frame, json_headers
    )
    assert status == 400 and json.loads(error)["field"] == "body"
    status, doc = server.json("GET", "/v1/status", headers=AUTH)
    assert status == 200 and doc["ready"] and doc["sessions"]["http"] >= 1
    assert set(doc["recent"]) == {"frames_per_s", "p50_ms", "p90_ms", "p99_ms", "frames"}
    assert server.request("DELETE", f"/v1/sessions/{created['id']}", headers=AUTH)[0] == 204


def test_demo_session_frames_take_a_camera(server: ServerProcess, tmp_path: Path) -> None:
    status, created = server.json(
        "POST", "/v1/demo/sessions", {"image": {"width": 160, "height": 90}}, headers=AUTH
    )
    assert status == 201, created
    assert created["scene"]["image"] == {"width": 160, "height": 90}
    assert created["scene"]["particles"]["radius"] == 0.4  # the demo's, not the default
    frames = f"/v1/sessions/{created['id']}/frames"
    json_headers = {**AUTH, "Content-Type": "application/json"}
    images = []
    for eye in ([-30.0, 26.0, 48.0], [40.0, 30.0, -20.0]):
        body = json.dumps({"scene": {"camera": {"eye": eye}}}).encode()
        status, headers, data = server.request("POST", frames + "?format=png", body, json_headers)
        assert status == 200 and headers["Content-Type"] == "image/png", data[:200]
        images.append(png_pixels(data, tmp_path))
    assert images[0].shape == (90, 160, 4)
    assert np.abs(images[0].astype(int) - images[1].astype(int)).mean() > 5  # the camera moved
    for body, field in (
        (b'{"scene": {"camera": {"fov_y": 0}}}', "camera.fov_y"),
        (b'{"camera": {}}', "body.camera"),
        (b'{"scene": 3}', "scene"),
        (b"[1]", "body"),
    ):
        status, _h, error = server.request("POST", frames, body, json_headers)
        assert status == 400 and json.loads(error)["field"] == field, error
    assert server.request("DELETE", f"/v1/sessions/{created['id']}", headers=AUTH)[0] == 204


# -- the page in a real browser ----------------------------------------------------------------

#: Element id on the page -> the value in GET /v1/status it shows.
SHOWN = {
    "renderer": lambda d: d["renderer"],
    "sessions-http": lambda d: d["sessions"]["http"],
    "sessions-stream": lambda d: d["sessions"]["stream"],
    "frames-per-s": lambda d: d["recent"]["frames_per_s"],
    "queue-depth": lambda d: d["queue_depth"],
    "in-flight": lambda d: d["in_flight"],
    "p50-ms": lambda d: d["recent"]["p50_ms"],
    "p90-ms": lambda d: d["recent"]["p90_ms"],
    "p99-ms": lambda d: d["recent"]["p99_ms"],
    "latency-frames": lambda d: d["recent"]["frames"],
    "frames-image": lambda d: d["frames_total"]["image"],
    "frames-error": lambda d: d["frames_total"]["error"],
    "frames-dropped": lambda d: d["frames_total"]["dropped"],
}
READ_SHOWN = (
    "window.sphrenderViewer.refreshStatus().then(() => Object.fromEntries("
    + json.dumps(list(SHOWN))
    + ".map((id) => [id, document.getElementById(id).dataset.value])))"
)


def decode_message(data: bytes) -> tuple[MessageType, dict[str, Any], bytes]:
    kind, hlen, _plen = parse_prefix(
        data[:PREFIX_SIZE], max_header_bytes=1 << 20, max_payload_bytes=1 << 30
    )
    return kind, parse_header(data[PREFIX_SIZE : PREFIX_SIZE + hlen]), data[PREFIX_SIZE + hlen :]


def http_frame_counts(server: ServerProcess) -> list[str]:
    """The /metrics lines counting HTTP frame requests (the page must add none)."""
    text = server.metrics_text(AUTH)
    return [line for line in text.splitlines() if 'route="/v1/sessions/{id}/frames"' in line]


def same(shown: str, value: Any) -> bool:
    return shown == value if isinstance(value, str) else float(shown) == float(value)


def check_status_matches(browser: Browser, server: ServerProcess) -> dict[str, Any]:
    compared: set[str] = set()
    for _round in range(5):
        before = server.json("GET", "/v1/status", headers=AUTH)[1]
        shown = browser.evaluate(READ_SHOWN)
        after = server.json("GET", "/v1/status", headers=AUTH)[1]
        for key, read in SHOWN.items():
            if read(before) == read(after):
                assert same(shown[key], read(after)), (key, shown[key], read(after))
                compared.add(key)
        if compared == set(SHOWN):
            return after
    raise AssertionError(f"values never stable between two reads: {set(SHOWN) - compared}")


def canvas_state(browser: Browser) -> dict[str, Any]:
    return dict(
        browser.evaluate(
            "(() => { const c = document.getElementById('live');"
            " const r = c.getBoundingClientRect();"
            " return {frames: Number(c.dataset.frames), fnv1a: c.dataset.fnv1a,"
            " session: c.dataset.session, body: window.sphrenderViewer.state.lastBody,"
            " error: document.getElementById('error').textContent,"
            " rect: [r.left, r.top, r.width, r.height]}; })()"
        )
    )


def check_screenshot(browser: Browser, rect: list[float], tmp_path: Path) -> None:
    shot = browser.screenshot(format="png")
    image = png_pixels(shot, tmp_path)[..., :3].astype(int)
    left, top, width, height = (round(v) for v in rect)
    region = image[top : top + height, left : left + width]
    assert region.shape[0] > 100 and region.shape[1] > 100
    assert region.std() > 8
    background = (np.abs(region - np.array(PAGE_BACKGROUND)).sum(axis=-1) <= 3).mean()
    assert background < 0.05, background
    if os.environ.get("SPHRENDER_UPDATE_DOCS") == "1":
        SCREENSHOT.parent.mkdir(exist_ok=True)
        SCREENSHOT.write_bytes(browser.screenshot(format="jpeg", quality=80))


def test_the_page_in_chromium_shows_the_servers_status_and_frames(
    server: ServerProcess, tmp_path: Path
) -> None:
    http_frames_before = http_frame_counts(server)
    with Browser(tmp_path / "profile") as browser:
        browser.command("Page.enable")
        url = f"http://127.0.0.1:{server.http_port}/?token={TOKEN}&width=480&height=270"
        browser.command("Page.navigate", url=url)
        browser.wait_for(
            "Number(document.getElementById('live')?.dataset.frames || 0) >= 1",
            timeout=150,
            what="the first demo frame on the page",
        )
        first = canvas_state(browser)
        assert first["error"] == "", first["error"]
        assert browser.evaluate("location.search") == "?width=480&height=270"  # token gone

        # Orbit: a drag on the canvas renders the demo from another eye.
        left, top, width, height = first["rect"]
        x, y = left + width / 2, top + height / 2
        browser.command("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y,
                        button="left", buttons=1, clickCount=1)  # fmt: skip
        for step in range(1, 6):
            browser.command("Input.dispatchMouseEvent", type="mouseMoved", x=x + 12 * step,
                            y=y + 3 * step, button="left", buttons=1)  # fmt: skip
        browser.command("Input.dispatchMouseEvent", type="mouseReleased", x=x + 60, y=y + 15,
                        button="left", buttons=0, clickCount=1)  # fmt: skip
        browser.wait_for(
            "window.sphrenderViewer.state.inFlight === 0 && "
            "!window.sphrenderViewer.state.dirty && "
            f"window.sphrenderViewer.state.frames > {first['frames']}",
            timeout=150,
            what="the orbited frame",
        )
        moved = canvas_state(browser)
        assert moved["error"] == "", moved["error"]
        assert (
            json.loads(moved["body"])["scene"]["camera"]["eye"]
            != json.loads(first["body"])["scene"]["camera"]["eye"]
        )
        assert moved["fnv1a"] != first["fnv1a"]

        # The page streamed over the WebSocket, not over HTTP frames.
        assert 'route="/v1/stream",code="101"' in server.metrics_text(AUTH)
        assert http_frame_counts(server) == http_frames_before
        assert browser.evaluate("window.sphrenderViewer.state.socket.readyState") == 1

        # The canvas holds exactly the server's frame for that FRAME: the same HELLO scene, the
        # demo's arrays and the page's camera, sent again on a raw stream connection.
        hello_scene = browser.evaluate("window.sphrenderViewer.state.helloScene")
        status, _headers, demo = server.request("GET", "/v1/demo/frame", headers=AUTH)
        assert status == 200
        kind, demo_header, demo_payload = decode_message(demo)
        assert kind == MessageType.FRAME and demo_header["id"] == 0
        header = {"id": 1, "arrays": demo_header["arrays"], **json.loads(moved["body"])}
        with server.stream() as client:
            client.hello(hello_scene, token=TOKEN)
            client.send(encode_message(MessageType.FRAME, header, demo_payload))
            kind, answer, data = client.receive()
            assert kind == MessageType.IMAGE, answer
        pixels = png_pixels(data, tmp_path)
        assert pixels.shape == (270, 480, 4) and (pixels[..., 3] == 255).all()
        assert pixels[..., :3].std() > 8  # a picture, not a flat fill
        assert fnv1a(pixels.tobytes()) == moved["fnv1a"]

        check_screenshot(browser, moved["rect"], tmp_path)

        # Another client's session, here a stream connection: the page lists it and shows
        # its latest image, byte for byte.
        with server.stream() as client:
            client.hello(STREAM_SCENE, token=TOKEN)
            client.frame(7, ball(1500, seed=5))
            kind, header, payload = client.receive()
            assert kind == MessageType.IMAGE and header["format"] == "png", header
            stream_pixels = png_pixels(payload, tmp_path)
            assert (stream_pixels[..., 3] == 255).all()
            listed = server.json("GET", "/v1/status", headers=AUTH)[1]["session_list"]
            stream_id = next(s for s in listed if s["id"] != moved["session"])
            assert stream_id["transport"] == "stream" and stream_id["images"] == 1
            browser.evaluate("window.sphrenderViewer.refreshStatus()")
            options = browser.evaluate(
                "[...document.getElementById('source').options].map((o) => o.value)"
            )
            assert options == ["demo", stream_id["id"]]
            browser.evaluate(f"window.sphrenderViewer.watch({json.dumps(stream_id['id'])})")
            watched = browser.wait_for(
                f"(() => {{ const c = document.getElementById('live');"
                f" return c.dataset.source === {json.dumps(stream_id['id'])}"
                f" && c.dataset.image === '1' && c.dataset.fnv1a; }})()",
                timeout=60,
                what="the stream session's image on the page",
            )
            assert watched == fnv1a(stream_pixels.tobytes())

            browser.evaluate("window.sphrenderViewer.stop()")
            shown_status = check_status_matches(browser, server)
            info = server.json("GET", "/v1/info", headers=AUTH)[1]
            assert shown_status["renderer"] == info["gl"]["renderer"]
            assert shown_status["frames_total"]["image"] >= 4  # page 2+, here 1, stream 1
            # The page's WebSocket session + ours.
            assert shown_status["sessions"] == {"http": 0, "stream": 2}


def test_the_pages_files_are_package_data() -> None:
    """A non-editable install carries every file of server/service/http/viewer_page/ (pyproject's
    package-data globs), and the server serves each of them."""
    import fnmatch
    import tomllib

    globs = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"
    ]["sphrender.server.service.http"]
    files = sorted(p.relative_to(REPO / "server/service/http").as_posix()
                   for p in (REPO / "server/service/http/viewer_page").iterdir())  # fmt: skip
    assert files == ["viewer_page/index.html", "viewer_page/viewer.css", "viewer_page/viewer.js"]
    for name in files:
        assert any(fnmatch.fnmatch(name, glob) for glob in globs), name


def test_recent_frames_percentiles_and_rate() -> None:
    """Nearest-rank percentiles over the last `size` images, and the rate over the images that
    finished within the window (timestamps given, so nothing here depends on the clock)."""
    from sphrender.server.service.metrics import RecentFrames

    recent = RecentFrames(size=100, window_s=10.0)
    assert recent.summary(now=0.0) == {
        "frames_per_s": 0.0, "p50_ms": 0.0, "p90_ms": 0.0, "p99_ms": 0.0, "frames": 0,
    }  # fmt: skip
    for i in range(150):  # latencies 1..150 ms, one frame every 0.5 s
        recent.add((i + 1) / 1000, now=i * 0.5)
    summary = recent.summary(now=74.5)
    # The last 100 are 51..150 ms: rank ceil(0.5 * 100) = 50 -> 100 ms, 90 -> 140, 99 -> 149.
    assert (summary["p50_ms"], summary["p90_ms"], summary["p99_ms"]) == (100.0, 140.0, 149.0)
    assert summary["frames"] == 100
    assert summary["frames_per_s"] == 2.0  # 21 frames in [64.5, 74.5]: 20 intervals / 10 s
    assert recent.summary(now=84.6)["frames_per_s"] == 0.0  # all older than the window


def test_latest_image_of_a_session(server: ServerProcess) -> None:
    from sphrender.core.protocol import encode_npz_frame

    status, created = server.json("POST", "/v1/sessions", SMALL_SCENE, headers=AUTH)
    assert status == 201
    latest = f"/v1/sessions/{created['id']}/latest"
    status, _h, error = server.request("GET", latest, headers=AUTH)
    assert status == 404 and json.loads(error)["field"] == "frame"
    assert server.request("GET", f"/v1/sessions/{'0' * 32}/latest", headers=AUTH)[0] == 404
    frames = f"/v1/sessions/{created['id']}/frames"
    npz = {**AUTH, "Content-Type": "application/x-npz"}
    status, _h, image = server.request("POST", frames, encode_npz_frame(ball(500)), npz)
    assert status == 200
    status, headers, kept = server.request("GET", latest, headers=AUTH)
    assert status == 200 and kept == image and headers["ETag"] == '"1"'
    assert headers["Content-Type"] == "image/png"
    status, headers, body = server.request("GET", latest, headers={**AUTH, "If-None-Match": '"1"'})
    assert status == 304 and body == b""
    status, _h, _exr = server.request(
        "POST", frames + "?format=exr", encode_npz_frame(ball(500)), npz
    )
    assert status == 200
    status, _h, error = server.request("GET", latest, headers=AUTH)
    assert status == 404 and "exr" in json.loads(error)["error"]
    assert server.request("DELETE", f"/v1/sessions/{created['id']}", headers=AUTH)[0] == 204
