"""The spatial hash grid (swarm.core.grid): neighbours within a radius, exactly and in ascending order."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.core import grid

pytestmark = pytest.mark.unit


def build(xs, ys, side):
    n = len(xs)
    cells = np.zeros((n, 2), np.int64)
    head = np.zeros(grid.table_size(n) + 1, np.int64)
    order = np.zeros(n, np.int64)
    grid.build(xs, ys, n, side, cells, head, order)
    return cells, head, order


def brute(x, y, xs, ys, radius, skip):
    dx = x - xs
    dy = y - ys
    hit = dx * dx + dy * dy < radius * radius
    if skip >= 0:
        hit[skip] = False
    return list(np.nonzero(hit)[0])


def clouds(rng):
    """name -> (xs, ys, side): the point sets every test runs on."""
    side = 1.5
    out = {}
    out["uniform"] = (*rng.uniform(-20.0, 20.0, (2, 400)), side)
    out["negative"] = (*rng.uniform(-60.0, -40.0, (2, 300)), side)
    centres = np.array([[-1e4, 3e3], [0.0, 0.0], [5e3, -7e3], [1e6, 1e6]])
    pts = np.concatenate([c + rng.normal(0.0, 2.0, (80, 2)) for c in centres])
    out["far clusters"] = (pts[:, 0].copy(), pts[:, 1].copy(), side)
    out["one cell"] = (*rng.uniform(0.0, side, (2, 150)), side)
    out["one cell negative"] = (*rng.uniform(-side, 0.0, (2, 150)), side)
    lattice = np.arange(-6, 7) * (side / 2)  # points exactly on cell borders
    gx, gy = np.meshgrid(lattice, lattice)
    out["borders"] = (gx.ravel().copy(), gy.ravel().copy(), side)
    out["small side"] = (*rng.uniform(-3.0, 3.0, (2, 300)), 0.25)
    out["one point"] = (np.array([0.3]), np.array([-0.2]), side)
    return out


CASES = ["uniform", "negative", "far clusters", "one cell", "one cell negative", "borders", "small side", "one point"]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("radius_share", [1.0, 0.7, 0.2])
def test_near_equals_brute_force_for_every_body(case, radius_share):
    rng = np.random.default_rng(12)
    xs, ys, side = clouds(rng)[case]
    cells, head, order = build(xs, ys, side)
    radius = radius_share * side
    out = np.zeros(len(xs), np.int64)
    hits = 0
    for i in range(len(xs)):
        cnt = grid.near(xs[i], ys[i], side, xs, ys, cells, head, order, radius, i, out)
        expected = brute(xs[i], ys[i], xs, ys, radius, i)
        assert list(out[:cnt]) == expected, f"body {i}"
        hits += cnt
    if case != "one point" and not (case == "borders" and radius_share < 0.5):  # lattice pitch: side / 2
        assert hits > 0


@pytest.mark.parametrize("case", CASES)
def test_near_equals_brute_force_for_free_query_points(case):
    rng = np.random.default_rng(13)
    xs, ys, side = clouds(rng)[case]
    cells, head, order = build(xs, ys, side)
    out = np.zeros(len(xs), np.int64)
    # query points near the bodies, and exactly on some of them (skip = -1 keeps them)
    qx = np.concatenate([xs[:50] + rng.normal(0, side, min(50, len(xs))), xs[:5]])
    qy = np.concatenate([ys[:50] + rng.normal(0, side, min(50, len(ys))), ys[:5]])
    for x, y in zip(qx, qy):
        cnt = grid.near(x, y, side, xs, ys, cells, head, order, side, -1, out)
        assert list(out[:cnt]) == brute(x, y, xs, ys, side, -1)
    for j in range(min(5, len(xs))):
        cnt = grid.near(xs[j], ys[j], side, xs, ys, cells, head, order, side, -1, out)
        assert j in list(out[:cnt])


def test_build_groups_bodies_by_bucket_in_ascending_id():
    rng = np.random.default_rng(14)
    xs, ys = rng.uniform(-30, 30, (2, 500))
    side = 1.5
    cells, head, order = build(xs, ys, side)
    assert_cells = np.column_stack([np.floor(xs / side), np.floor(ys / side)]).astype(np.int64)
    assert (cells == assert_cells).all()
    assert head[0] == 0 and head[-1] == len(xs)
    assert (np.diff(head) >= 0).all()
    assert sorted(order) == list(range(len(xs)))
    mask = len(head) - 2
    for b in range(len(head) - 1):
        members = order[head[b]:head[b + 1]]
        assert list(members) == sorted(members)
        for j in members:
            assert grid.bucket(int(cells[j, 0]), int(cells[j, 1]), mask) == b


def test_near_after_rebuild_with_moved_points():
    rng = np.random.default_rng(15)
    xs, ys = rng.uniform(-10, 10, (2, 200))
    side = 1.5
    out = np.zeros(200, np.int64)
    for _ in range(5):
        xs = xs + rng.normal(0, 0.5, 200)
        ys = ys + rng.normal(0, 0.5, 200)
        cells, head, order = build(xs, ys, side)
        for i in range(0, 200, 7):
            cnt = grid.near(xs[i], ys[i], side, xs, ys, cells, head, order, side, i, out)
            assert list(out[:cnt]) == brute(xs[i], ys[i], xs, ys, side, i)


@pytest.mark.parametrize("n, size", [(0, 16), (1, 16), (8, 16), (9, 32), (16, 32), (17, 64), (37, 128), (1000, 2048)])
def test_table_size_is_a_power_of_two_at_least_twice_n(n, size):
    assert grid.table_size(n) == size


def test_update_sorts_only_when_a_body_changed_cell_and_equals_build():
    """update() equals build() after every move, those that change no cell (no sort) and those that do."""
    rng = np.random.default_rng(16)
    n, side = 120, 1.5
    xs, ys = rng.uniform(-10, 10, (2, n))
    cells = np.zeros((n, 2), np.int64)
    head = np.zeros(grid.table_size(n) + 1, np.int64)
    order = np.zeros(n, np.int64)
    grid.update(xs, ys, n, side, cells, head, order)  # a new grid: always sorted
    sorts = 0
    for step in range(40):
        scale = 0.3 if step % 2 else 1e-4  # every other step a move too small to change any cell (mostly)
        xs = xs + rng.normal(0, scale, n)
        ys = ys + rng.normal(0, scale, n)
        moved = (np.floor(xs / side) != cells[:, 0]) | (np.floor(ys / side) != cells[:, 1])
        grid.update(xs, ys, n, side, cells, head, order)
        want = build(xs, ys, side)
        assert (cells == want[0]).all() and (head == want[1]).all() and (order == want[2]).all()
        sorts += int(moved.any())
    assert 0 < sorts < 40
