"""The dam-frame figures against the union of the particle spheres
(benchmarks/studies/sphere_union.py) on cases whose answers are known: a sphere's projected
area, lone particles, edge pixels by class, and the droplets' normal error."""

from __future__ import annotations

import math

import numpy as np

from benchmarks.studies.sphere_union import (
    droplet_error_deg,
    edge_alpha,
    edge_classes,
    gap_coverage,
    lone_particles,
    sphere_union,
)
from sphrender.server.engine.frame_output import RenderedFrame
from sphrender.server.scene import CameraConfig

CONFIG = CameraConfig(eye=(0.0, 0.0, 1.0), target=(0.0, 0.0, 0.0), fov_y=40.0)
SIZE = 64


def test_lone_particles_have_no_other_within_the_support() -> None:
    points = np.array(
        [[0.0, 0.0, 0.0], [0.03, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0, 0], [2.0, 0, 0]]
    )
    # a pair 0.03 apart, one alone, a coincident pair (not lone: the other is at distance 0)
    assert lone_particles(points, 0.04).tolist() == [False, False, True, False, False]
    assert lone_particles(points[:2], 0.02).tolist() == [True, True]
    assert lone_particles(points[:1], 0.04).tolist() == [True]


def test_the_coverage_of_a_sphere_adds_up_to_its_projected_disc() -> None:
    """A sphere of radius r at distance d on the axis projects to a disc of radius
    f r / sqrt(d^2 - r^2) pixels (f = focal length in pixels). Its 4 x 4 supersampled coverage
    sums to that area up to the sub-samples cut by the rim: at most half a sub-sample row per
    rim pixel if they all erred one way (113 rim pixels x 1/8 px = 1.4 % here); they do not,
    so 0.5 % holds with room."""
    r = 0.2
    union = sphere_union(CONFIG, SIZE, SIZE, np.zeros((1, 3)), r, 4 * r)
    focal = (SIZE / 2) / math.tan(math.radians(20.0))
    disc = math.pi * (focal * r / math.sqrt(1.0 - r * r)) ** 2
    assert abs(union.coverage.sum() - disc) < 0.005 * disc, (union.coverage.sum(), disc)
    # a lone particle: every pixel it covers at its centre is a droplet pixel
    assert np.array_equal(union.droplet, union.truth.hit)
    assert union.droplet.sum() > 0.9 * disc


def test_only_the_lone_particles_pixels_are_droplets() -> None:
    pair = np.array([[-0.3, 0.0, 0.0], [-0.26, 0.0, 0.0]])
    lone = np.array([[0.3, 0.0, 0.0]])
    union = sphere_union(CONFIG, SIZE, SIZE, np.concatenate([pair, lone]), 0.03, 0.12)
    columns = np.nonzero(union.droplet.any(axis=0))[0]
    assert len(columns) > 0 and columns.min() > SIZE // 2  # the right-hand sphere only
    assert union.truth.hit[:, : SIZE // 2].any()  # the pair is drawn, just not a droplet


def test_edge_pixels_split_into_silhouettes_and_gaps_the_reference_covers() -> None:
    coverage = np.ones((7, 9))
    coverage[:, :2] = 0.0  # background on the left ...
    coverage[:, 2] = 0.5  # ... its silhouette
    coverage[3, 6] = 0.6  # a gap between spheres that no pixel sees through
    coverage[5, 5:8] = 0.7
    coverage[6, 6] = 0.0  # a gap the union leaves a pixel empty in, but the reference covers
    reference = np.ones_like(coverage)
    reference[:, :2] = 0.0
    silhouettes, gaps = edge_classes(coverage, reference)
    assert silhouettes.sum() == 7 and silhouettes[:, 2].all()
    assert gaps.sum() == 4 and gaps[3, 6] and gaps[5, 5:8].all()
    alpha = coverage.copy()
    alpha[3, 6] = alpha[6, 6] = 1.0  # the gaps drawn closed
    alpha[5, 5:8] = 1.0
    alpha[:, 2] = 0.6  # the silhouette 0.1 off
    result = edge_alpha(alpha, coverage, reference)
    assert math.isclose(result.silhouettes, 0.1)
    assert math.isclose(result.all, (7 * 0.1 + 0.4 + 3 * 0.3) / 11)
    assert math.isclose(result.gap_share, 4 / 11)
    seen = gap_coverage(alpha, coverage, reference)
    assert math.isclose(seen.spheres, (0.6 + 3 * 0.7) / 4)
    assert (seen.alpha, seen.reference) == (1.0, 1.0)
    # where the reference leaves the gap's empty pixel empty too, it is background
    reference[6, 6] = 0.0
    silhouettes, gaps = edge_classes(coverage, reference)
    assert silhouettes[5, 5:8].all() and gaps.sum() == 1
    # a pixel at the image's end is no silhouette of background beyond it
    assert not edge_classes(np.full((3, 3), 0.5), np.zeros((3, 3)))[0].any()
    assert math.isnan(gap_coverage(alpha, np.ones((7, 9)), reference).alpha)


def test_the_droplet_error_is_the_angle_to_the_spheres_normal() -> None:
    union = sphere_union(CONFIG, SIZE, SIZE, np.zeros((1, 3)), 0.2, 0.8)
    depth = np.where(union.truth.hit, union.truth.depth, np.inf).astype(np.float32)
    rgba = np.zeros((SIZE, SIZE, 4), np.float32)
    exact = RenderedFrame(rgba, depth, union.truth.normals.astype(np.float32))
    assert droplet_error_deg(exact, union) < 0.01  # float32 rounding
    flipped = RenderedFrame(rgba, depth, (-union.truth.normals).astype(np.float32))
    assert abs(droplet_error_deg(flipped, union) - 180.0) < 0.1
    nothing = RenderedFrame(rgba, np.full((SIZE, SIZE), np.inf, np.float32), exact.normals)
    assert math.isnan(droplet_error_deg(nothing, union))
