"""Device prepare (issue "GPU-ready frame"): the compute shader that culls and transforms the
particles on the GPU gives the image the CPU's prepare gives, on every hard case.

Both paths compute the view-space centre in float64 and round it to float32 once, and the same
rectangles and far distance, so the splatted depth agrees exactly wherever one sphere is in
front. Where two spheres tie in the 24-bit depth buffer (|depth difference| < far / 2**24) the
one drawn first wins, and the host path's occlusion culling draws in another order than the
device's one pass: those pixels may hold either sphere's depth, so the tolerance is that tie
width. Colours follow the depth through the same passes: at most the same tie, seen through the
smoothing's normalised weights and the shading, which the 1e-4 colour tolerance (sRGB-linear
units, ~1/40 of an 8-bit step) bounds with room.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from sphrender.core.frame import make_frame
from sphrender.server.content.lattice import jittered_lattice_ball, lattice_slab
from sphrender.server.engine.frame_output import RenderedFrame, RenderStats
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.geometry.prepare import prepare_particles
from sphrender.server.engine.gpu.draw import FullscreenTriangle, read_image
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.gpu.programs import ProgramCache
from sphrender.server.engine.passes.context import PassContext
from sphrender.server.engine.passes.device_culling import DeviceCullInput
from sphrender.server.engine.passes.device_prepare import DevicePrepare
from sphrender.server.engine.passes.prepare_stage import resolve_mode
from sphrender.server.engine.passes.splat import SplatPass
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import Scene, scene_from_dict

R = 0.01
TIE = 2.0**-24  # of far: one step of the 24-bit depth buffer


@pytest.fixture(scope="module")
def renderers(gl_context: GLContext) -> Iterator[tuple[SurfaceRenderer, SurfaceRenderer]]:
    host = SurfaceRenderer(gl_context, prepare="host")
    device = SurfaceRenderer(gl_context, prepare="device")
    yield host, device
    host.release()
    device.release()


def scene_at(shift: float = 0.0, **sections: Any) -> Scene:
    base: dict[str, Any] = {
        "image": {"width": 160, "height": 96},
        "camera": {
            "eye": [0.5 + shift, 0.35 + shift, 0.6 + shift],
            "target": [shift, shift, shift],
            "fov_y": 40.0,
        },
        "particles": {"radius": R},
    }
    for key, value in sections.items():
        base[key] = {**base.get(key, {}), **value}
    return scene_from_dict(base)


def both(
    renderers: tuple[SurfaceRenderer, SurfaceRenderer], scene: Scene, positions: Any, **arrays: Any
) -> tuple[tuple[RenderedFrame, RenderStats], tuple[RenderedFrame, RenderStats]]:
    frame = make_frame(positions, **arrays)
    host, device = renderers
    return (
        host.render(frame, scene, depth=True, normals=True),
        device.render(frame, scene, depth=True, normals=True),
    )


def assert_same_image(
    host: tuple[RenderedFrame, RenderStats], device: tuple[RenderedFrame, RenderStats]
) -> None:
    (a, sa), (b, sb) = host, device
    assert a.depth is not None and b.depth is not None
    assert np.isfinite(b.rgba).all() and not np.isnan(b.depth).any()
    assert sa.particles_drawn == sb.particles_drawn
    np.testing.assert_allclose(sb.far, sa.far, rtol=1e-6)  # float32 vs float64 max, x 1.001
    hit_a, hit_b = np.isfinite(a.depth), np.isfinite(b.depth)
    assert np.array_equal(hit_a, hit_b)
    tie = sa.far * TIE * 2  # the tie, plus the far distances' rounding
    np.testing.assert_allclose(b.depth[hit_b], a.depth[hit_a], rtol=0, atol=tie)
    np.testing.assert_allclose(b.rgba, a.rgba, rtol=0, atol=1e-4)


@pytest.mark.parametrize("shift", [0.0, 1e5])
def test_ball_with_temperatures_matches_the_host_prepare(
    renderers: tuple[SurfaceRenderer, SurfaceRenderer], shift: float
) -> None:
    """A 4k-particle ball (the host path culls it: > MIN_PARTICLES) with per-particle kelvin,
    near the origin and at 1e5 (eye and particles shifted together)."""
    positions = jittered_lattice_ball(0.2, R, seed=3) + shift
    kelvin = np.linspace(300.0, 2200.0, len(positions)).astype(np.float32)
    host, device = both(renderers, scene_at(shift), positions, temperatures=kelvin)
    for _, stats in (host, device):  # both culled (the device's aligned pyramid a bit less)
        assert stats.particles_splatted < 0.8 * stats.particles_drawn
    assert_same_image(host, device)


def test_sparse_cloud_matches_the_host_prepare(
    renderers: tuple[SurfaceRenderer, SurfaceRenderer],
) -> None:
    """A gaussian cloud of 3000 particles: culled (> MIN_PARTICLES) but most are drawn and most
    reach an edge, so the host path's coverage id list runs past the particle count (it once
    ran past the quad index buffer and lost the coverage of 650 silhouette pixels)."""
    positions = np.random.default_rng(0).normal(size=(3000, 3)) * 0.15
    host, device = both(renderers, scene_at(), positions)
    alpha = host[0].rgba[..., 3]
    assert host[0].depth is not None and (alpha[np.isfinite(host[0].depth)] > 0).all()
    assert_same_image(host, device)


def test_dense_wall_behind_spatter(renderers: tuple[SurfaceRenderer, SurfaceRenderer]) -> None:
    """A dense slab (spacing 1 r, so the front layer covers it without gaps) with small droplets
    8 r in front of it: the droplets pull their tiles' front forward, so the slab particles in
    those tiles miss the front band and are drawn only by the occlusion test's second draw."""
    slab = lattice_slab(0.3, 0.3, 8, R / 2)  # spacing r: 8 layers are 7 r deep
    drops = np.random.default_rng(6).uniform([-0.12, 8 * R, -0.12], [0.12, 8 * R, 0.12], (40, 3))
    radii = np.concatenate([np.full(len(slab), R, np.float32), np.full(40, 0.3 * R, np.float32)])
    scene = scene_at(image={"width": 480, "height": 288})  # particles ~5 px: the tests bite
    host, device = both(renderers, scene, np.concatenate([slab, drops]), radii=radii)
    assert host[1].particles_splatted < host[1].particles_drawn  # both cull
    assert device[1].particles_splatted < device[1].particles_drawn
    assert_same_image(host, device)


