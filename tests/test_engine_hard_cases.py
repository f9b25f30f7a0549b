"""Numerical hard cases and bad input for the engine (real EGL context).

Every render here must produce only finite colour and normals, and depth that is finite or +inf;
the geometric expectation of each case is stated next to it.
"""

from __future__ import annotations

import subprocess
import sys
import threading
from typing import Any

import numpy as np
import pytest

from sphrender.core.errors import InputError
from sphrender.core.frame import make_frame
from sphrender.server.bench.analytic import sphere_hits
from sphrender.server.content.lattice import jittered_lattice_ball
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.engine.geometry.camera import Camera
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import MAX_IMAGE_SIDE, Scene, scene_from_dict

FILTERS = ["narrow_range", "bilateral", "gaussian", "none"]


def scene(**sections: Any) -> Scene:
    base: dict[str, Any] = {
        "image": {"width": 96, "height": 64},
        "camera": {"eye": [0.0, 0.0, 1.0], "target": [0.0, 0.0, 0.0], "fov_y": 45.0, "near": 0.01},
        "particles": {"radius": 0.05},
    }
    for key, value in sections.items():
        base[key] = {**base.get(key, {}), **value}
    return scene_from_dict(base)


def assert_clean(frame: RenderedFrame, environment_background: bool = False) -> None:
    assert np.isfinite(frame.rgba).all()
    alpha = frame.rgba[:, :, 3]
    assert np.all((alpha >= 0.0) & (alpha <= 1.0))
    if frame.depth is not None:
        assert not np.isnan(frame.depth).any()
        assert np.all((frame.depth > 0) | np.isinf(frame.depth))
        covered = np.isfinite(frame.depth)  # a surface at the pixel centre
        # Every such pixel shows it; anti-aliasing adds partial alpha only next to one.
        assert np.all(alpha[covered] > 0.0)
        near = covered.copy()
        for axis in (0, 1):
            for step in (-1, 1):
                near |= np.roll(covered, step, axis=axis)
        near |= np.roll(np.roll(covered, 1, 0), 1, 1) | np.roll(np.roll(covered, -1, 0), -1, 1)
        near |= np.roll(np.roll(covered, 1, 0), -1, 1) | np.roll(np.roll(covered, -1, 0), 1, 1)
        if environment_background:
            assert np.all(alpha == 1.0)
        else:
            assert np.all(alpha[~near] == 0.0)
        if frame.normals is not None:
            assert np.isfinite(frame.normals).all()
            lengths = np.linalg.norm(frame.normals, axis=2)
            assert np.allclose(lengths[covered], 1.0, atol=1e-5)
            assert np.all(lengths[~covered] == 0.0)
    elif frame.normals is not None:
        assert np.isfinite(frame.normals).all()


def render(renderer: SurfaceRenderer, positions: Any, sc: Scene, **arrays: Any) -> RenderedFrame:
    frame, _ = renderer.render(make_frame(positions, **arrays), sc, depth=True, normals=True)
    assert_clean(frame, sc.shading.background == "environment")
    return frame


@pytest.mark.parametrize("filter_name", FILTERS)
def test_zero_particles_is_an_empty_image(renderer: SurfaceRenderer, filter_name: str) -> None:
    frame = render(renderer, np.zeros((0, 3)), scene(quality={"filter": filter_name}))
    assert np.all(frame.rgba == 0.0)
    assert frame.depth is not None and np.all(np.isinf(frame.depth))


@pytest.mark.parametrize("filter_name", FILTERS)
def test_coincident_particles_render_like_one(renderer: SurfaceRenderer, filter_name: str) -> None:
    # Without exact droplets: one particle alone is a droplet (density m W(0) = 0.32 rest < 0.45)
    # and skips the smoothing, 500 coincident ones are not; the splat and filters are tested.
    sc = scene(quality={"filter": filter_name, "exact_droplets": False})
    one = render(renderer, np.zeros((1, 3)), sc)
    many = render(renderer, np.zeros((500, 3)), sc)
    assert one.depth is not None and many.depth is not None
    assert np.array_equal(one.depth, many.depth)


