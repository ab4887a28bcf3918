"""Exact unicycle steps, the leader's segments and compensated sums (swarm.core.kinematics)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from swarm.core import kinematics
from swarm.core.scenario import Leader, Segment

pytestmark = pytest.mark.unit


def rk4_unicycle(x, y, th, v, w, duration, substeps):
    """Integrate q' = (v cos th, v sin th, w) with classical RK4."""
    h = duration / substeps

    def f(q):
        return np.array([v * math.cos(q[2]), v * math.sin(q[2]), w])

    q = np.array([x, y, th], float)
    for _ in range(substeps):
        k1 = f(q)
        k2 = f(q + 0.5 * h * k1)
        k3 = f(q + 0.5 * h * k2)
        k4 = f(q + h * k3)
        q = q + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return q


@pytest.mark.parametrize("a", [0.0, 1e-12, -1e-9, 1e-4, 9.999e-4, 1e-3, 1.0001e-3, -0.02, 0.5, 1.5, -3.0, 10.0])
def test_sinc(a):
    expected = 1.0 if a == 0.0 else math.sin(a) / a
    assert_allclose(kinematics.sinc(a), expected, rtol=1e-15)


@pytest.mark.parametrize(
    "v, w",
    [(0.5, 0.0), (0.5, 1e-9), (0.5, -1e-9), (0.5, 1e-6), (1.0, 0.7), (-0.3, 2.0), (0.0, 1.0), (2.0, -3.0),
     (0.5, 0.0982)],
)
@pytest.mark.parametrize("dt", [0.01, 0.5, 2.0])
def test_arc_displacement_matches_a_fine_integration(v, w, dt):
    rng = np.random.default_rng(10)
    for th in list(rng.uniform(-math.pi, math.pi, 2)) + [0.0, 7.5]:
        dx, dy, dth = kinematics.arc_displacement(th, v, w, dt)
        q = rk4_unicycle(0.0, 0.0, th, v, w, dt, 50 + int(600 * dt))  # RK4 error ~1e-13 here
        assert_allclose([dx, dy, dth], q - [0.0, 0.0, th], rtol=0, atol=1e-12 + 1e-12 * abs(v) * dt)


def test_arc_displacement_closes_a_full_circle():
    v, w = 0.5, 0.25
    period = 2 * math.pi / w
    dx, dy, dth = kinematics.arc_displacement(0.3, v, w, period)
    assert_allclose([dx, dy], [0.0, 0.0], atol=1e-14)
    assert_allclose(dth, 2 * math.pi, rtol=1e-15)
    # half a circle: the diameter 2 v / w, perpendicular-left of the start heading
    dx, dy, _ = kinematics.arc_displacement(0.0, v, w, period / 2)
    assert_allclose([dx, dy], [0.0, 2 * v / w], atol=1e-14)


def test_step_pose_accumulates_exact_arcs():
    q = np.array([50.0, -20.0, 0.4])
    c = np.zeros(3)
    v, w, dt, steps = 0.5, 0.05, 0.01, 20000
    for _ in range(steps):
        kinematics.step_pose(q, c, v, w, dt)
    dx, dy, dth = kinematics.arc_displacement(0.4, v, w, steps * dt)
    assert_allclose(q, [50.0 + dx, -20.0 + dy, 0.4 + dth], rtol=0, atol=1e-12)


def test_kahan_add_keeps_long_sums_exact():
    s, c = 50.0, 0.0
    plain = 50.0
    for _ in range(100_000):
        s, c = kinematics.kahan_add(s, c, 1e-3)
        plain += 1e-3
    assert_allclose(s, 150.0, rtol=0, atol=1e-12)
    assert abs(plain - 150.0) > 1e-11  # what the compensation is for


def test_step_pose_stays_exact_far_from_the_origin():
    q = np.array([50.0, 0.0, 0.0])
    c = np.zeros(3)
    for _ in range(100_000):
        kinematics.step_pose(q, c, 0.1, 0.0, 0.01)
    assert_allclose(q, [50.0 + 100_000 * 0.1 * 0.01, 0.0, 0.0], rtol=0, atol=1e-12)


SEGMENTS = [(10.0, 0.5, 0.0), (16.0, 0.5, math.pi / 32), (8.0, 0.5, 0.0), (16.0, 0.5, -math.pi / 32),
            (3.5, -0.2, 1.0), (2.25, 0.0, 0.0)]


def _leader(start=(1.0, -2.0, 0.3), segments=SEGMENTS):
    return Leader(start, tuple(Segment(*s) for s in segments))


def test_leader_table_chains_start_poses():
    leader = _leader()
    table = leader.table()
    assert table.shape == (len(SEGMENTS), 6)
    assert_allclose(table[:, kinematics.SEG_T0], np.cumsum([0.0] + [s[0] for s in SEGMENTS[:-1]]))
    assert_allclose(table[:, kinematics.SEG_V], [s[1] for s in SEGMENTS])
    assert_allclose(table[:, kinematics.SEG_W], [s[2] for s in SEGMENTS])
    assert tuple(table[0, 1:4]) == (1.0, -2.0, 0.3)


def test_leader_state_is_continuous_at_segment_switches():
    leader = _leader()
    table = leader.table()
    for k in range(1, len(SEGMENTS)):
        ts = table[k, kinematics.SEG_T0]
        before = np.array(kinematics.leader_state(table, np.nextafter(ts, 0.0))[:3])
        at = np.array(kinematics.leader_state(table, ts)[:3])
        assert_allclose(at, table[k, 1:4], rtol=0, atol=1e-15)
        assert_allclose(before, at, rtol=0, atol=1e-13)
        # and the velocities switch to the new segment's exactly at its start
        assert kinematics.leader_state(table, ts)[3:] == (SEGMENTS[k][1], SEGMENTS[k][2])
        assert kinematics.leader_state(table, np.nextafter(ts, 0.0))[3:] == (SEGMENTS[k - 1][1], SEGMENTS[k - 1][2])


def test_leader_state_equals_integrating_the_segments():
    start = (1.0, -2.0, 0.3)
    leader = _leader(start)
    table = leader.table()
    q = np.array(start, float)
    t = 0.0
    checkpoints = []
    for duration, v, w in SEGMENTS + [(7.0, SEGMENTS[-1][1], SEGMENTS[-1][2])]:  # the last one continues
        for part in range(2):  # a checkpoint inside the segment and at its end
            q = rk4_unicycle(*q, v, w, duration / 2, 1000)
            t += duration / 2
            checkpoints.append((t, q.copy()))
    for t, q in checkpoints:
        got = kinematics.leader_state(table, t)
        assert_allclose(got[:3], q, rtol=0, atol=1e-10, err_msg=f"t = {t}")
        assert got[:3] == leader.state(t)[:3]


def test_leader_keeps_the_last_segment_forever():
    leader = _leader(segments=[(2.0, 0.5, 0.0), (3.0, 0.4, 0.2)])
    table = leader.table()
    x0, y0, th0 = table[1, 1:4]
    for t in (5.0, 10.0, 1000.0):
        dx, dy, dth = kinematics.arc_displacement(th0, 0.4, 0.2, t - 2.0)
        assert_allclose(kinematics.leader_state(table, t), (x0 + dx, y0 + dy, th0 + dth, 0.4, 0.2), atol=1e-12)