def test_buffers_grown_between_frames(
    gl_context: GLContext, renderers: tuple[SurfaceRenderer, SurfaceRenderer]
) -> None:
    """A fresh device renderer, a small frame, then one 10x larger: every storage buffer grows
    (a binding made before a buffer grew reads zeros past its old end: the culling flags once
    did and dropped 472 pixels)."""
    device = SurfaceRenderer(gl_context, prepare="device")
    try:
        small = np.random.default_rng(1).normal(size=(3000, 3)) * 0.15
        large = np.random.default_rng(2).normal(size=(30000, 3)) * 0.15
        device.render(make_frame(small), scene_at())
        frame = make_frame(large)
        grown = device.render(frame, scene_at(), depth=True, normals=True)
        host = renderers[0].render(frame, scene_at(), depth=True, normals=True)
        assert_same_image(host, grown)
    finally:
        device.release()


def test_near_plane_eye_plane_and_eye_inside(
    renderers: tuple[SurfaceRenderer, SurfaceRenderer],
) -> None:
    """Spheres cut by the near plane, one reaching the eye plane (no rectangle: the whole image
    is the box), one around the eye (culled), one behind the camera, tiny and huge radii."""
    eye = np.array([0.5, 0.35, 0.6])
    ahead = -eye / np.linalg.norm(eye)
    positions = np.concatenate(
        [
            jittered_lattice_ball(0.06, R, seed=1),
            [eye + ahead * 0.12, eye + ahead * 0.005 + [0.03, 0.0, 0.0], eye, eye - ahead * 0.3],
            [[0.05, 0.05, 0.05], [-0.05, 0.0, 0.02]],
        ]
    )
    radii = np.full(len(positions), R, np.float32)
    radii[-6:] = [0.02, 0.02, 0.01, 0.05, 1e-5, 0.08]
    scene = scene_at(camera={"near": 0.1})
    host, device = both(renderers, scene, positions, radii=radii)
    assert_same_image(host, device)


def test_droplets_and_a_far_limit(renderers: tuple[SurfaceRenderer, SurfaceRenderer]) -> None:
    """Exact droplets (client densities below droplet_density) over a slab, and a scene far
    distance that cuts the slab's back."""
    pool = lattice_slab(0.3, 0.3, 2, R)
    drops = np.array([[0.0, 5 * R, 0.0], [0.05, 7 * R, -0.04], [-0.06, 4 * R, 0.05]])
    positions = np.concatenate([pool, drops])
    densities = np.full(len(positions), 1000.0, np.float32)
    densities[-3:] = 100.0
    scene = scene_at(camera={"far": 0.85}, quality={"exact_droplets": True})
    host, device = both(renderers, scene, positions, densities=densities)
    assert host[1].stage_ms.get("droplets") is not None and "droplets" in device[1].stage_ms
    assert_same_image(host, device)


