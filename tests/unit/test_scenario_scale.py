"""Building and checking a scenario is O(N log N) and resolves to the very numbers it always did.

The closest-pair checks and the random generator search grids instead of all pairs; these
tests hold the grids to the all-pairs answers, the generator to its all-pairs original draw for draw,
the built-in scenarios to their recorded text, and count the pair checks at 20 000 robots.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from swarm.core import generators, geometry
from swarm.core import scenario_file as sf

pytestmark = pytest.mark.unit


def all_pairs_closest(points: np.ndarray, within: float):
    """The reference: every pair, the first smallest in (i, j) order."""
    n = len(points)
    d2 = np.sum((points[:, None, :] - points[None, :, :]) ** 2, axis=2)
    d2[np.diag_indices(n)] = np.inf
    i, j = divmod(int(np.argmin(d2)), n)
    i, j = sorted((i, j))
    d = math.sqrt(d2[i, j])
    return (i, j, d) if d <= within else None


def point_sets(rng):
    """Spread, lattice (many ties), a 1e-7 m cluster (crowded cells), duplicates, a line."""
    for n in (2, 3, 50, 400):
        yield rng.uniform(-50.0, 50.0, (n, 2))
        yield np.round(rng.uniform(-3.0, 3.0, (n, 2)) * 4.0) / 4.0
        yield 3.0 + rng.uniform(0.0, 1e-7, (n, 2))
        pts = rng.uniform(0.0, 10.0, (n, 2))
        pts[n // 2] = pts[0]
        yield pts
        yield np.column_stack([np.linspace(0.0, 1.0, n), np.zeros(n)])


@pytest.mark.parametrize("within", [1e-9, 0.1, 0.3, 1.2, 5.0])
def test_closest_pair_equals_the_all_pairs_search(within):
    rng = np.random.default_rng(int(within * 1e9) % 2**32)
    for pts in point_sets(rng):
        assert geometry.closest_pair(pts, within) == all_pairs_closest(pts, within)


@pytest.mark.parametrize("within", [0.2, 1.0, 3.0])
def test_grid_pairs_are_exactly_the_pairs_within(within):
    rng = np.random.default_rng(7)
    for pts in point_sets(rng):
        others = rng.uniform(-5.0, 5.0, (37, 2))
        for b, same in ((None, True), (others, False)):
            grid = geometry.Grid(pts if same else b, within)
            i, j, d2 = grid.pairs(pts, within, same=same)
            ref = np.sum((pts[:, None, :] - (pts if same else b)[None, :, :]) ** 2, axis=2)
            want = ref <= within * within
            if same:
                want &= np.triu(np.ones_like(want), 1).astype(bool)
            assert sorted(zip(i.tolist(), j.tolist())) == sorted(zip(*map(np.ndarray.tolist, np.nonzero(want))))
            assert (d2 == ref[i, j]).all()


def old_random_poses(rng, count, region, min_separation, obstacles, obstacle_clearance, max_tries=200_000):
    """The generator as it was before the grid (all placed robots tested at every draw), for reference."""
    xmin, xmax, ymin, ymax = region
    placed = np.empty((count, 2))
    n = tries = 0
    centres = np.asarray(obstacles, float)[:, :2] if len(obstacles) else np.empty((0, 2))
    while n < count:
        if tries >= max_tries:
            raise generators.GeneratorError("no room")
        tries += 1
        p = np.array([rng.uniform(xmin, xmax), rng.uniform(ymin, ymax)])
        if n and np.min(np.sum((placed[:n] - p) ** 2, axis=1)) < min_separation**2:
            continue
        if len(centres) and np.min(np.sum((centres - p) ** 2, axis=1)) < obstacle_clearance**2:
            continue
        placed[n] = p
        n += 1
    headings = -rng.uniform(-math.pi, math.pi, size=count)
    return np.column_stack([placed, headings])


def test_random_poses_draw_what_the_all_pairs_generator_drew():
    rng = np.random.default_rng(2024)
    for _ in range(60):
        seed, count = int(rng.integers(0, 2**31)), int(rng.integers(1, 250))
        x0, y0, w, h = rng.uniform(-100, 100), rng.uniform(-100, 100), rng.uniform(2, 40), rng.uniform(2, 40)
        region = (x0, x0 + w, y0, y0 + h)
        m = int(rng.integers(0, 40))
        obstacles = np.column_stack([rng.uniform(x0, x0 + w, m), rng.uniform(y0, y0 + h, m), np.full((m, 2), 0.3)])
        sep, clearance = float(rng.choice([0.0, 0.3, 0.8, 1.5])), float(rng.choice([0.0, 1.2, 2.0]))
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        try:
            want = old_random_poses(a, count, region, sep, obstacles, clearance, max_tries=2000)
        except generators.GeneratorError:
            with pytest.raises(generators.GeneratorError):
                generators.random_poses(b, count, region, sep, obstacles, clearance, max_tries=2000)
            continue
        got = generators.random_poses(b, count, region, sep, obstacles, clearance, max_tries=2000)
        assert (got == want).all()
        assert a.random() == b.random()  # the same draws consumed: what follows (the assignment) is unchanged


# sha256 of `swarm scenario show NAME --robots N [--seed S]` as written before the grids
RECORDED = {
    ("paper-50hz", 37, None): "755045f23b28dee7e190a665e2dc940e02b5e6ea10a0f109b84cc0e89281c344",
    ("paper", 100, None): "a74db70f502a65acc9872e72c44a8c981c39d3f839ad64b1c54f84346542981c",
    ("paper-50hz", 1000, None): "56f4a8e131283342d665ecacdc1b83ffba38154419af04d508fe462c3195960a",
    ("paper-50hz", 37, 5): "1c89998b2a68b68bcf9cacbf37489425e48be8c26693a61d3057bcce3ac29de3",
}


@pytest.mark.parametrize("name, n, seed", list(RECORDED))
def test_builtins_resolve_to_the_recorded_numbers(name, n, seed):
    text = sf.to_toml(sf.load(name, sf.Overrides(robots=n, seed=seed), progress=sf.silent))
    assert hashlib.sha256(text.encode()).hexdigest() == RECORDED[(name, n, seed)]


def test_the_pair_checks_stay_linear_at_20000_robots():
    """Every search of building and checking paper-50hz at 20 000 robots, counted: O(N), not N^2 / 2 = 2e8."""
    n = 20_000
    counter = geometry.Counter()
    scn = sf.load("paper-50hz", sf.Overrides(robots=n), progress=sf.silent, counter=counter)
    sf.advisories(scn, counter)
    assert scn.n == n
    assert 0 < counter.pairs < 50 * n, counter.pairs


def test_crowded_points_do_not_make_the_search_quadratic():
    """20 000 points within 1e-6 m (all in one cell of the 0.3 m check): the cells shrink instead."""
    pts = np.random.default_rng(3).uniform(0.0, 1e-6, (20_000, 2))
    counter = geometry.Counter()
    i, j, d = geometry.closest_pair(pts, 0.3, counter)
    assert d < 1e-8 and counter.pairs < 50 * len(pts), counter.pairs
