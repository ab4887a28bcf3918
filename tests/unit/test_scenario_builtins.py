"""The built-in scenarios (docs/scenarios.md) and the generators they and scenario files use: hexagonal
patches, obstacle rows, random starts."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from swarm.core import generators
from swarm.core import scenario_file as sf

pytestmark = pytest.mark.unit

# --------------------------------------------------------------------------- built-ins


def test_builtins_share_one_geometry():
    paper, fast = sf.load("paper"), sf.load("paper-50hz")
    assert paper.n == fast.n == 37
    assert (paper.dt, paper.control.governor) == (0.001, False)
    assert (fast.dt, fast.control.governor) == (0.02, True)
    assert (paper.poses == fast.poses).all() and (paper.offsets == fast.offsets).all()
    assert (paper.obstacles == fast.obstacles).all()
    assert paper.duration == fast.duration == 120.0
    assert (paper.control.k1, paper.control.k2, paper.control.k3, paper.control.tu) == (0.5, 0.5, 1.0, 1.0)
    assert (paper.r, paper.R) == (0.3, 1.2)


@pytest.mark.parametrize("name", sf.BUILTINS)
@pytest.mark.parametrize("n", [1, 7, 19, 37, 61, 10])
def test_builtins_resize_with_robots(name, n):
    scn = sf.load(name, sf.Overrides(robots=n, seed=1))
    assert scn.n == n and scn.offsets.shape == (n, 2)
    s = 0.5 if name == "turtlebot3" else 1.0  # turtlebot3: every length halved
    hexagon = generators.hex_patch(n, 1.5 * s)
    assert sorted(map(tuple, np.round(scn.offsets, 12))) == sorted(map(tuple, np.round(hexagon, 12)))
    # the barrier: one row 2.6 m below the lowest slot, 1.6 m pitch
    lowest = scn.offsets[:, 1].min()
    assert_allclose(scn.obstacles[:, 1], lowest - 2.6 * s, atol=1e-12)
    assert_allclose(np.diff(scn.obstacles[:, 0]), 1.6 * s, rtol=1e-9)
    assert_allclose(scn.obstacles[:, 0].mean(), 4.7 * s, atol=1e-9)
    # starts: a 9 m^2-per-robot rectangle, aspect 2.8:1, centred on x = 5, top 1.5 m below the barrier
    width = math.sqrt(9.0 * n * 2.8) * s
    height = 9.0 * n * s * s / width
    top = lowest - (2.6 + 1.5) * s
    assert (np.abs(scn.poses[:, 0] - 5.0 * s) <= width / 2).all()
    assert (scn.poses[:, 1] <= top).all() and (scn.poses[:, 1] >= top - height).all()
    xmin, xmax, ymin, ymax = sf.builtin_document(name, n)["robots"]["random"]["region"]
    assert_allclose((xmax - xmin) * (ymax - ymin), 9.0 * n * s * s, rtol=1e-12)
    assert_allclose([xmin, xmax, ymax], [5.0 * s - width / 2, 5.0 * s + width / 2, top], atol=1e-12)
    # the barrier spans the start rectangle with room on both sides
    assert scn.obstacles[:, 0].min() < xmin - 3.5 * s and scn.obstacles[:, 0].max() > xmax + 3.5 * s
    assert (np.abs(scn.poses[:, 2]) <= math.pi).all()


def test_paper_default_has_37_robots_and_a_barrier():
    scn = sf.load("paper")
    assert scn.n == 37
    assert_allclose(scn.obstacles[:, 1], scn.offsets[:, 1].min() - 2.6, atol=1e-12)
    assert (scn.poses[:, 1] < scn.obstacles[0, 1]).all()


# --------------------------------------------------------------------------- generators


@pytest.mark.parametrize("count, rings", [(1, 0), (7, 1), (19, 2), (37, 3), (61, 4), (91, 5)])
@pytest.mark.parametrize("spacing", [1.5, 2.0])
def test_hex_patch_full_rings(count, rings, spacing):
    pts = generators.hex_patch(count, spacing)
    assert pts.shape == (count, 2)
    assert tuple(pts[0]) == (0.0, 0.0)
    assert_allclose(pts.mean(axis=0), [0.0, 0.0], atol=1e-12)
    assert_allclose(np.hypot(pts[:, 0], pts[:, 1]).max(), rings * spacing, rtol=1e-12)
    if count > 1:
        d = np.hypot(*(pts[:, None] - pts[None, :]).transpose(2, 0, 1))
        d[np.diag_indices(count)] = np.inf
        assert_allclose(d.min(), spacing, rtol=1e-12)
        # every point has its nearest neighbour at exactly one spacing: a lattice patch
        assert_allclose(d.min(axis=1), spacing, rtol=1e-12)
        # horizontal rows
        rows = np.round(pts[:, 1] / (spacing * math.sqrt(3) / 2), 9)
        assert_allclose(rows, np.round(rows), atol=1e-9)


@pytest.mark.parametrize("count", [2, 5, 10, 20, 40])
def test_hex_patch_partial_rings_are_distinct_and_spaced(count):
    pts = generators.hex_patch(count, 1.5)
    assert pts.shape == (count, 2)
    full = generators.hex_patch(91, 1.5)
    assert (pts == full[:count]).all()  # grows point by point
    d = np.hypot(*(pts[:, None] - pts[None, :]).transpose(2, 0, 1))
    d[np.diag_indices(count)] = np.inf
    assert_allclose(d.min(), 1.5, rtol=1e-12)


def test_hex_patch_refuses_zero():
    with pytest.raises(generators.GeneratorError):
        generators.hex_patch(0, 1.5)


@pytest.mark.parametrize(
    "start, end, pitch, count",
    [((0.0, 0.0), (10.0, 0.0), 3.0, 4), ((0.0, 0.0), (9.6, 0.0), 1.6, 7), ((-5.0, 2.0), (5.0, -2.0), 1.0, 12),
     ((1.0, 1.0), (1.0, 1.0), 1.0, 1), ((0.0, 0.0), (0.5, 0.0), 2.0, 2)],
)
def test_obstacle_row(start, end, pitch, count):
    pts = generators.obstacle_row(start, end, pitch)
    assert pts.shape == (count, 2)
    assert_allclose(pts[0], start, atol=1e-12)
    assert_allclose(pts[-1], end, atol=1e-12)
    if count > 1:
        steps = np.hypot(*np.diff(pts, axis=0).T)
        assert_allclose(steps, steps[0], rtol=1e-9)
        length = math.dist(start, end)
        assert abs(steps[0] - pitch) <= pitch / 2 or length < pitch


def test_random_poses_respect_region_separation_and_clearance():
    obstacles = np.array([[0.0, 0.0, 0.3, 1.2], [3.0, 3.0, 0.3, 1.2]])
    region = (-5.0, 5.0, -4.0, 6.0)
    poses = generators.random_poses(np.random.default_rng(17), 30, region, 0.9, obstacles, 1.2)
    assert poses.shape == (30, 3)
    assert (poses[:, 0] >= -5).all() and (poses[:, 0] <= 5).all()
    assert (poses[:, 1] >= -4).all() and (poses[:, 1] <= 6).all()
    assert (poses[:, 2] > -math.pi).all() and (poses[:, 2] <= math.pi).all()
    d = np.hypot(*(poses[:, None, :2] - poses[None, :, :2]).transpose(2, 0, 1))
    d[np.diag_indices(30)] = np.inf
    assert d.min() >= 0.9
    do = np.hypot(*(poses[:, None, :2] - obstacles[None, :, :2]).transpose(2, 0, 1))
    assert do.min() >= 1.2
    again = generators.random_poses(np.random.default_rng(17), 30, region, 0.9, obstacles, 1.2)
    assert (again == poses).all()
    other = generators.random_poses(np.random.default_rng(18), 30, region, 0.9, obstacles, 1.2)
    assert not np.allclose(other, poses)


def test_random_poses_gives_up_when_there_is_no_room():
    with pytest.raises(generators.GeneratorError, match="larger"):
        generators.random_poses(np.random.default_rng(19), 50, (0.0, 1.0, 0.0, 1.0), 0.8, np.empty((0, 4)), 1.2,
                                max_tries=5000)