def test_particles_behind_the_camera_are_invisible(renderer: SurfaceRenderer) -> None:
    behind = np.array([[0.0, 0.0, 1.5], [0.1, 0.0, 3.0], [0.0, 0.0, 1.0 + 0.011]])
    frame = render(renderer, behind, scene())
    assert np.all(frame.rgba[:, :, 3] == 0.0)


def test_particle_around_the_eye_is_culled(renderer: SurfaceRenderer) -> None:
    """A sphere containing the eye would cover the image with its inside: it is culled, and the
    particle behind it still renders."""
    frame = render(renderer, np.array([[0.0, 0.0, 0.99], [0.0, 0.0, 0.0]]), scene())
    camera = Camera.from_config(scene().camera, 96, 64)
    covered = frame.rgba[:, :, 3] > 0
    assert 0 < covered.sum() < 0.5 * covered.size
    assert frame.depth is not None
    assert np.nanmin(np.where(covered, frame.depth, np.nan)) > 0.9  # the one at the origin
    assert camera.near < 0.9


@pytest.mark.parametrize("offset", [0.0, 0.02, 0.049, 0.06])
def test_particles_at_and_across_the_near_plane(renderer: SurfaceRenderer, offset: float) -> None:
    """Sphere centres at depth near + offset with r = 0.05: their front is cut by the near plane.
    Fragments nearer than `near` are discarded; nothing is NaN and no sprite is giant: coverage
    stays within the projection of the sphere's silhouette cone. What remains visible is exact:
    the pixels whose ray meets the sphere's front surface at eye depth >= near (a numpy ray
    cast; the same pixel-centre test as the splat, ties within 1e-6 of near left out), so a
    sphere that crosses the near plane is not culled whole. Its silhouette's tangent points lie
    at eye depth d - r^2 / d (d = near + offset): at offset 0.049 (0.132) a ring around the cut
    stays visible; at 0 and 0.02 (0.079, 0.099) the whole front lies nearer than the plane.
    Gap closing off: it would (rightly) close the cut, a hole enclosed by the ring."""
    near = 0.1
    sc = scene(camera={"near": near}, quality={"close_gaps": 0.0})
    z = 1.0 - (near + offset)
    frame = render(renderer, np.array([[0.0, 0.0, z]]), sc)
    assert frame.depth is not None
    covered = np.isfinite(frame.depth)
    assert np.all(frame.depth[covered] >= near * (1 - 1e-6))
    assert np.all(frame.depth[covered] <= near + offset + 0.05 + 1e-6)
    camera = Camera.from_config(sc.camera, sc.image.width, sc.image.height)
    hit, front_depth = sphere_hits(camera, np.array([0.0, 0.0, z]), 0.05)
    visible = hit & (front_depth >= near)
    ties = hit & (np.abs(front_depth - near) < 1e-6)
    assert np.array_equal(covered & ~ties, visible & ~ties)
    depth = near + offset
    assert visible.any() == (depth - 0.05**2 / depth > near)


def test_far_plane_clips(renderer: SurfaceRenderer) -> None:
    sc = scene(camera={"far": 0.5})
    frame = render(renderer, np.array([[0.0, 0.0, 0.0]]), sc)  # at depth 1.0 > far
    assert np.all(frame.rgba[:, :, 3] == 0.0)


@pytest.mark.parametrize("radius", [1e-6, 1e-3, 10.0, 1e3])
def test_tiny_and_huge_radii(renderer: SurfaceRenderer, radius: float) -> None:
    """The camera sits 1 unit from the origin. Tiny spheres cover at most a pixel or so; huge
    ones (eye inside) are culled, so the image is empty; nothing is ever NaN."""
    sc = scene(particles={"radius": radius})
    positions = np.array([[0.0, 0.0, 0.0], [0.1, 0.05, -0.2]])
    frame = render(renderer, positions, sc)
    covered = int((frame.rgba[:, :, 3] > 0).sum())
    if radius < 1e-3:
        assert covered <= 4
    elif radius >= 10.0:
        assert covered == 0


