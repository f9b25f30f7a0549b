"""Surface detail from an image file (`[finish] detail_image`): a height map with a known slope
gives the analytic normal tilt on an exact plane (also at 1e5), the detail stays on the
workpiece when the camera moves, a changed file is read again, and bad files are refused with
errors that name the field, in-process and through the real server over HTTP. Every image is
written here with OpenImageIO into the test's own directory."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import OpenImageIO as oiio
import pytest
import reference_shading as ref
from service_harness import SMALL_SCENE, ServerProcess, ball
from single_passes import SinglePasses
from world_fixed import two_view_angles

from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.core.protocol import MessageType, encode_message, encode_npz_frame
from sphrender.server.content.lattice import lattice_slab
from sphrender.server.content.marks import grinding_marks
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.lighting.detail_image import detail_texels
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

FIELD = "finish.detail_image"
#: Texels per tile of the test's height map: the wave below has one period per tile.
TEXELS = 64
WAVE = 0.25  # amplitude of each of the two sinusoids (image values)


def write_image(path: Path, pixels: npt.ArrayLike, format: str = "float") -> Path:
    """`pixels` (H, W, C) written with OpenImageIO (the type from `format`)."""
    data = np.asarray(pixels, dtype=np.float32)
    height, width, channels = data.shape
    out = oiio.ImageOutput.create(os.fspath(path))
    assert out is not None, oiio.geterror()
    out.open(os.fspath(path), oiio.ImageSpec(width, height, channels, format))
    out.write_image(data if format == "float" else np.clip(data, 0, 1))
    out.close()
    return path


def wave(n: int = TEXELS) -> npt.NDArray[np.float64]:
    """h = 0.5 + WAVE sin(2 pi u) + WAVE sin(2 pi v + pi / 4) at the texel centres, (n, n, 1):
    swapping u and v, or mirroring either, gives another image."""
    centres = (np.arange(n) + 0.5) / n
    along_u = WAVE * np.sin(2 * np.pi * centres)[None, :]
    along_v = WAVE * np.sin(2 * np.pi * centres + np.pi / 4)[:, None]
    return (0.5 + along_u + along_v)[..., None]


def wave_normals(world: npt.NDArray, axis: int, size: float, depth: float) -> npt.NDArray:
    """The analytic normals of a face whose normal is +`axis` under `wave`: there the tile's u
    runs along world axis + 1 and v along axis + 2 (detail_image.glsl), so height = depth (WAVE
    sin(2 pi p_u / size) + WAVE sin(2 pi p_v / size + pi / 4)); the normal is e_axis - grad."""
    k = 2 * np.pi / size
    along_u, along_v = (axis + 1) % 3, (axis + 2) % 3
    n = np.zeros(world.shape)
    n[..., axis] = 1.0
    n[..., along_u] = -depth * WAVE * k * np.cos(k * world[..., along_u])
    n[..., along_v] = -depth * WAVE * k * np.cos(k * world[..., along_v] + np.pi / 4)
    result: npt.NDArray = n / np.linalg.norm(n, axis=-1, keepdims=True)
    return result


@pytest.fixture(scope="module")
def assets(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The directory the scenes' images are named relative to (the server's environment dir)."""
    directory = tmp_path_factory.mktemp("assets")
    write_image(directory / "wave.exr", wave())
    write_image(directory / "rgb.png", np.full((4, 4, 3), 0.5), "uint8")
    write_image(directory / "huge.png", np.zeros((1, 2049, 1)), "uint8")
    nan = wave(8)
    nan[3, 5, 0] = np.nan
    write_image(directory / "nan.exr", nan)
    write_image(directory / "big.exr", np.full((4, 4, 1), 2e6))
    write_image(directory / "fine.exr", np.tile(wave(4), (16, 16, 1)))  # period: 4 texels
    (directory / "junk.png").write_bytes(b"this is not an image at all")
    whole = write_image(directory / "trunc.png", wave(64), "uint8").read_bytes()
    (directory / "trunc.png").write_bytes(whole[: len(whole) // 2])  # a header, half the pixels
    roughness = np.stack([np.full((4, 4), 0.5), np.ones((4, 4))], axis=-1)  # flat, map = 1
    write_image(directory / "rough.exr", roughness)
    outside = write_image(directory.parent / "outside.exr", wave(8))
    os.symlink(outside, directory / "escape.exr")
    return directory


@pytest.fixture(scope="module")
def image_renderer(gl_context: GLContext, assets: Path) -> Iterator[SurfaceRenderer]:
    renderer = SurfaceRenderer(gl_context, environment_dirs=[assets])
    yield renderer
    renderer.release()


def plane_scene(
    eye: list[float], target: list[float], finish: dict[str, Any], radius: float = 0.02
) -> Scene:
    return scene_from_dict(
        {
            "image": {"width": 128, "height": 96},
            "camera": {"eye": eye, "target": target, "fov_y": 35.0},
            "particles": {"radius": radius},
            "finish": finish,
        }
    )


@pytest.mark.parametrize("origin", [0.0, 1e5])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_known_slope_gives_the_analytic_tilt(
    image_renderer: SurfaceRenderer, origin: float, axis: int
) -> None:
    """The plane p_axis = origin facing +axis (exact normals and depth) under the wave: each
    pixel's detail normal against the analytic one at its world point. The image's own error:
    central differences and bilinear lookup of a sinusoid of 64 texels lose (2 pi / 64)^2 (1/6
    + 1/8) = 0.3 % of the slope (<= 0.22 here), 0.04 deg; only pixels whose footprint is under a
    texel are kept (coarser levels average the slope, by design). At 1e5 the eye's tile offset
    (float64 on the host) keeps the same bound."""
    size, depth = 2.0, 0.2
    target = np.full(3, origin)
    offsets = np.zeros(3)
    offsets[[axis, (axis + 1) % 3, (axis + 2) % 3]] = (1.2, 0.3, 0.9)
    scene = plane_scene(list(target + offsets), list(target), {"detail_image": "wave.exr",
                        "detail_image_size": size, "detail_image_depth": depth})  # fmt: skip
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    rays = ref.pixel_rays(camera)
    towards = -rays.directions[..., axis]  # the cosine between the ray and the face's normal
    t = (camera.eye[axis] - origin) / np.maximum(towards, 1e-9)
    hit = towards > 0.05
    image = np.zeros((camera.height, camera.width, 4), dtype=np.float32)
    image[..., axis] = np.where(hit, 1.0, 0.0)
    image[..., 3] = np.where(hit, t * rays.view_z, 0.0)
    got = SinglePasses(image_renderer).detail_normal_depth(image, scene)
    world = camera.eye + rays.directions * t[..., None]
    footprint = t * 2 * camera.tan_half_fov_y / camera.height / np.maximum(towards, 0.25)
    fine = hit & (np.log2(footprint * TEXELS / size) < -0.1)
    assert fine.sum() > 0.5 * hit.sum()
    want = wave_normals(world, axis, size, depth)
    n = got[..., :3].astype(np.float64)
    angle = np.degrees(np.arccos(np.clip(np.sum(n * want, -1), -1, 1)))[fine]
    tilt = np.degrees(np.arccos(want[..., axis]))[fine]
    print(f"{fine.sum()} px: max error {angle.max():.4f} deg, tilt mean {tilt.mean():.2f} deg")
    assert tilt.mean() > 4.0  # the detail is there
    assert angle.max() < 0.1
    assert np.array_equal(got[..., 3], image[..., 3])  # depth passes through


def test_marks_finer_than_a_pixel_average_out(image_renderer: SurfaceRenderer) -> None:
    """A sinusoid of 4 texels a period, its tile 0.05 wide, seen from ~1.5 away: a pixel covers
    ~16 texels (level ~4), and from level 2 on every texel averages whole periods, whose sampled
    slopes sum to 0. So the normals stay flat (within 0.1 degree; measured 0) where the base
    level would tilt them by up to 19 degrees: no aliased noise."""
    size, depth = 0.05, 0.0011
    finish = {"detail_image": "fine.exr", "detail_image_size": size, "detail_image_depth": depth}
    scene = plane_scene([0.3, 1.2, 0.9], [0.0, 0.0, 0.0], finish)
    camera = Camera.from_config(scene.camera, scene.image.width, scene.image.height)
    rays = ref.pixel_rays(camera)
    towards = -rays.directions[..., 1]
    t = camera.eye[1] / np.maximum(towards, 1e-9)
    hit = towards > 0.05
    image = np.zeros((camera.height, camera.width, 4), dtype=np.float32)
    image[..., 1] = np.where(hit, 1.0, 0.0)
    image[..., 3] = np.where(hit, t * rays.view_z, 0.0)
    got = SinglePasses(image_renderer).detail_normal_depth(image, scene)
    footprint = t * 2 * camera.tan_half_fov_y / camera.height / np.maximum(towards, 0.25)
    coarse = hit & (np.log2(footprint * TEXELS / size) > 2.5)
    assert coarse.sum() > 0.9 * hit.sum()
    fine = detail_texels(np.tile(wave(4), (16, 16, 1)).astype(np.float32))
    base = np.degrees(np.arctan(depth / size * fine.slope_scale))  # the steepest base texel
    tilt = np.degrees(np.arccos(np.clip(got[..., 1], -1, 1)))[coarse]
    print(f"{coarse.sum()} px: tilt max {tilt.max():.3f} deg (base level up to {base:.1f})")
    assert base > 15.0 and tilt.max() < 0.1


def top_face(
    renderer: SurfaceRenderer, frame: ParticleFrame, eye: list[float], finish: dict[str, Any]
) -> tuple[npt.NDArray, npt.NDArray]:
    """World (x, z) of the plate's top-face pixels seen from `eye` and the detail's slope there,
    s = n - n_d / (n . n_d) from the normals without (n) and with (n_d) the image detail."""
    scenes = [plane_scene(eye, [0.0, 0.0, 0.0], f) for f in (finish, {})]
    camera = Camera.from_config(scenes[0].camera, 128, 96)
    out, _ = renderer.render(frame, scenes[0], depth=True, normals=True)
    plain, _ = renderer.render(frame, scenes[1], depth=True, normals=True)
    assert out.depth is not None and out.normals is not None and plain.normals is not None
    assert np.all(np.isfinite(out.rgba))
    rays = ref.pixel_rays(camera)
    world = camera.eye + rays.directions * (out.depth.astype(np.float64) / rays.view_z)[..., None]
    n, n_d = plain.normals.astype(np.float64), out.normals.astype(np.float64)
    top = np.isfinite(world[..., 1]) & (world[..., 1] > 0.0) & (n[..., 1] > 0.99)
    slope = n[top] - n_d[top] / np.sum(n[top] * n_d[top], axis=-1, keepdims=True)
    return world[top][:, [0, 2]], slope[:, [0, 2]]


def test_image_detail_stays_put_when_the_camera_moves(image_renderer: SurfaceRenderer) -> None:
    """The plate's top face from two cameras half a turn apart: view B's slopes interpolated
    (linear over its pixels' world x, z) at view A's points give normals within 1 degree of
    A's. The interpolation's own error on the wave (period 0.3, B's pixels ~0.01 apart) is
    (2 pi 0.01 / 0.3)^2 / 8 = 0.5 % of a slope <= 0.15, 0.05 deg; the rest is each view's
    screen-space surface (its bumps and base normals), which put each view alone 0.26 / 0.36
    deg (p99) from the analytic normals when measured; together p99 0.45, max 0.71 deg."""
    finish = {"detail_image": "wave.exr", "detail_image_size": 0.3, "detail_image_depth": 0.03}
    frame = make_frame(lattice_slab(1.2, 1.2, 2, 0.02))
    points_a, slopes_a = top_face(image_renderer, frame, [0.0, 1.3, 1.0], finish)
    points_b, slopes_b = top_face(image_renderer, frame, [0.7, 1.1, -0.9], finish)
    angle, tilt = two_view_angles(points_a, slopes_a, points_b, slopes_b)
    assert tilt.mean() > 3.0  # the detail is there: a screen-fixed one would differ this much
    assert angle.max() < 1.0


def test_a_changed_file_is_read_again(gl_context: GLContext, tmp_path: Path) -> None:
    """The texture is cached per file; writing the file anew (new mtime) takes effect on the
    next frame: a flat height map then leaves the normals as without detail."""
    renderer = SurfaceRenderer(gl_context, environment_dirs=[tmp_path])
    try:
        path = write_image(tmp_path / "marks.exr", wave())
        frame = make_frame(lattice_slab(0.6, 0.6, 2, 0.02))
        base = {**SMALL_SCENE, "camera": {"eye": [0.0, 0.8, 0.6], "target": [0, 0, 0]}}
        finish = {"detail_image": "marks.exr", "detail_image_size": 0.2, "detail_image_depth": 0.02}
        plain, _ = renderer.render(frame, scene_from_dict(base), normals=True)
        first, _ = renderer.render(frame, scene_from_dict({**base, "finish": finish}), normals=True)
        stat = path.stat()
        write_image(path, np.full((8, 8, 1), 0.3))
        os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))
        second, _ = renderer.render(
            frame, scene_from_dict({**base, "finish": finish}), normals=True
        )
        assert plain.normals is not None and first.normals is not None
        assert second.normals is not None
        assert np.abs(first.normals - plain.normals).max() > 0.02
        assert np.abs(second.normals - plain.normals).max() < 1e-5
    finally:
        renderer.release()


