"""Real time without a message (docs/faults.md, Safe under faults), on the in-memory bus and a fake clock:
a neighbour's age goes to the law body by body and a live one is never forgotten while in range; a pose
that does not come is replaced by the last one advanced by the robot's own command; robots log a lost and
a returning liveliness token; the guard halts a robot that lost the world; the real-time world holds a
missing command one period, then brakes, and adds up the robots' fault counters."""

from __future__ import annotations

import logging
import math
import threading

import pytest

from agents import robot
from agents.guard import Guard
from swarm.core import faults as F
from swarm.core import kinematics, law, scenario_file
from swarm.core.clock import FakeClock
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.proto.protocol import Clock, Cmd, Config, FaultStats, Pose, Ref, State
from world.faultworld import brake_factor
from world.world import World

F_ = "rtf"
CFG = Config(id=3, x=0.0, y=0.0, theta=0.0, dx=1.5, dy=-0.5, r=0.3, R=1.2, k1=0.5, k2=0.5, k3=1.0, tu=1.0,
             vt=0.05, threshold=law.THRESHOLD_FROZEN, governor=True, dt=0.02, sense=1.5, reach=1.2,
             lockstep=False, robots=16)
EPOCH = 1_000_000.0 - 2.0  # the fake clock's time() is 1e6 + elapsed: simulated time 2.0 + elapsed


class Rig:
    """A real-time agent on a fake clock (its epoch: simulated 2.0 s at elapsed 0), and a probe bus."""

    def __init__(self, cfg=CFG, drive=None, guard=None):
        self.net = MemoryNet()
        self.clock = FakeClock()
        bus = MemoryBus(self.net)
        self.agent = robot.Agent(bus, cfg, F_, clock=self.clock, drive=drive, guard=guard)
        self.agent.start([])
        self.probe = MemoryBus(self.net)
        self.cmds: list[Cmd] = []
        self.states: list[State] = []
        self.probe.subscribe(keys.robot_cmd(F_, cfg.id), lambda k, b: self.cmds.append(protocol.decode(b, "cmd")))
        self.probe.subscribe(f"swarm/{F_}/cell/*/*/{cfg.id}", lambda k, b: self.states.append(protocol.decode(b, "state")))
        self.put(keys.world_clock(F_), Clock(t=0.0, seq=0, epoch=EPOCH, speed=1.0))
        self.agent._first_pose_t = -1.0  # past the listening start

    def put(self, key, msg):
        self.probe.put(key, protocol.encode(msg))

    def now(self) -> float:
        return self.agent.sim_time(self.clock.time())

    def pose(self, seq: int, x: float = 0.0, y: float = 0.0, th: float = 0.0) -> None:
        self.put(keys.robot_pose(F_, CFG.id), Pose(t=self.now(), seq=seq, x=x, y=y, theta=th))

    def state(self, j: int, t: float, x: float, y: float, seq: int = 1) -> None:
        cx, cy = keys.cell_of(x, y, CFG.sense)
        self.put(keys.cell(F_, cx, cy, j), State(id=j, t=t, seq=seq, x=x, y=y, theta=0.0, r=0.3, R=1.2, frozen=False))


def law_with_ages(agent, pose, ref, t, bodies, ages, horizon):
    p = list(agent.p)
    p[law.P_DT] = horizon
    mem = [0.0] * law.M_SIZE
    mem[law.M_SCALE] = 1.0
    nx, ny, nr, nR, nk = ([b[i] for b in bodies] for i in range(5))
    return law.robot_command(*pose, CFG.dx, CFG.dy, CFG.r, t, *ref, nx, ny, nr, nR, nk, ages, len(bodies), mem, p)


