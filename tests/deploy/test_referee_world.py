"""The referee without physics (world.referee_world) on the in-memory bus and a fake clock: what it
serves, the metrics from the robots' states (odometry-based, max_pose_age_s), snapshots with estimated
velocities, lost robots, a lost leader, bad states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.core import inventory, kinematics, runid, scenario_file
from swarm.core.clock import FakeClock
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.proto.protocol import State
from world.referee_world import NotReady, RefereeOptions, RefereeWorld, run_referee

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]
TB3 = scenario_file.load("turtlebot3", progress=scenario_file.silent)
SCN = TB3.replace(duration=2.0)


def fleet_of(scn=SCN, **row3):
    doc = {"robot": [{"id": i} for i in range(scn.n)]}
    doc["robot"][3].update(row3)
    return inventory.apply(inventory.parse(doc, "fleet.toml"), scn)


def slot(scn, i: int, t: float) -> tuple[float, float, float]:
    xl, yl, thl, _v, _w = kinematics.leader_state(scn.leader.table(), t)
    return xl + scn.offsets[i, 0], yl + scn.offsets[i, 1], thl


class Fed(RefereeWorld):
    """A referee whose robots publish their state (at their slot, `lag` s old) just before each period."""

    lag = 0.03
    feed = True

    def take_states(self) -> None:
        if self.feed:
            t = round(self.k * self.scn.dt, 9)
            for i in range(self.n):
                if self.alive[i]:
                    x, y, th = slot(self.scn, i, t - self.lag)
                    c = keys.cell_of(x, y, self.scn.cell_side)
                    self.agent.put(keys.cell(self.name, c[0], c[1], i), protocol.encode(
                        State(id=i, t=t - self.lag, seq=self.k + 1, x=x, y=y, theta=th, r=0.15, R=0.6, frozen=False)))
        super().take_states()


@pytest.fixture
def world():
    net = MemoryNet()
    ref = Fed(MemoryBus(net), fleet_of(v_max=0.2, initial_pose=[1.0, -3.0, 0.5]), "f", clock=FakeClock())
    ref.agent = MemoryBus(net)
    ref.watcher = MemoryBus(net)
    ref.start()
    yield ref
    ref.close()


def test_it_serves_the_run_the_configurations_and_the_obstacles(world):
    w = world.watcher
    (_, run), = w.query(keys.world_run("f"))
    run = protocol.decode(run, "run")
    assert run.digest == runid.digest(SCN) and run.scenario == runid.canonical(SCN) and not run.lockstep
    (_, cfg), = w.query(keys.world_config("f", 3))
    cfg = protocol.decode(cfg, "config", 3)
    assert (cfg.x, cfg.y, cfg.theta) == (1.0, -3.0, 0.5)  # the inventory's start
    assert (cfg.v_max, cfg.w_max) == (0.2, 2.84) and cfg.run == run.run and cfg.digest == run.digest
    (_, cfg0), = w.query(keys.world_config("f", 0))
    assert protocol.decode(cfg0, "config", 0).v_max == 0.22
    assert w.query(keys.world_config("f", 7)) == []
    (_, obs), = w.query(keys.world_obstacles("f"))
    assert len(protocol.decode(obs, "obstacles").obstacles) == len(SCN.obstacles)


def _alive(world, robots=range(7), leader=True):
    tokens = [world.agent.token(keys.alive("f", "robot", i)) for i in robots]
    if leader:
        tokens.append(world.agent.token(keys.alive("f", "leader")))
    return tokens


def test_a_run_of_robots_at_their_slots(world):
    snaps, progress = [], []
    world.watcher.subscribe(keys.world_snapshot("f"), lambda k, b: snaps.append(protocol.decode(b, "snapshot")))
    world.watcher.subscribe(keys.world_progress("f"), lambda k, b: progress.append(protocol.decode(b, "progress")))
    clocks = []
    world.watcher.subscribe(keys.world_clock("f"), lambda k, b: clocks.append(protocol.decode(b, "clock")))
    _alive(world)
    world.wait_ready(1.0)
    m = world.run()
    assert m["odometry_based"] is True and m["referee_only"] is True and m["mode"] == "realtime"
    assert m["max_pose_age_s"] == pytest.approx(0.03, abs=1e-9)
    assert m["converged_at_s"] == 0.0 and m["collisions"] == 0 and m["robots_lost"] == 0 and m["failure"] is None
    assert m["steps"] == 40 and m["samples"] == 41 and m["duration_s"] == 2.0 and m["bad_messages"] == 0
    assert m["min_robot_distance_m"] == pytest.approx(0.75, rel=1e-6)  # the formation's spacing
    assert m["scenario_digest"] == runid.digest(SCN)
    assert [c.seq for c in clocks] == [0] + list(range(41)) and len({c.epoch for c in clocks}) == 1
    s = snaps[-1]
    assert s.t == 2.0 and [r.id for r in s.robots] == list(range(7))
    assert all(r.alive and not r.stopped for r in s.robots)
    x, y, th = slot(SCN, 2, 2.0 - 0.03)
    assert (s.robots[2].x, s.robots[2].y) == pytest.approx((x, y))
    assert s.robots[2].v == pytest.approx(0.15, rel=1e-3) and abs(s.robots[2].w) < 1e-9  # estimated from states
    assert progress[-1].converged == 7 and progress[-1].alive == 7


def test_robots_without_a_state_are_not_live_and_stale_ones_are_shown_stopped(world):
    _alive(world)
    world.feed = False
    world.wait_ready(1.0)
    snaps = []
    world.watcher.subscribe(keys.world_snapshot("f"), lambda k, b: snaps.append(protocol.decode(b, "snapshot")))
    m = world.run()
    assert m["converged_at_s"] is None and m["final_position_error_max_m"] is None and m["max_pose_age_s"] == 0.0
    assert all(r.stopped and r.alive for r in snaps[-1].robots)
    np.testing.assert_array_equal(world.q, world.scn.poses)  # they stand at their starts


def test_a_robot_lost_during_the_run_is_counted(world):
    tokens = _alive(world)
    world.wait_ready(1.0)
    orig = world.sample

    def sample(t, k):
        if k == 10:
            tokens[4].close()
        orig(t, k)

    world.sample = sample
    m = world.run()
    assert m["robots_lost"] == 1 and m["robots_alive_at_end"] == 6


def test_a_lost_leader_ends_the_run_with_a_failure():
    net = MemoryNet()
    ref = Fed(MemoryBus(net), fleet_of(TB3.replace(duration=60.0)), "f", RefereeOptions(lost_timeout=1.0),
              clock=FakeClock())
    ref.agent = MemoryBus(net)
    ref.start()
    try:
        tokens = _alive(ref)
        ref.wait_ready(1.0)
        tokens[-1].close()
        m = ref.run()
        assert m["failure"].startswith("leader lost at t = ") and m["duration_s"] < 2.0
    finally:
        ref.close()


def test_bad_states_are_dropped_and_counted(world):
    _alive(world)
    world.feed = False
    a = world.agent
    good = State(id=2, t=0.0, seq=1, x=0.0, y=0.0, theta=0.0, r=0.15, R=0.6, frozen=False)
    a.put(keys.cell("f", 0, 0, 3), protocol.encode(good))  # id 2 on robot 3's key
    a.put(keys.cell("f", 0, 0, 9), protocol.encode(protocol.replace(good, id=9)))  # not in the run
    a.put(keys.cell("f", 0, 0, 2), b"garbage")
    a.put(keys.cell("f", 0, 0, 2), protocol.encode(good))
    a.put(keys.cell("f", 0, 0, 2), protocol.encode(protocol.replace(good, t=1e6, seq=2)))  # a jump
    world.take_states()
    assert world.bad.count == 4 and world.seen.tolist() == [False, False, True] + [False] * 4


def test_not_ready_names_the_missing_and_run_referee_closes():
    net = MemoryNet()
    agent = MemoryBus(net)
    agent.token(keys.alive("f", "robot", 0))
    with pytest.raises(NotReady, match=r"not alive after 0.3 s: leader, robot 1, robot 2"):
        run_referee(MemoryBus(net), FakeClock(), fleet_of(), RefereeOptions(start_timeout=0.3), name="f")
    assert agent.query(keys.world_run("f")) == []  # closed: nothing served any more


def test_speeds_the_law_cannot_exceed_are_refused_nowhere_here():
    """The referee refuses no position: a robot outside the arena is still seen (the guard halts it)."""
    net = MemoryNet()
    scn = scenario_file.load("turtlebot3", progress=scenario_file.silent)
    ref = RefereeWorld(MemoryBus(net), fleet_of(scn), "f", clock=FakeClock())
    ref.start()
    try:
        MemoryBus(net).put(keys.cell("f", 400, 400, 1), protocol.encode(
            State(id=1, t=0.0, seq=1, x=300.0, y=300.0, theta=math.pi, r=0.15, R=0.6, frozen=True)))
        ref.take_states()
        assert ref.seen[1] and ref.q[1].tolist() == [300.0, 300.0, math.pi] and ref.frozen[1]
    finally:
        ref.close()