BAD_FILES = [
    ("missing.png", "not found in the environment directories"),
    ("junk.png", "cannot be read as an image"),
    ("trunc.png", "the pixels of trunc.png cannot be read (damaged file)"),
    ("rgb.png", "has 3 channels; a detail image has 1 (height) or 2 (height, roughness)"),
    ("huge.png", "is 2049x1 pixels; at most 2048 a side"),
    ("nan.exr", "contains NaN or infinite pixels"),
    ("big.exr", "has values beyond -1e6 to 1e6"),
    ("../wave.exr", "must be a path relative to an environment directory"),
    ("/etc/passwd.png", "must be a path relative to an environment directory"),
    ("wave.txt", "must end in one of .png, .exr"),
    ("escape.exr", "leads outside the environment directories"),
]


@pytest.mark.parametrize(("name", "words"), BAD_FILES)
def test_bad_files_are_refused_naming_the_field(
    image_renderer: SurfaceRenderer, assets: Path, name: str, words: str
) -> None:
    scene = plane_scene([0.5, 0.5, 0.5], [0, 0, 0], {"detail_image": name})
    frame = make_frame(lattice_slab(0.2, 0.2, 1, 0.02))
    with pytest.raises(InputError) as caught:
        image_renderer.render(frame, scene)
    assert caught.value.field == FIELD
    assert words in caught.value.message, caught.value.message
    assert str(assets) not in caught.value.message  # never the server's own directories
    good = plane_scene([0.5, 0.5, 0.5], [0, 0, 0], {"detail_image": "wave.exr"})
    rendered, _ = image_renderer.render(frame, good)  # the renderer is still whole
    assert np.all(np.isfinite(rendered.rgba))