def test_a_neighbours_age_goes_to_the_law_and_a_live_one_in_range_is_never_forgotten():
    rig = Rig()
    rig.put(keys.leader_ref(F_), Ref(t=2.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    rig.state(7, t=1.7, x=1.0, y=0.6)  # ahead, 1.17 m away; 0.3 s old when it comes
    rig.clock.advance(0.05)
    rig.pose(10)
    assert rig.agent.tick_realtime(rig.now())
    body = [(1.0, 0.6, 0.3, 1.2, law.KIND_ROBOT)]
    ref = (0.025, 0.0, 0.0, 0.5, 0.0)
    expected = law_with_ages(rig.agent, (0.0, 0.0, 0.0), ref, 2.05, body, [0.35], 2 * CFG.dt)
    assert (rig.cmds[-1].v, rig.cmds[-1].w) == pytest.approx(expected, rel=1e-9)  # (times from 1e6 s: 1e-11 off)
    fresh = law_with_ages(rig.agent, (0.0, 0.0, 0.0), ref, 2.05, body, [0.0], 2 * CFG.dt)
    assert fresh[0] > 0.1 and rig.cmds[-1].v == 0.0  # fresh, it would drive on; 0.35 s old, it may be anywhere near
    # 5 s later, nothing heard of robot 7 (2 s used to forget it): still a body, 5.35 s old
    rig.clock.advance(5.0)
    rig.pose(11)
    assert rig.agent.tick_realtime(rig.now())
    assert rig.agent.neighbours == 1 and rig.agent.stale == 1
    assert rig.agent.oldest_state_s == pytest.approx(5.35) and rig.cmds[-1].v == 0.0


def test_a_state_out_of_range_is_left_out_until_a_newer_one_comes():
    """The simulator's rule: a neighbour whose state is farther than reach + L is forgotten (it left the
    cells, or this robot left its); coming back near its old position does not bring it back."""
    rig = Rig()
    rig.put(keys.leader_ref(F_), Ref(t=2.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.0, w=0.0))
    rig.state(7, t=2.0, x=1.4, y=0.0)  # beyond reach + L = 1.3 m
    rig.pose(1)
    rig.agent.tick_realtime(rig.now())
    assert rig.agent.neighbours == 0 and 7 in rig.agent.away
    rig.clock.advance(0.02)
    rig.pose(2, x=0.5)  # now 0.9 m from its last position: still left out
    rig.agent.tick_realtime(rig.now())
    assert rig.agent.neighbours == 0
    rig.state(7, t=rig.now(), x=1.4, y=0.1, seq=2)  # a newer state, in range: a body again
    rig.clock.advance(0.02)
    rig.pose(3, x=0.5)
    rig.agent.tick_realtime(rig.now())
    assert rig.agent.neighbours == 1 and 7 not in rig.agent.away


def test_a_lost_token_is_logged_and_the_robot_stays_a_static_body_with_its_age_then(caplog):
    rig = Rig()
    rig.put(keys.leader_ref(F_), Ref(t=2.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.0, w=0.0))
    other = MemoryBus(rig.net)
    tok = other.token(keys.alive(F_, "robot", 5))
    rig.state(5, t=1.9, x=0.8, y=0.0)
    rig.pose(1)
    rig.agent.tick_realtime(rig.now())  # takes the state: 0.1 s old
    rig.clock.advance(0.2)
    with caplog.at_level(logging.INFO, logger="swarm.robot"):
        tok.close()
        rig.clock.advance(3.0)  # a dead body does not age
        rig.pose(2)
        rig.agent.tick_realtime(rig.now())
        tok = other.token(keys.alive(F_, "robot", 5))
    lines = [r.getMessage() for r in caplog.records]
    assert "robot 3: robot 5 lost (its liveliness token is gone)" in lines
    assert "robot 3: robot 5 back (its liveliness token is here again)" in lines
    assert rig.agent.dead_age == {} and 5 not in rig.agent.dead
    other.close()


def test_the_static_body_of_a_lost_robot_carries_its_age_at_the_loss():
    rig = Rig()
    other = MemoryBus(rig.net)
    tok = other.token(keys.alive(F_, "robot", 5))
    rig.put(keys.leader_ref(F_), Ref(t=2.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.0, w=0.0))
    rig.state(5, t=1.9, x=0.8, y=0.0)
    rig.pose(1)
    rig.agent.tick_realtime(rig.now())
    rig.clock.advance(0.2)
    tok.close()
    rig.clock.advance(3.0)
    nx, ny, nr, nR, nk, na, robots, _ = rig.agent.bodies(0.0, 0.0, None, rig.now())
    assert (nx, nk, robots) == ([0.8], [law.KIND_OBSTACLE], 0) and na == [pytest.approx(0.3)]
    other.close()


def test_without_its_pose_a_robot_advances_the_last_one_by_its_own_command_and_never_goes_back_in_time():
    rig = Rig()
    rig.put(keys.leader_ref(F_), Ref(t=2.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    rig.pose(1, x=-1.0)
    assert rig.agent.tick_realtime(rig.now())
    c0 = rig.cmds[-1]
    assert c0.v != 0.0 and rig.agent.periodic  # the simulated world's drive: a pose each period
    assert rig.agent.late_due() == pytest.approx(robot.POSE_LATE_PERIODS * CFG.dt)
    rig.clock.advance(0.03)  # the pose of 2.02 was lost
    assert rig.agent.tick_realtime(rig.now(), late=True)
    dx, dy, dth = kinematics.arc_displacement(0.0, c0.v, c0.w, 0.03)
    st = rig.states[-1]
    assert (st.t, st.x, st.y, st.theta) == pytest.approx((2.03, -1.0 + dx, dy, dth), abs=1e-9)
    assert rig.cmds[-1].t == pytest.approx(2.03) and rig.agent.reckoned == 1
    assert rig.agent.late_due() == pytest.approx(2.5 * CFG.dt)  # one more period
    # the pose of 2.02 comes after all (late): brought to 2.03 by the last command, not back to 2.02
    c1 = rig.cmds[-1]
    rig.put(keys.robot_pose(F_, CFG.id), Pose(t=2.02, seq=2, x=-0.99, y=0.0, theta=0.0))
    rig.agent.take_poses(rig.agent.drive.drain())
    rig.agent.tick_realtime(rig.now())
    dx, dy, dth = kinematics.arc_displacement(0.0, c1.v, c1.w, 0.01)
    st = rig.states[-1]
    assert (st.t, st.x, st.y) == pytest.approx((2.03, -0.99 + dx, dy), abs=1e-9)
    assert [c.t for c in rig.cmds] == sorted(c.t for c in rig.cmds)


def test_the_guard_halts_a_robot_that_lost_the_world():
    class Drive:
        halted = None

        def halt(self, why):
            self.halted = why

    g = Guard(Drive(), FakeClock())
    assert g.reason(0.0) is None
    g.world(True)
    g.world(False)
    assert g.check(0.0) == "the world is lost" and g.drive.halted == "the world is lost"
    g.world(True)
    assert g.reason(0.0) is None


def test_a_real_time_agent_tells_its_guard_when_the_worlds_token_goes():
    halted: list[str] = []

    class Drive:
        halted = None
        periodic = False

        def start(self):
            pass

        def halt(self, why):
            halted.append(why)
            self.halted = why

        def close(self):
            pass

    drive = Drive()
    guard = Guard(drive, FakeClock())
    rig = Rig(drive=drive, guard=guard)
    tok = MemoryBus(rig.net).token(keys.alive(F_, "world"))
    assert guard.check(None) is None
    tok.close()
    assert guard.check(None) == "the world is lost" and halted == ["the world is lost"]


# --------------------------------------------------------------------------- the world


def world_doc() -> dict:
    return {"run": {"duration": 1.2, "dt": 0.02, "seed": 0},
            "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 1.2, "v": 0.0, "w": 0.0}]},
            "formation": {"offsets": [[0.0, 0.0], [5.0, 0.0]], "assignment": "ordered"},
            "robots": {"poses": [[0.0, 0.0, 0.0], [5.0, 0.0, 0.0]]}}


def test_the_real_time_world_holds_a_missing_command_one_period_then_brakes_then_stops(write_scenario):
    """Robot 0 answers its poses up to t = 0.4 s with (V, W), then falls silent: the world moves it with
    that command for the period it was meant for and one more, then brakes it along BRAKE_S (a step a
    period), and its watchdog (here 0.15 wall s: 0.6 simulated s at speed 4) stops it.

    On a fake clock: the world's loop sees exactly the times of its schedule, so a loaded machine cannot
    stall it past a period (the memory bus answers each pose synchronously, within the same step)."""
    scn = scenario_file.load(write_scenario(world_doc()))
    net = MemoryNet()
    world = World(MemoryBus(net), scn, F_, lockstep=False, speed=4.0, watchdog=0.15, clock=FakeClock())
    world.start()
    drive = MemoryBus(net)
    V, W = 0.4, 0.2
    snaps: list = []

    def on_pose(key: str, data: bytes) -> None:
        p = protocol.decode(data, "pose")
        if p.t <= 0.4:
            drive.put(keys.robot_cmd(F_, 0), protocol.encode(Cmd(t=p.t, seq=p.seq, v=V, w=W)), reliable=True)

    drive.subscribe(keys.robot_pose(F_, 0), on_pose)
    drive.subscribe(keys.world_snapshot(F_), lambda k, b: snaps.append(protocol.decode(b, "snapshot")))
    try:
        metrics = world.run(threading.Event())
    finally:
        world.close()
        drive.close()
    applied = [(s.t, s.robots[0].v) for s in snaps]
    last = max(t for t, v in applied if v == V)  # the held command's last period
    # the last answer (to the pose of t = 0.4 s) is taken a fine step later: its period and one more run out
    # between the checks at 0.44 s and 0.46 s, so the snapshot of 0.44 s still has it
    assert last == pytest.approx(0.4 + 2 * scn.dt, abs=1e-9)
    ramp = [v for t, v in applied if t > last and v > 0.0]
    steps = [brake_factor(k, scn.dt) * V for k in range(2, 20)]  # a step each period (seen where a snapshot falls)
    assert all(min(abs(v - f) for f in steps) < 1e-12 for v in ramp) and ramp == sorted(ramp, reverse=True)
    assert len(set(ramp)) >= 5
    assert all(v == 0.0 for t, v in applied if t > last + 0.25 + 2 * scn.dt)
    assert world.stopped[0] and metrics["robots_alive_at_end"] == 0  # (no tokens on this bus)
    assert world.cmd_held == 1 and world.watchdog_stops == 1  # held once, when it fell silent; stopped once


def test_the_real_time_world_drops_commands_by_the_model_and_adds_up_each_process_counters(write_scenario):
    doc = world_doc()
    doc["faults"] = {"seed": 4, "drop": [{"class": "cmd", "p": 1.0, "from": [1]}],
                     "kill": [{"robot": 1, "at": 0.3, "restart": 0.2}]}
    scn = scenario_file.load(write_scenario(doc))
    net = MemoryNet()
    world = World(MemoryBus(net), scn, F_, lockstep=False, speed=4.0)
    world.start()
    bot = MemoryBus(net)

    def on_pose(i):
        def cb(key: str, data: bytes) -> None:
            p = protocol.decode(data, "pose")
            bot.put(keys.robot_cmd(F_, i), protocol.encode(Cmd(t=p.t, seq=p.seq, v=0.3, w=0.0)), reliable=True)
        return cb

    bot.subscribe(keys.robot_pose(F_, 0), on_pose(0))
    bot.subscribe(keys.robot_pose(F_, 1), on_pose(1))
    # robot 1's first process reports twice, then a new process (a new token) counts from 0 again
    tokens = [bot.token(keys.alive(F_, "robot", 1))]

    def report(seq, d):
        bot.put(keys.robot_faults(F_, 1), protocol.encode(FaultStats(0.1 * seq, seq, d, 2 * d, 0, 1, 0, 0, 0.05 * d,
                                                                    frozen=False)), reliable=True)

    report(0, 1)
    report(1, 3)
    world._take_faultstats()
    report(1, 3)  # the same again: refused (a stale one)
    world._take_faultstats()
    tokens[0].close()
    tokens.append(bot.token(keys.alive(F_, "robot", 1)))
    report(0, 2)
    world._take_faultstats()
    try:
        metrics = world.run(threading.Event())
    finally:
        world.close()
        bot.close()
    f = metrics["faults"]
    assert world.q[1] == list(scn.poses[1])  # every command of robot 1 was lost: it never moved
    assert world.q[0][0] > 0.1
    assert f["dropped"]["cmd"] > 40 and f["dropped"]["state"] == 3 + 2 and f["dropped"]["pose"] == 6 + 4
    assert f["delayed"]["state"] == 2 and f["max_state_age_s"] == pytest.approx(0.15)
    assert metrics["messages_dropped"] == sum(f["dropped"].values())
    assert (f["killed"], f["restarted"], f["hung"], f["partitions"]) == (1, 1, 0, 0)
    assert metrics["stale_messages"] >= 1
    assert math.isfinite(f["max_state_age_s"])


def test_a_table_of_faults_decides_the_world_side_on_the_same_links(write_scenario):
    doc = world_doc()
    doc["faults"] = {"drop": [{"class": "all", "p": 0.5}]}
    scn = scenario_file.load(write_scenario(doc))
    world = World(MemoryBus(MemoryNet()), scn, F_, lockstep=False)
    assert world.fbus is not None and world.fbus.me == F.WORLD and world.bus is world.fbus
    lock = World(MemoryBus(MemoryNet()), scn, F_, lockstep=True)
    assert lock.fbus is None  # lock-step decides in world.faultworld


def test_a_reference_gap_its_fault_bus_explains_is_taken_not_counted_bad():
    """Real time under faults: after a partition (or a burst of drops) of references longer than the window's
    t_span, the next reference jumped the window and was counted bad, 2 a partition's end (from a contract
    audit). A gap the robot's own fault bus lost references in is the schedule's; any other jump is refused."""

    class Counters:  # what the agent reads of its FaultBus
        dropped, delayed, lost_t = [0] * 4, [0] * 4, [-math.inf] * 4

    counters = Counters()
    agent = robot.Agent(MemoryBus(MemoryNet()), CFG, F_, clock=FakeClock(), counters=counters)
    ref = lambda t, seq: Ref(t=t, seq=seq, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0)  # noqa: E731
    agent._on_ref(ref(1.0, 10))
    agent._on_ref(ref(4.0, 40))  # 3 s later: beyond t_span, nothing lost in between
    assert agent.bad.count == 1 and agent.ref.seq == 10
    counters.lost_t[3] = 3.5  # faultgen.CLS_REF: the bus lost a reference of t = 3.5
    agent._on_ref(ref(4.1, 41))
    assert agent.bad.count == 1 and agent.ref.seq == 41
    agent._on_ref(ref(9.0, 90))  # a jump past what the bus lost: still refused
    assert agent.bad.count == 2 and agent.ref.seq == 41
    counters.lost_t[3] = 9.5
    agent._on_ref(ref(1e6, 10**7))  # after a loss, but far beyond its window (a forged one): refused
    assert agent.bad.count == 3 and agent.ref.seq == 41
