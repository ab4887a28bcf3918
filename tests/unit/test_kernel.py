"""The compiled batched simulator (swarm.core.kernel via swarm.core.sim) against the plain single-robot law.

The reference below is the robot agent's view of one tick, written out by hand: for each
robot, its known bodies by brute force (closer than the cell side; robots by ascending
id, then obstacles by ascending index), the plain-Python swarm.core.law.robot_command, then
every robot moves one exact arc with swarm.core.kinematics.step_pose.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from swarm.core import kinematics, law
from swarm.core import scenario_file as sf
from swarm.core.scenario import Control, Scenario
from swarm.core.sim import Simulation

pytestmark = pytest.mark.unit


class Reference:
    """A pure-Python, one-robot-at-a-time simulation of a scenario."""

    def __init__(self, scn: Scenario):
        n = scn.n
        self.scn = scn
        self.q = np.array(scn.poses, float)
        self.comp = np.zeros((n, 3))
        self.mem = np.zeros((n, law.M_SIZE))
        self.mem[:, law.M_SCALE] = 1.0
        self.cmd = np.zeros((n, 2))
        self.p = scn.params()
        self.table = scn.leader.table()
        self.k = 0
        self.governed = 0
        self.frozen_steps = 0

    def neighbours(self, i):
        scn, q = self.scn, self.q
        side2 = scn.cell_side * scn.cell_side
        rows = []
        for j in range(scn.n):
            dx, dy = q[i, 0] - q[j, 0], q[i, 1] - q[j, 1]
            if j != i and dx * dx + dy * dy < side2:
                rows.append((q[j, 0], q[j, 1], scn.r, scn.R, law.KIND_ROBOT))
        for x, y, r, R in scn.obstacles:
            dx, dy = q[i, 0] - x, q[i, 1] - y
            if dx * dx + dy * dy < side2:
                rows.append((x, y, r, R, law.KIND_OBSTACLE))
        size = scn.n + len(scn.obstacles)
        nx, ny, nr, nR = (np.zeros(size) for _ in range(4))
        nk = np.zeros(size, np.int64)
        for a, row in enumerate(rows):
            nx[a], ny[a], nr[a], nR[a], nk[a] = row
        return nx, ny, nr, nR, nk, np.zeros(size), len(rows)

    def advance(self, steps):
        scn = self.scn
        for _ in range(steps):
            t = self.k * scn.dt
            xl, yl, thl, vl, wl = kinematics.leader_state(self.table, t)
            for i in range(scn.n):
                x, y, th = self.q[i]
                ox, oy = scn.offsets[i]
                self.cmd[i] = law.robot_command(x, y, th, ox, oy, scn.r, t, xl, yl, thl, vl, wl,
                                                *self.neighbours(i), self.mem[i], self.p)
                self.governed += self.mem[i, law.M_SCALE] < 1.0
                self.frozen_steps += self.mem[i, law.M_FROZEN] != 0.0
            for i in range(scn.n):
                kinematics.step_pose(self.q[i], self.comp[i], self.cmd[i, 0], self.cmd[i, 1], scn.dt)
            self.k += 1


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "overrides, steps, governed",
    [
        (sf.Overrides(robots=7, seed=3), 200, False),
        (sf.Overrides(robots=7, seed=4), 1500, True),  # 30 s at 50 Hz: the governor acts
        (sf.Overrides(robots=7, seed=3, governor=False, dt=0.001), 200, False),
        (sf.Overrides(robots=7, seed=5, governor=False, dt=0.001), 2500, False),
    ],
)
@pytest.mark.parametrize("threads", [1, 3])  # 3: the parallel kernel, blocks of 2, 2 and 3 robots
def test_batched_simulation_equals_the_single_robot_law(overrides, steps, governed, threads):
    scn = sf.load("paper-50hz", overrides)
    assert len(scn.obstacles) > 0
    sim = Simulation(scn, threads=threads)
    ref = Reference(scn)
    done = 0
    for chunk in (1, steps // 3, steps - 1 - steps // 3):  # uneven chunks: the state carries over
        sim.advance(done + chunk)
        ref.advance(chunk)
        done += chunk
        assert sim.next_k == done
        assert_allclose(sim.q, ref.q, rtol=0, atol=1e-12)
        assert_allclose(sim.mem, ref.mem, rtol=0, atol=1e-12)
        assert_allclose(sim.cmd, ref.cmd, rtol=0, atol=1e-12)
    assert ref.frozen_steps > 0  # the freeze rule was exercised
    assert (ref.governed > 0) == governed
    # the robots did move
    assert np.max(np.hypot(*(ref.q[:, :2] - scn.poses[:, :2]).T)) > 0.1 * steps * scn.dt


@pytest.mark.timeout(120)
def test_a_crowd_grows_the_candidate_lists_and_still_equals_the_single_robot_law():
    """64 robots 0.4 m apart beside a cluster of 36 obstacles: each robot has some 60 candidate robots and many
    have tens of obstacles, more than the lists' first arrays hold; the kernel asks for more, and every step
    equals the brute-force reference."""
    base = sf.load("paper-50hz", sf.Overrides(robots=64, seed=2))
    g = np.arange(8) * 0.4
    xy = np.array([(x, y) for x in g for y in g])
    poses = np.column_stack([xy, np.zeros(64)])
    offsets = np.column_stack([np.arange(64) * 1.6 - 50.0, np.full(64, 10.0)])
    ob = np.array([(3.3 + 0.5 * (c % 6), 0.5 * (c // 6), 0.2, 1.5) for c in range(36)])
    scn = base.replace(poses=poses, offsets=offsets, obstacles=ob, duration=4.0)
    sim = Simulation(scn)
    first = (len(sim.lcand), len(sim.ocand))
    ref = Reference(scn)
    for chunk in (1, 60, 139):
        sim.advance(sim.next_k + chunk)
        ref.advance(chunk)
        assert_allclose(sim.q, ref.q, rtol=0, atol=1e-12)
        assert_allclose(sim.cmd, ref.cmd, rtol=0, atol=1e-12)
    assert len(sim.lcand) > first[0] and len(sim.ocand) > first[1]  # both lists grew
    assert ref.frozen_steps > 0


def _law_inputs(rng, count):
    for _ in range(count):
        yield rng.uniform(-10, 10), rng.uniform(0.1, 0.5), rng.uniform(0.6, 2.0)


def test_compiled_law_functions_equal_the_plain_ones():
    from swarm.core import jit

    cl = jit.compiled("swarm.core.law")
    rng = np.random.default_rng(16)
    for a in list(rng.uniform(-20, 20, 200)) + [math.pi, -math.pi, 3 * math.pi, -3 * math.pi, 0.0]:
        assert cl.wrap_angle(a) == law.wrap_angle(a)
    for _, r, R in _law_inputs(rng, 200):
        for l in (rng.uniform(0, r), rng.uniform(r, R), rng.uniform(R, 2 * R)):
            assert_allclose(cl.potential(l, r, R), law.potential(l, r, R), rtol=1e-14)
            assert_allclose(cl.potential_slope(l, r, R), law.potential_slope(l, r, R), rtol=1e-14)
    for mode in (law.THRESHOLD_OFF, law.THRESHOLD_FROZEN, law.THRESHOLD_ALWAYS):
        for frozen in (False, True):
            for v in (0.0, -0.0, 0.01, -0.01, 0.3):
                assert cl.apply_threshold(v, 0.05, mode, frozen) == law.apply_threshold(v, 0.05, mode, frozen)


# --------------------------------------------------------------------------- metrics


@pytest.mark.timeout(120)
@pytest.mark.parametrize("seed", [0, 2])
def test_paper_50hz_converges_without_collision(seed):
    scn = sf.load("paper-50hz", sf.Overrides(seed=seed))
    m = Simulation(scn).run().metrics
    assert m["robots"] == 37 and m["obstacles"] == len(scn.obstacles) > 0
    assert m["collisions"] == 0
    assert m["min_robot_distance_m"] > scn.r
    assert m["min_obstacle_distance_m"] > scn.r
    assert m["converged_at_s"] is not None and m["converged_at_s"] < 100.0
    assert m["last_freeze_end_s"] is not None and m["last_freeze_end_s"] < m["converged_at_s"] + 5.0
    assert m["final_position_error_max_m"] < 1e-9
    assert m["final_orientation_error_max_rad"] < 1e-9
    assert m["duration_s"] == pytest.approx(120.0) and m["dt"] == 0.02 and m["seed"] == seed
    assert m["interrupted"] is False


def _two_body_doc(governor, obstacle):
    """dt = 0.05, k1 = 5: long steps that jump into a body unless something holds them back."""
    doc = {
        "run": {"duration": 20.0, "dt": 0.05},
        "control": {"governor": governor, "k1": 5.0},
        "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 1.0, "v": 0.0, "w": 0.0}]},
    }
    if obstacle:  # a robot driving straight through an obstacle to its slot
        doc["formation"] = {"offsets": [[4.0, 0.0]]}
        doc["robots"] = {"poses": [[-4.0, 0.0, 0.0]]}
        doc["obstacles"] = [{"center": [0.0, 0.0]}]
    else:  # two robots swapping places head-on
        doc["formation"] = {"offsets": [[3.0, 0.0], [-3.0, 0.5]]}
        doc["robots"] = {"poses": [[-3.0, 0.0, 0.0], [3.0, 0.5, math.pi]]}
    return doc


@pytest.mark.timeout(60)
@pytest.mark.parametrize("obstacle", [False, True])
def test_governor_prevents_the_collision_that_happens_without_it(obstacle):
    key = "min_obstacle_distance_m" if obstacle else "min_robot_distance_m"
    on = Simulation(sf.resolve(sf.parse(_two_body_doc(True, obstacle), "test", "head-on"))).run()
    m = on.metrics
    assert m["collisions"] == 0
    assert m[key] > 0.3
    assert m["governed_robot_steps"] > 0
    # every sampled pose too (the invariant, not only the metric)
    q = on.recording.q
    if obstacle:
        assert np.min(np.hypot(q[:, 0, 0], q[:, 0, 1])) > 0.3
    else:
        assert np.min(np.hypot(q[:, 0, 0] - q[:, 1, 0], q[:, 0, 1] - q[:, 1, 1])) > 0.3

    off = Simulation(sf.resolve(sf.parse(_two_body_doc(False, obstacle), "test", "head-on"))).run().metrics
    assert off["collisions"] >= 1
    assert off[key] < 0.3
    assert off["governed_robot_steps"] == 0


@pytest.mark.timeout(60)
def test_a_pair_that_starts_inside_counts_one_collision():
    base = sf.resolve(sf.parse(_two_body_doc(False, False), "test", "inside"))
    # bypass the file checks: two robots 0.2 m apart, slots 3 m apart. The governor keeps
    # the clamped repulsion (dV/dl ~ -8e7 at r + eps) from flinging them kilometres apart.
    scn = base.replace(poses=np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]]),
                       offsets=np.array([[-1.5, 0.0], [1.5, 0.0]]), duration=10.0, dt=0.01,
                       control=Control(governor=True))
    m = Simulation(scn).run().metrics
    assert m["min_robot_distance_m"] == pytest.approx(0.2)
    assert m["collisions"] == 1
    assert m["final_position_error_max_m"] < 0.05


@pytest.mark.timeout(60)
def test_metrics_follow_the_recorded_errors():
    scn = sf.load("paper-50hz", sf.Overrides(robots=7, seed=1, duration=40.0))
    res = Simulation(scn).run()
    rec, m = res.recording, res.metrics
    assert rec.t[0] == 0.0 and rec.t[-1] == pytest.approx(40.0)
    # errors are against the live leader reference
    leader = np.array([scn.leader.state(t)[:3] for t in rec.t])
    assert_allclose(rec.leader, leader, atol=1e-12)
    px = leader[:, None, 0] + scn.offsets[None, :, 0] - rec.q[:, :, 0]
    assert_allclose(rec.err[:, :, 0], px, atol=1e-12)
    pe = np.hypot(rec.err[-1, :, 0], rec.err[-1, :, 1])
    assert_allclose(m["final_position_error_max_m"], pe.max(), rtol=1e-12)
    # converged_at_s: every later sample is converged, and some sample before it is not
    ok = (np.hypot(rec.err[:, :, 0], rec.err[:, :, 1]) < 0.05).all(axis=1) & (np.abs(rec.err[:, :, 2]) < 0.05).all(axis=1)
    assert m["converged_at_s"] is not None
    assert ok[rec.t >= m["converged_at_s"] - 1e-9].all()
    assert not ok[rec.t < m["converged_at_s"] - scn.dt / 2].all()
    # the smallest robot distance is no larger than any sampled one
    d = np.hypot(rec.q[:, :, None, 0] - rec.q[:, None, :, 0], rec.q[:, :, None, 1] - rec.q[:, None, :, 1])
    d[:, np.arange(scn.n), np.arange(scn.n)] = np.inf
    assert m["min_robot_distance_m"] <= d.min() + 1e-12


def reference_metrics(scn: Scenario):
    """The metrics of docs/metrics.md, from the reference run, evaluated at every step 0..K."""
    ref = Reference(scn)
    K = scn.steps
    n = scn.n
    obs = scn.obstacles
    inside_prev: set = set()
    collisions = 0
    min_rr = min_ro = math.inf
    last_bad = last_frozen = -1
    for k in range(K + 1):
        t = k * scn.dt
        xl, yl, thl, _, _ = scn.leader.state(t)
        q = ref.q
        inside_now = set()
        for i in range(n):
            for j in range(i + 1, n):
                d = math.hypot(q[i, 0] - q[j, 0], q[i, 1] - q[j, 1])
                min_rr = min(min_rr, d)
                if d < scn.r:
                    inside_now.add((i, j))
            for o, (x, y, r, _) in enumerate(obs):
                d = math.hypot(q[i, 0] - x, q[i, 1] - y)
                min_ro = min(min_ro, d)
                if d < r:
                    inside_now.add((i, n + o))
        collisions += len(inside_now - inside_prev)
        inside_prev = inside_now
        pe = np.hypot(xl + scn.offsets[:, 0] - q[:, 0], yl + scn.offsets[:, 1] - q[:, 1])
        ee = np.abs([law.wrap_angle(thl - th) for th in q[:, 2]])
        if not ((pe < 0.05) & (ee < 0.05)).all():
            last_bad = k
        if k < K:
            frozen_before = ref.frozen_steps
            ref.advance(1)
            if ref.frozen_steps > frozen_before:
                last_frozen = k
    return {
        "converged_at_s": None if last_bad == K else (last_bad + 1) * scn.dt,
        "final_position_error_max_m": float(pe.max()),
        "final_orientation_error_max_rad": float(ee.max()),
        "min_robot_distance_m": min_rr if n > 1 else None,
        "min_obstacle_distance_m": min_ro if len(obs) else None,
        "collisions": collisions,
        "last_freeze_end_s": None if last_frozen < 0 else last_frozen * scn.dt,
    }


def _far_apart_doc():
    """Nobody ever within the cell side: two robots pass each other 2 m apart and an obstacle 3 m off,
    at dt = 0.01 s, so the closest approach falls between the 0.05 s samples."""
    return {
        "run": {"duration": 4.0, "dt": 0.01},
        "leader": {"start": [0.0, 0.0, 7.0], "segments": [{"duration": 4.0, "v": 0.3, "w": 0.0}]},
        "formation": {"offsets": [[0.0, 0.0], [0.0, 2.0]]},
        "robots": {"poses": [[0.0, 0.0, 7.0], [0.3, 2.0, -12.5]]},
        "obstacles": [{"center": [0.7, -3.2]}],
    }


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "make",
    [
        # a robot that bounces in and out of an obstacle (three collisions)
        lambda: sf.resolve(sf.parse(_two_body_doc(False, True), "t", "o")).replace(duration=10.0, dt=0.1,
                                                                                     control=Control(k1=2.0)),
        lambda: sf.resolve(sf.parse(_two_body_doc(False, False), "t", "h")).replace(duration=10.0),
        lambda: sf.resolve(sf.parse(_two_body_doc(True, False), "t", "h")).replace(duration=10.0),
        lambda: sf.load("paper-50hz", sf.Overrides(robots=7, seed=4, duration=30.0)),
        lambda: sf.resolve(sf.parse(_far_apart_doc(), "t", "far")),
    ],
    ids=["obstacle-bounces", "head-on-free", "head-on-governed", "paper-50hz-7", "far-apart"],
)
@pytest.mark.parametrize("threads", [1, 2])
def test_metrics_equal_their_definition_evaluated_at_every_step(make, threads):
    scn = make()
    got = Simulation(scn, threads=threads).run().metrics
    want = reference_metrics(scn)
    for key, value in want.items():
        if value is None:
            assert got[key] is None, key
        elif isinstance(value, int):
            assert got[key] == value, key
        else:
            assert_allclose(got[key], value, rtol=1e-12, atol=1e-12, err_msg=key)
    assert got["duration_s"] == pytest.approx(scn.steps * scn.dt)


@pytest.mark.timeout(180)
def test_the_parallel_kernel_equals_the_serial_one_bit_for_bit():
    """A crowded 1000-robot paper run (collisions, freezes, robots at obstacles), on 1 and on 2 threads: every state,
    command, sample and metric the same bits (each robot's step reads only the state before it; the metrics are
    reduced in id order)."""
    scn = sf.load("paper", sf.Overrides(robots=1000, duration=1.0, seed=0))
    runs = []
    for threads in (1, 2):
        sim = Simulation(scn, threads=threads, record_period=0.01)
        runs.append((sim, sim.run()))
    (one, a), (two, b) = runs
    assert two.k is not one.k and two.scratch[0].shape[0] == 2
    assert a.metrics["collisions"] > 0 and a.metrics["freeze_intervals"] > 0
    for name in ("q", "comp", "mem", "cmd", "acc", "iacc", "pairs", "last_frozen"):
        np.testing.assert_array_equal(getattr(one, name), getattr(two, name), err_msg=name)
    for name in ("t", "q", "err", "cmd", "frozen", "leader"):
        np.testing.assert_array_equal(getattr(a.recording, name), getattr(b.recording, name), err_msg=name)
    assert {k: v for k, v in a.metrics.items() if not k.startswith("wall")} == \
        {k: v for k, v in b.metrics.items() if not k.startswith("wall")}


@pytest.mark.timeout(60)
def test_run_stops_when_asked_and_says_so():
    scn = sf.load("paper-50hz", sf.Overrides(robots=7, seed=1))
    calls = []
    res = Simulation(scn).run(should_stop=lambda: len(calls) > 0, progress=calls.append)
    assert len(calls) == 1
    assert res.metrics["interrupted"] is True
    assert 0 < res.metrics["duration_s"] < scn.duration
    assert calls[0].robots == 7 and calls[0].t == pytest.approx(res.metrics["duration_s"])


def test_a_sparse_swarm_of_150_measures_every_pair_at_every_step():
    """150 robots (11 175 pairs) that never come within the cell side, closest mid-run: min_robot_distance_m
    came from the 0.05 s samples, 7e-7 m off the contract's every-step minimum (from a contract audit)."""
    from pathlib import Path

    scn = sf.load(str(Path(__file__).parent / "data" / "sparse150.toml"), progress=sf.silent)
    result = Simulation(scn).run()  # samples every 0.05 s, as swarm sim records
    q = Simulation(scn, record_period=scn.dt).run().recording.q  # every step
    n = scn.n
    d = np.hypot(*(q[:, :, None, :2] - q[:, None, :, :2]).transpose(3, 0, 1, 2))
    d[:, np.arange(n), np.arange(n)] = np.inf
    assert n == 150 and d.min() > scn.cell_side  # never within the cell side: the far pairs' path
    assert result.metrics["min_robot_distance_m"] == float(d.min())