def test_the_steepest_detail_stays_finite(image_renderer: SurfaceRenderer) -> None:
    """The largest depth over the smallest tile (slopes ~1e21 before the shader's clamp), seen
    from near and far: every colour, depth and normal finite, normals unit length."""
    frame = make_frame(lattice_slab(0.6, 0.6, 2, 0.02))
    finish = {"detail_image": "wave.exr", "detail_image_depth": 1e6, "detail_image_size": 1e-6,
              "detail_image_roughness": 1.0}  # fmt: skip
    for eye in ([0.0, 0.8, 0.6], [0.0, 0.05, 0.4]):
        scene = plane_scene(eye, [0.0, 0.0, 0.0], finish)
        out, _ = image_renderer.render(frame, scene, depth=True, normals=True)
        assert out.normals is not None and np.all(np.isfinite(out.rgba))
        length = np.linalg.norm(out.normals, axis=-1)
        surface = length > 0
        assert surface.any() and np.allclose(length[surface], 1.0, atol=1e-3)


def test_a_roughness_map_of_one_adds_the_strength(image_renderer: SurfaceRenderer) -> None:
    """A flat height with a roughness channel of 1 moves roughness by + strength (2 g - 1) =
    + strength everywhere: the same image as the material's roughness raised by it (0.3 + 0.4).
    0.3 + 0.4 rounds to 1 ulp above 0.7, and where that moves an IBL or BRDF-table lookup across
    one of llvmpipe's 8-bit filter weight steps the colour moves by up to 1/256 of the texels'
    difference: rtol 1/256 (measured: 1.1e-3 at most, on 135 of the pixels)."""
    frame = make_frame(lattice_slab(0.6, 0.6, 2, 0.02))
    base = {**SMALL_SCENE, "camera": {"eye": [0.0, 0.8, 0.6], "target": [0, 0, 0]}}
    finish = {"detail_image": "rough.exr", "detail_image_roughness": 0.4}
    mapped = {**base, "material": {"roughness": 0.3}, "finish": finish}
    raised = {**base, "material": {"roughness": 0.7}}
    got, _ = image_renderer.render(frame, scene_from_dict(mapped))
    want, _ = image_renderer.render(frame, scene_from_dict(raised))
    lower, _ = image_renderer.render(frame, scene_from_dict({**mapped, "finish": {}}))
    assert np.abs(want.rgba - lower.rgba).max() > 0.01  # roughness shows in this view
    np.testing.assert_allclose(got.rgba, want.rgba, rtol=1 / 256, atol=1e-6)