def test_huge_radius_seen_from_outside(renderer: SurfaceRenderer) -> None:
    """Unfiltered, depth equals the analytic ray-sphere hit (front at 5000 - 1000 on the axis) to
    float32 precision of the eye-relative values."""
    sc = scene(
        camera={"eye": [0.0, 0.0, 5000.0], "near": 1.0},
        particles={"radius": 1e3},
        quality={"filter": "none"},
    )
    frame = render(renderer, np.zeros((1, 3)), sc)
    assert frame.depth is not None
    hit, true_depth = sphere_hits(Camera.from_config(sc.camera, 96, 64), np.zeros(3), 1e3)
    assert np.array_equal(np.isfinite(frame.depth), hit)
    assert np.allclose(frame.depth[hit], true_depth[hit], rtol=1e-5)
    assert 4000.0 <= frame.depth.min() < 4001.0


def test_grazing_view_of_a_huge_scene_far_from_origin(renderer: SurfaceRenderer) -> None:
    rng = np.random.default_rng(5)
    positions = rng.normal(size=(2000, 3)) * [1.0, 0.01, 1.0] + 1e5
    sc = scene(
        camera={"eye": [1e5 - 3.0, 1e5 + 0.05, 1e5], "target": [1e5, 1e5, 1e5]},
        particles={"radius": 0.02},
    )
    render(renderer, positions, sc)


def test_image_larger_than_any_limit_is_rejected(renderer: SurfaceRenderer) -> None:
    """Whichever is lower rejects: the configuration's side limit or the driver's GL limit."""
    limit = renderer.max_image_side()
    too_wide = min(limit, MAX_IMAGE_SIDE) + 1
    with pytest.raises(InputError) as info:
        renderer.render(make_frame(np.zeros((1, 3))), scene(image={"width": too_wide}))
    assert info.value.field == "image.width"
    assert str(min(limit, MAX_IMAGE_SIDE)) in info.value.message


def test_gl_context_refuses_other_threads(renderer: SurfaceRenderer) -> None:
    errors: list[BaseException] = []

    def use_from_other_thread() -> None:
        try:
            renderer.render(make_frame(np.zeros((1, 3))), scene())
        except BaseException as exc:
            errors.append(exc)

    thread = threading.Thread(target=use_from_other_thread)
    thread.start()
    thread.join()
    assert len(errors) == 1 and isinstance(errors[0], RuntimeError)
    assert "thread" in str(errors[0])


def test_a_second_context_on_the_owner_thread_is_refused_and_another_thread_may_own_one(
    renderer: SurfaceRenderer,
) -> None:
    """A second standalone context made on a thread that owns one would become current and take
    over the first's calls (and once released leave none: wrong images, a driver crash): it is
    refused before anything is created. A context on another thread is that thread's; made,
    used and released there, it leaves this thread's frames byte for byte as they were."""
    frame = make_frame(jittered_lattice_ball(0.3, 0.05, seed=0))
    before, _ = renderer.render(frame, scene(), depth=True)
    with pytest.raises(RuntimeError, match="already owns a GL context"):
        GLContext()
    done: list[object] = []

    def own_one() -> None:
        try:
            with GLContext() as other:
                worker = SurfaceRenderer(other, stage_timings=False)
                done.append(worker.render(frame, scene())[0].rgba.shape)
                worker.release()
        except BaseException as exc:
            done.append(exc)

    thread = threading.Thread(target=own_one)
    thread.start()
    thread.join()
    assert done == [before.rgba.shape], done
    after, _ = renderer.render(frame, scene(), depth=True)
    assert np.array_equal(after.rgba, before.rgba)
    assert after.depth is not None and before.depth is not None
    assert np.array_equal(after.depth, before.depth)


