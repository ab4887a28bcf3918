"""The referee's compiled look at every pair (world/_referee.c) gives what its numpy gives (world.referee.pair_scan):
the smallest distances to the bit, the same pairs inside each other and inside obstacles, the same frozen robots;
with dead robots, robots on top of each other, no obstacle, one robot and none, more robots than one block of
the numpy's rows, and values no run's pose has (NaN, infinite: passed over alike); and it refuses arrays it
cannot read."""

from __future__ import annotations

import math
import os
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from world import referee

# skipped without the compiled scan, except under .ci/run (SWARM_REQUIRE_COMPILED): there its absence fails
pytestmark = [pytest.mark.unit,
              pytest.mark.skipif(referee._referee is None and not os.environ.get("SWARM_REQUIRE_COMPILED"),
                                 reason="the compiled referee is not built here (no C compiler)")]


def test_ci_builds_the_compiled_referee():
    """.ci/run sets SWARM_REQUIRE_COMPILED: there a missing build (it is optional at install) is a failure."""
    if os.environ.get("SWARM_REQUIRE_COMPILED"):
        assert referee._referee is not None


def both(q, r, R, live, obstacles, freezes):
    args = (np.ascontiguousarray(q, float).reshape(-1, 3), np.ascontiguousarray(r, float), np.ascontiguousarray(R, float),
            np.ascontiguousarray(live, bool), np.ascontiguousarray(obstacles, float).reshape(-1, 4), freezes)
    with np.errstate(all="ignore"):  # numpy says so of NaN and overflow; the compiled scan is silent
        py = referee.pair_scan(*args)
    c = referee._referee.pair_scan(*args)
    return py, c


def same(py, c) -> None:
    assert struct.pack("<dd", *py[:2]) == struct.pack("<dd", *c[:2])  # to the bit
    assert sorted(py[2]) == sorted(c[2]) and len(set(c[2])) == len(c[2])
    assert py[3] == c[3]


@st.composite
def swarms(draw):
    n = draw(st.integers(0, 12))
    m = draw(st.integers(0, 4))
    odd = st.sampled_from([math.nan, math.inf, -math.inf, 1e308])  # no run's pose, but the same answer all the same
    coord = st.one_of(st.floats(-3.0, 3.0), st.sampled_from([0.0, -0.0, 0.25, 1e-12]), odd)
    q = [[draw(coord), draw(coord), draw(st.floats(-4.0, 4.0))] for _ in range(n)]
    r = [draw(st.sampled_from([0.0, 0.2, 0.25, 0.5, math.nan])) for _ in range(n)]
    R = [draw(st.sampled_from([0.0, 0.3, 0.5, 1.0, math.nan, math.inf])) for _ in range(n)]
    live = [draw(st.booleans()) for _ in range(n)]
    obstacles = [[draw(coord), draw(coord), draw(st.sampled_from([0.0, 0.3, 1.0])), 0.0] for _ in range(m)]
    return q, r, R, live, obstacles, draw(st.booleans())


@settings(max_examples=400, deadline=None)
@given(swarms())
def test_the_compiled_scan_gives_what_the_numpy_gives(case):
    same(*both(*case))


def test_a_swarm_larger_than_a_block_of_rows_and_its_collisions():
    rng = np.random.default_rng(7)
    n = referee._BLOCK + 44
    q = np.column_stack([rng.uniform(0, 12, n), rng.uniform(0, 12, n), rng.uniform(-3, 3, n)])
    q[5, :2] = q[290, :2] + 0.01  # a pair across two blocks, inside each other
    live = rng.random(n) > 0.1
    obstacles = [[3.0, 3.0, 0.8, 0.0], [9.0, 2.0, 0.5, 0.0]]
    py, c = both(q, np.full(n, 0.2), np.full(n, 0.5), live, obstacles, True)
    same(py, c)
    assert (5, 290) in c[2] and any(j >= n for _i, j in c[2]) and any(c[3])


def test_one_robot_or_none_has_no_pair_distance():
    for n in (0, 1):
        py, c = both(np.zeros((n, 3)), np.full(n, 0.2), np.full(n, 0.5), np.ones(n, bool), [], True)
        same(py, c)
        assert c[0] == np.inf and c[1] == np.inf and c[2] == [] and c[3] == b"\x00" * n


def test_arrays_it_cannot_read_are_refused_not_misread():
    q, r, live = np.zeros((3, 3)), np.full(3, 0.2), np.ones(3, bool)
    none = np.zeros((0, 4))
    scan = referee._referee.pair_scan
    with pytest.raises(TypeError, match="q must be a contiguous array of 'd'"):
        scan(q.astype(np.float32), r, r, live, none, True)
    with pytest.raises(TypeError, match="live must be a contiguous array of '\\?'"):
        scan(q, r, r, live.astype(np.int8), none, True)
    for q_bad in (np.zeros((2, 3)), np.zeros(9), np.zeros((3, 3)).T.copy().reshape(3, 3)[:, :2].copy()):
        with pytest.raises(ValueError, match="q must be n x 3"):
            scan(q_bad, r, r, live, none, True)
    with pytest.raises(ValueError, match="obstacles m x 4"):
        scan(q, r, r, live, np.zeros(8), True)
    with pytest.raises(ValueError, match="contiguous"):  # numpy's own refusal of a buffer it cannot give as asked
        scan(np.zeros((3, 6))[:, ::2], r, r, live, none, True)
    with pytest.raises(TypeError, match="6 arguments"):
        scan(q, r, r, live, none)
