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
from swarm.core import kinematics, law, safety, scenario_file
from swarm.core.clock import FakeClock
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.proto.protocol import Clock, Cmd, Config, FaultStats, Pose, Ref, State
from world.world import World
from swarm.drives.base import DriveBase

pytestmark = pytest.mark.unit

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


def test_a_neighbours_age_goes_to_the_safety_rule_and_the_law_runs_as_in_lock_step():
    """The law is lock-step's (every age 0, the governor's horizon the period); the safety rule takes the age: a
    neighbour 0.95 m ahead whose state came 0.55 s old may be anywhere within V x (its age and this robot's
    reservation), so the robot stands although the law, with the same bodies, would drive on. PROBE_S later, never
    heard again, it is kept (not hearing it says nothing of where it is), and the robot listens for it in every
    cell: its state from a cell beyond those this robot hears takes it as away (and ends the listening), and a
    newer state near brings it back."""
    rig = Rig()
    rig.put(keys.leader_ref(F_), Ref(t=2.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    rig.state(7, t=1.45, x=0.9, y=0.3)  # ahead, 0.95 m away; 0.55 s old when it comes
    rig.clock.advance(0.05)
    rig.pose(10)
    assert rig.agent.tick_realtime(rig.now())
    body = [(0.9, 0.3, 0.3, 1.2, law.KIND_ROBOT)]
    ref = (0.025, 0.0, 0.0, 0.5, 0.0)
    lawful = law_with_ages(rig.agent, (0.0, 0.0, 0.0), ref, 2.05, body, [0.0], CFG.dt)
    assert lawful[0] > 0.1 and rig.cmds[-1].v == 0.0 and rig.agent.held == 1
    assert rig.agent.neighbours == 1 and rig.agent.oldest_state_s == pytest.approx(0.6)
    rig.clock.advance(robot.PROBE_S + 0.1)
    rig.pose(11)
    assert rig.agent.tick_realtime(rig.now())
    assert rig.agent.neighbours == 1 and 7 not in rig.agent.away and rig.cmds[-1].v == 0.0
    assert list(rig.agent._probes) == [7] and rig.agent.probed == 1  # listened for in every cell
    far = 3.5 * CFG.sense  # where it went: a cell this robot does not hear (only the probe does)
    rig.put(keys.cell(F_, *keys.cell_of(far, 0.3, CFG.sense), 7),
            State(id=7, t=rig.now(), seq=2, x=far, y=0.3, theta=0.0, r=0.3, R=1.2, frozen=False))
    rig.clock.advance(2 * safety.PROMISE_S)  # past its promise to stand
    rig.pose(12)
    assert rig.agent.tick_realtime(rig.now())
    assert rig.agent.neighbours == 0 and 7 in rig.agent.away and rig.cmds[-1].v > 0.0
    rig.pose(13)
    assert rig.agent.tick_realtime(rig.now()) and rig.agent._probes == {}  # away: the listening ends
    rig.state(7, t=rig.now(), x=0.9, y=0.3, seq=3)
    rig.clock.advance(0.02)
    rig.pose(14)
    assert rig.agent.tick_realtime(rig.now())
    assert rig.agent.neighbours == 1 and 7 not in rig.agent.away


def test_a_lost_token_and_its_return_are_logged(caplog):
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
    assert 5 not in rig.agent.dead
    other.close()


@pytest.mark.parametrize("stop", [None, 0.25])
def test_a_lost_robot_is_a_static_body_for_the_law_and_keeps_its_motion_bound_until_the_world_lists_it(stop):
    """A robot whose token goes is a static body for the law at its last state; the safety rule keeps its motion
    bound, the speed bound over its age, whatever it announced: this robot's newest state of it need not be its
    last (a later one, and the commands after it, may not have come), and the world, which stopped it, lists
    where (test_agent_realtime: the listing wins)."""
    rig = Rig()
    other = MemoryBus(rig.net)
    tok = other.token(keys.alive(F_, "robot", 5))
    rig.put(keys.leader_ref(F_), Ref(t=2.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.0, w=0.0))
    cx, cy = keys.cell_of(0.8, 0.0, CFG.sense)
    rig.put(keys.cell(F_, cx, cy, 5), State(id=5, t=1.9, seq=1, x=0.8, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False,
                                            stop=stop, still=None if stop is None else 0.0))
    rig.pose(1)
    rig.agent.tick_realtime(rig.now())
    rig.clock.advance(0.2)
    tok.close()
    rig.clock.advance(3.0)
    with rig.agent.lock:
        nx, ny, nr, nR, nk, na, robots, _, safe, _ = rig.agent._rt_bodies(0.0, 0.0, rig.now(), rig.now() + 0.2)
    assert (nx, nk, robots) == ([0.8], [law.KIND_DEAD], 0)
    V, eps = CFG.v_bound, 0.01
    assert safe == [(0.8, 0.0, 0.3, pytest.approx(V * (0.2 + 0.1 + 3.2 + eps)))]
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
    class Drive(DriveBase):
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

    class Drive(DriveBase):
        halted = None
        periodic = False

        def start(self, on_poses=None):
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


def _run_world_with(write_scenario, answer, watchdog=0.15):
    """A real-time world on a fake clock (speed 4) with robot 0 answering each of its poses with answer(pose)
    (a Cmd, or None for no answer); returns the world, its metrics and every snapshot's (t, v of robot 0)."""
    scn = scenario_file.load(write_scenario(world_doc()))
    net = MemoryNet()
    world = World(MemoryBus(net), scn, F_, lockstep=False, speed=4.0, watchdog=watchdog, clock=FakeClock())
    world.start()
    drive = MemoryBus(net)
    snaps: list = []

    def on_pose(key: str, data: bytes) -> None:
        c = answer(protocol.decode(data, "pose"))
        if c is not None:
            drive.put(keys.robot_cmd(F_, 0), protocol.encode(c), reliable=True)

    drive.subscribe(keys.robot_pose(F_, 0), on_pose)
    drive.subscribe(keys.world_snapshot(F_), lambda k, b: snaps.append(protocol.decode(b, "snapshot")))
    try:
        metrics = world.run(threading.Event())
    finally:
        world.close()
        drive.close()
    return world, metrics, [(s.t, s.robots[0].v) for s in snaps]


@pytest.mark.parametrize("valid", [0.1, None])
def test_the_real_time_world_executes_a_command_until_it_runs_out_then_brakes_then_stops(write_scenario, valid):
    """Robot 0 answers its poses up to t = 0.4 s with (V, W), valid for 0.1 s (or without a validity: then two
    periods from its arrival), then falls silent: the world executes the last command until it runs out, then
    brakes it in steps no faster than a linear ramp to a stop over RAMP_S (docs/runtime.md, "The safety
    invariant"), and the robot stands: the watchdog (0.15 wall s: 0.6 simulated s at speed 4) never has to.

    On a fake clock: the world's loop sees exactly the times of its schedule, so a loaded machine cannot
    stall it past a period (the memory bus answers each pose synchronously, within the same step)."""
    from swarm.core import safety

    V, W = 0.4, 0.2
    world, metrics, applied = _run_world_with(write_scenario, lambda p: Cmd(
        t=p.t, seq=p.seq, v=V, w=W, until=None if valid is None else p.t + valid) if p.t <= 0.4 else None)
    dt = world.scn.dt
    last = max(t for t, v in applied if v == V)  # the last snapshot with the full command
    runs_out = 0.4 + (valid if valid is not None else 2 * dt + world.fine_dt)  # (taken a fine step after the pose)
    assert runs_out - dt - 1e-9 <= last <= runs_out + 1e-9
    ramp = [(t, v) for t, v in applied if t > last and v > 0.0]
    assert ramp and all(v <= V * (1.0 - (t - runs_out) / safety.RAMP_S) + 1e-12 for t, v in ramp)  # under the ramp
    assert [v for _, v in ramp] == sorted((v for _, v in ramp), reverse=True)
    assert all(v == 0.0 for t, v in applied if t > runs_out + safety.RAMP_S + 1e-9)
    assert world.stopped[0] and metrics["robots_alive_at_end"] == 0  # (no tokens on this bus)
    assert world.cmd_held == 1 and metrics["cmd_braked"] == 1 and world.watchdog_stops == 0


def test_the_real_time_world_refuses_a_command_that_comes_after_its_validity(write_scenario):
    """A command that was valid until before the world takes it is never executed: too late, counted
    (cmd_expired), not a bad message; its robot does not move on it."""
    world, metrics, applied = _run_world_with(write_scenario, lambda p: Cmd(t=p.t, seq=p.seq, v=0.4, w=0.0,
                                                                             until=p.t - 0.001))
    assert all(v == 0.0 for _, v in applied) and world.q[0] == list(world.scn.poses[0])
    assert metrics["cmd_expired"] > 10 and metrics["bad_messages"] == 0


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