def test_aovs_are_read_back_only_when_asked(renderer: SurfaceRenderer) -> None:
    frame, stats = renderer.render(make_frame(np.zeros((1, 3))), scene())
    assert frame.depth is None and frame.normals is None
    # No densities and no density pass (the default): no SPH stage, no droplet split.
    assert set(stats.stage_ms) == {"prepare", "splat", "smooth", "normals", "shade", "readback"}
    # With the density pass a lone particle is a droplet: found by SPH, drawn by its own pass.
    _, stats = renderer.render(
        make_frame(np.zeros((1, 3))), scene(quality={"droplet_density_pass": True})
    )
    assert set(stats.stage_ms) == {
        "sph", "prepare", "splat", "smooth", "droplets", "normals", "shade", "readback"
    }  # fmt: skip
    _, stats = renderer.render(make_frame(np.zeros((0, 3))), scene())
    assert "smooth" not in stats.stage_ms  # nothing to smooth


@pytest.mark.parametrize(
    ("arrays", "field"),
    [
        ({"positions": [[0.0, np.nan, 0.0]]}, "positions[0]"),
        ({"positions": [[0.0, 0.0, 0.0], [np.inf, 0.0, 0.0]]}, "positions[1]"),
        ({"positions": [[0.0, 0.0]]}, "positions"),
        ({"positions": np.array([["a", "b", "c"]])}, "positions"),
        ({"positions": [[0.0, 0.0, 0.0]], "radii": [0.0]}, "radii[0]"),
        ({"positions": [[0.0, 0.0, 0.0]], "radii": [-1.0]}, "radii[0]"),
        ({"positions": [[0.0, 0.0, 0.0]], "radii": [1.0, 2.0]}, "radii"),
        ({"positions": [[0.0, 0.0, 0.0]], "densities": [np.nan]}, "densities[0]"),
        ({"positions": [[0.0, 0.0, 0.0]], "temperatures": [-5.0]}, "temperatures[0]"),
    ],
)
def test_bad_particle_arrays_name_the_field(arrays: dict[str, Any], field: str) -> None:
    with pytest.raises(InputError) as info:
        make_frame(**arrays)
    assert info.value.field == field


def test_sprites_larger_than_point_size_limit_are_whole(renderer: SurfaceRenderer) -> None:
    """llvmpipe caps point sprites at 255 px; instanced quads have no cap. A sphere ~560 px
    across must cover exactly its analytic disc."""
    sc = scene(
        image={"width": 800, "height": 640},
        camera={"eye": [0.0, 0.0, 0.3]},
        particles={"radius": 0.1},
        quality={"filter": "none"},
    )
    frame = render(renderer, np.array([[0.02, -0.01, 0.0]]), sc)
    hit, _ = sphere_hits(Camera.from_config(sc.camera, 800, 640), np.array([0.02, -0.01, 0.0]), 0.1)
    assert frame.depth is not None
    covered = np.isfinite(frame.depth)  # surface at the pixel centre (alpha is sub-pixel)
    assert hit.any(axis=0).sum() > 500  # wider than any point sprite could be
    assert np.array_equal(covered, hit)


def test_a_context_whose_release_fails_still_leaves_its_thread_free() -> None:
    """The service's render child rebuilds its context after a GL fault, and a broken context
    may fail to release: the thread must still be free to make the next one. In a child
    process (a context made here would meet the session's); the release really happens, then
    raises as a broken driver's would."""
    script = """
import numpy as np
from sphrender.core.frame import make_frame
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

broken = GLContext()
real_release = broken._ctx.release
def failing_release():
    real_release()
    raise RuntimeError("driver refused")
broken._ctx.release = failing_release
try:
    broken.release()
except RuntimeError as exc:
    assert "driver refused" in str(exc)
else:
    raise AssertionError("the release did not fail")
with GLContext() as fresh:
    renderer = SurfaceRenderer(fresh)
    scene = scene_from_dict({"image": {"width": 32, "height": 24}})
    frame, _ = renderer.render(make_frame(np.zeros((1, 3))), scene)
    assert frame.rgba.shape == (24, 32, 4)
    renderer.release()
print("ok")
"""
    result = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 0 and result.stdout.strip() == "ok", result.stderr