def test_roughness_map_moves_the_shading_and_stays_finite(
    image_renderer: SurfaceRenderer,
) -> None:
    """With only the roughness moved (depth 0), normals are as without detail and colour is not."""
    frame = make_frame(lattice_slab(0.6, 0.6, 2, 0.02))
    base = {**SMALL_SCENE, "camera": {"eye": [0.0, 0.8, 0.6], "target": [0, 0, 0]}}
    finish = {"detail_image": "wave.exr", "detail_image_depth": 0.0,
              "detail_image_roughness": 1.0, "detail_image_size": 0.2}  # fmt: skip
    plain, _ = image_renderer.render(frame, scene_from_dict(base), normals=True)
    rough, _ = image_renderer.render(
        frame, scene_from_dict({**base, "finish": finish}), normals=True
    )
    assert plain.normals is not None and rough.normals is not None
    assert np.abs(rough.normals - plain.normals).max() < 1e-5
    assert np.all(np.isfinite(rough.rgba))
    assert np.abs(rough.rgba[..., :3] - plain.rgba[..., :3]).max() > 0.01


def test_bad_files_over_http_name_the_field(assets: Path, tmp_path: Path) -> None:
    """Through `sphrender serve`: a session naming a bad file gets 400 with the field and the
    reason in its JSON, and so does a frame naming it, and a stream HELLO a fatal ERROR; a good
    file then renders (the server and its renderer are up)."""
    config = {"security": {"environment_dirs": [str(assets)]}}
    with ServerProcess(tmp_path / "server", config) as service:
        for name, words in (BAD_FILES[0], BAD_FILES[2], BAD_FILES[4], BAD_FILES[5]):
            bad = {**SMALL_SCENE, "finish": {"detail_image": name}}
            status, answer = service.json("POST", "/v1/sessions", bad)
            assert status == 400, answer
            assert answer["field"] == FIELD and words in answer["error"], answer
            status, _h, body = service.request(
                "POST", "/v1/render", encode_npz_frame(ball(200), scene=bad)
            )
            error = json.loads(body)
            assert status == 400 and error["field"] == FIELD, error
            assert words in error["error"], error
            with service.stream() as client:
                client.send(encode_message(MessageType.HELLO, {"scene": bad}))
                kind, header, _payload = client.receive()
                assert kind == MessageType.ERROR and header["code"] == "bad_input", header
                assert header["field"] == FIELD and words in header["error"], header
        good = {**SMALL_SCENE, "finish": {"detail_image": "wave.exr"}}
        status, _h, body = service.request(
            "POST", "/v1/render", encode_npz_frame(ball(200), scene=good)
        )
        assert status == 200 and body.startswith(b"\x89PNG")


def test_grinding_marks_tile_without_seams() -> None:
    """The example's height map wraps: the step across the tile's edge is no larger than the
    largest step inside it (a seam would be a step of up to a whole mark's depth)."""
    heights = grinding_marks(64, marks=20)[..., 0].astype(np.float64)
    assert heights.min() >= 0.0 and heights.max() == 1.0 and heights.min() < 0.5
    for axis in (0, 1):
        inside = np.abs(np.diff(heights, axis=axis)).max()
        edge = np.abs(np.take(heights, 0, axis) - np.take(heights, -1, axis)).max()
        assert edge <= inside


def test_ground_plate_example_is_a_valid_scene() -> None:
    from sphrender.server.scene import read_scene_toml

    path = Path(__file__).resolve().parents[1] / "examples" / "ground_plate.toml"
    scene = scene_from_dict(read_scene_toml(path))
    assert scene.finish.detail_image == "grinding-marks.exr"