def test_nothing_to_draw(renderers: tuple[SurfaceRenderer, SurfaceRenderer]) -> None:
    """Zero particles, and particles all behind the camera: background, no error. The frame
    with particles none of which is in view says so in a note (their extent and the camera,
    the same from both prepares); the empty frame has nothing to say."""
    for positions in (np.zeros((0, 3)), np.array([[1.0, 1.0, 1.5], [2.0, 1.5, 2.0]])):
        host, device = both(renderers, scene_at(), positions)
        assert device[1].particles_drawn == 0
        assert_same_image(host, device)
        assert host[1].notes == device[1].notes
        if len(positions):
            (note,) = device[1].notes
            assert note.field == "camera"
            assert "none of the frame's 2 particles is in view" in note.message
            assert "x 1 to 2, y 1 to 1.5, z 1.5 to 2" in note.message
        else:
            assert device[1].notes == []


def test_ellipsoids_match_the_host_prepare(gl_context: GLContext) -> None:
    """Fixed tilted ellipsoids (2 : 1 : 0.5 r) at 1e5 through both prepares, the splat alone:
    the same depth image (the device computes the bounding radius from the axes itself), with
    and without the device's occlusion culling."""
    positions = jittered_lattice_ball(0.18, R, seed=5)  # > MIN_PARTICLES: culled
    rotations = np.linalg.qr(np.random.default_rng(2).normal(size=(len(positions), 3, 3)))[0]
    axes = (rotations * np.array([2 * R, R, 0.5 * R])).astype(np.float32)
    scene = scene_at(1e5)
    shifted = positions + 1e5
    camera = Camera.from_config(scene.camera, 160, 96)
    context = PassContext(gl_context, ProgramCache(gl_context), FullscreenTriangle(gl_context))
    splat = SplatPass(context)
    try:
        frame = make_frame(shifted)
        prepared = prepare_particles(frame, camera, scene, ellipsoids=(shifted, axes))
        host = read_image(
            splat.run(camera, splat.upload(prepared), bounds=None, box=None).depth.read(), 160, 96
        )
        device = DevicePrepare(context, splat.buffers).run(
            frame, camera, scene, ellipsoids=(shifted, axes)
        )
        assert device.visible == prepared.center_radius.shape[0]
        got = read_image(
            splat.run(camera, device.bulk, bounds=None, box=device.box).depth.read(), 160, 96
        )
        cull = DeviceCullInput(device.bulk.count, device.nearest, device.bulk.far, R)
        culled_out = splat.run(camera, device.bulk, bounds=None, box=device.box, device_cull=cull)
        culled = read_image(culled_out.depth.read(), 160, 96)
        assert splat.splatted(culled_out.splatted, device.visible) < device.visible  # it did cull
    finally:
        splat.release()
        context.fullscreen.release()
        context.programs.release()
    assert (host > 0).sum() > 500
    # The same pixels hit; depths to float32 rounding: the bounding radius (numpy's float32 norm
    # vs GLSL length, which may differ in the last bit) sizes the quad, and each fragment's ray
    # is the normalised interpolated quad point, so a few ulps of depth move (measured: 21 of
    # ~2000 pixels, 1-2 ulps).
    assert np.array_equal(got > 0, host > 0)
    np.testing.assert_allclose(got, host, rtol=4 * 2.0**-23, atol=0)
    # Culled on the device (bounding spheres, aligned pyramid): the same draws' depth, up to
    # depth-buffer ties of the changed draw order.
    assert np.array_equal(culled > 0, got > 0)
    np.testing.assert_allclose(culled, got, rtol=0, atol=device.bulk.far * TIE * 2)


def test_host_ms_is_reported(renderers: tuple[SurfaceRenderer, SurfaceRenderer]) -> None:
    """Every frame says what its render thread did outside GL calls: a positive share of the
    wall time, which the stage times (measured with the GPU waited for) bound from above."""
    for renderer in renderers:
        _, stats = renderer.render(make_frame(jittered_lattice_ball(0.05, R)), scene_at())
        assert 0.0 < stats.host_ms < sum(stats.stage_ms.values()) + 50.0


def test_prepare_modes_resolve_and_bad_ones_are_named(monkeypatch: pytest.MonkeyPatch) -> None:
    """auto: host on a software rasteriser, device on a GPU, unless SPHRENDER_PREPARE says;
    an unknown mode names where it came from and the allowed values."""
    monkeypatch.delenv("SPHRENDER_PREPARE", raising=False)
    assert resolve_mode("auto", software=True) == "host"
    assert resolve_mode("auto", software=False) == "device"
    assert resolve_mode("device", software=True) == "device"
    monkeypatch.setenv("SPHRENDER_PREPARE", "device")
    assert resolve_mode("auto", software=True) == "device"
    assert resolve_mode("host", software=False) == "host"  # an explicit mode wins
    monkeypatch.setenv("SPHRENDER_PREPARE", "gpu")
    with pytest.raises(ValueError, match="SPHRENDER_PREPARE must be one of auto, host, device"):
        resolve_mode("auto", software=True)
    with pytest.raises(ValueError, match="prepare must be one of"):
        resolve_mode("fast", software=True)
