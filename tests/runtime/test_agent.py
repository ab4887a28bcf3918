"""The robot agent on the in-memory bus: its command is the core law, its traffic follows its cells."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
import sys

import pytest

from agents import robot
from swarm.proto import keys, protocol
from swarm.core import law, safety
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto.protocol import Clock, Config, Pose, Ref, State

F = "t"
CFG = Config(id=3, x=0.0, y=0.0, theta=0.0, dx=1.5, dy=-0.5, r=0.3, R=1.2, k1=0.5, k2=0.5, k3=1.0, tu=1.0,
             vt=0.05, threshold=law.THRESHOLD_FROZEN, governor=True, dt=0.02, sense=1.5, reach=1.2,
             lockstep=True, robots=16)


class Wire:
    """An agent on a MemoryNet plus a probe bus that records what it publishes."""

    def __init__(self, cfg=CFG, obstacles=()):
        self.net = MemoryNet()
        self.agent = robot.Agent(MemoryBus(self.net), cfg, F, wait_timeout=60.0)
        self.agent.start([protocol.Obstacle(*o) for o in obstacles])
        self.probe = MemoryBus(self.net)
        self.cmds: list[protocol.Cmd] = []
        self.states: list[protocol.State] = []
        self.statuses: list[protocol.Status] = []
        self.probe.subscribe(keys.robot_cmd(F, cfg.id), lambda k, b: self.cmds.append(protocol.decode(b, "cmd")))
        self.probe.subscribe(f"swarm/{F}/cell/*/*/{cfg.id}", lambda k, b: self.states.append(protocol.decode(b, "state")))
        self.probe.subscribe(keys.robot_status(F, cfg.id),
                             lambda k, b: self.statuses.append(protocol.decode(b, "status")))

    def put(self, key, msg):
        self.probe.put(key, protocol.encode(msg))

    def tick(self, k, pose, ref, neighbours=()):
        """One lock-step tick in the world's order: ref (a tick ahead), pose, the neighbours'
        states, and at k = 0 the clock (the world's start barrier)."""
        t = k * CFG.dt
        self.put(keys.leader_ref(F), Ref(t=t, seq=k, x=ref[0], y=ref[1], theta=ref[2], v=ref[3], w=ref[4]))
        self.put(keys.robot_pose(F, CFG.id), Pose(t=t, seq=k, x=pose[0], y=pose[1], theta=pose[2]))
        acted = self.agent.tick_lockstep()  # starts the tick: publishes its state, decides whom to wait for
        for j, (x, y, th) in neighbours:
            cx, cy = keys.cell_of(x, y, CFG.sense)
            self.put(keys.cell(F, cx, cy, j), State(id=j, t=t, seq=k, x=x, y=y, theta=th, r=0.3, R=1.2, frozen=False))
        if k == 0:
            assert not acted, "tick 0 must wait for the start barrier"
            self.put(keys.world_clock(F), Clock(t=t, seq=k, epoch=0.0, speed=1.0))
        return acted or self.agent.tick_lockstep()


def law_command(pose, ref, t, bodies, mem=None, cfg=CFG, horizon=None, obstacle_r=0.0):
    """The core law called directly with the same inputs (horizon: the governor's, default dt)."""
    mem = mem if mem is not None else [0.0] * law.M_SIZE
    p = [0.0] * law.P_SIZE
    p[law.P_K1], p[law.P_K2], p[law.P_K3], p[law.P_TU], p[law.P_VT] = cfg.k1, cfg.k2, cfg.k3, cfg.tu, cfg.vt
    p[law.P_THRESHOLD], p[law.P_GOVERNOR], p[law.P_SENSE], p[law.P_REACH] = cfg.threshold, 1.0, cfg.sense, cfg.reach
    p[law.P_OBSTACLE_R] = obstacle_r
    p[law.P_DT] = cfg.dt if horizon is None else horizon
    nx, ny, nr, nR, nk = ([b[i] for b in bodies] for i in range(5))
    return law.robot_command(pose[0], pose[1], pose[2], cfg.dx, cfg.dy, cfg.r, t, *ref, nx, ny, nr, nR, nk,
                             [0.0] * len(bodies), len(bodies), mem, p)


@pytest.mark.unit
def test_command_is_the_core_law_with_neighbours_and_an_obstacle():
    w = Wire(obstacles=[(0.9, 0.8, 0.3, 1.2)])
    pose, ref = (0.2, 0.1, 0.4), (1.0, 0.5, 0.2, 0.5, 0.05)
    nbs = [(7, (1.1, -0.3, 0.0)), (1, (-0.8, 0.2, 1.0)), (9, (5.0, 5.0, 0.0))]  # 9 is out of range
    assert w.tick(0, pose, ref, nbs)
    assert len(w.cmds) == 1 and w.cmds[0].seq == 0
    # summation order: robots by ascending id (1, 7), then the obstacle
    bodies = [(-0.8, 0.2, 0.3, 1.2, law.KIND_ROBOT), (1.1, -0.3, 0.3, 1.2, law.KIND_ROBOT),
              (0.9, 0.8, 0.3, 1.2, law.KIND_OBSTACLE)]
    v, om = law_command(pose, ref, 0.0, bodies)
    assert (w.cmds[0].v, w.cmds[0].w) == (v, om)  # bit for bit
    assert w.agent.neighbours == 2
    assert w.statuses and w.statuses[0].neighbours == 2 and w.statuses[0].frozen


@pytest.mark.unit
def test_freeze_memory_carries_over_ticks_like_the_law():
    w = Wire()
    mem = [0.0] * law.M_SIZE
    mem[law.M_SCALE] = 1.0
    for k in range(5):
        pose, ref = (0.01 * k, 0.0, 0.0), (0.02 * k, 0.0, 0.0, 0.5, 0.0)
        nb = (0.8, 0.1, 0.0)
        w.tick(k, pose, ref, [(4, nb)])
        expected = law_command(pose, ref, k * CFG.dt, [(*nb[:2], 0.3, 1.2, law.KIND_ROBOT)], mem)
        assert (w.cmds[-1].v, w.cmds[-1].w) == expected


@pytest.mark.unit
def test_waits_for_neighbours_known_at_the_previous_tick():
    w = Wire()
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    w.tick(0, (0.0, 0.0, 0.0), ref, [(5, (1.0, 0.0, 0.0))])
    assert len(w.cmds) == 1
    # tick 1: robot 5 was within R + 2L at tick 0, so the agent waits for its state_1
    w.put(keys.leader_ref(F), Ref(t=0.02, seq=1, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    w.put(keys.robot_pose(F, CFG.id), Pose(t=0.02, seq=1, x=0.0, y=0.0, theta=0.0))
    assert not w.agent.tick_lockstep()
    assert w.agent.waiting == {5}
    w.put(keys.cell(F, 0, 0, 5), State(id=5, t=0.02, seq=1, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False))
    assert w.agent.tick_lockstep()
    assert len(w.cmds) == 2


@pytest.mark.unit
@pytest.mark.parametrize("distance, awaited", [(2.15, True), (2.25, False)])
def test_the_wait_reach_follows_the_largest_R_of_any_body(distance, awaited):
    """An obstacle with R = 2 makes the law's reach 2 m (the governor counts robots that close), so
    with cells of 2.3 m (L = 0.1 m) the agent waits for robots within 2.2 m at the previous tick."""
    cfg = protocol.replace(CFG, sense=2.3, reach=2.0)
    w = Wire(cfg)
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    w.put(keys.leader_ref(F), Ref(t=0.0, seq=0, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    w.put(keys.robot_pose(F, cfg.id), Pose(t=0.0, seq=0, x=0.0, y=0.0, theta=0.0))
    w.agent.tick_lockstep()
    w.put(keys.cell(F, *keys.cell_of(distance, 0.0, 2.3), 5),
          State(id=5, t=0.0, seq=0, x=distance, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False))
    w.put(keys.world_clock(F), Clock(t=0.0, seq=0, epoch=0.0, speed=1.0))
    assert w.agent.tick_lockstep()
    w.put(keys.leader_ref(F), Ref(t=0.02, seq=1, x=0.0, y=0.0, theta=0.0, v=ref[3], w=0.0))
    w.put(keys.robot_pose(F, cfg.id), Pose(t=0.02, seq=1, x=0.0, y=0.0, theta=0.0))
    assert w.agent.tick_lockstep() is not awaited
    assert w.agent.waiting == ({5} if awaited else set())


@pytest.mark.unit
def test_a_robot_whose_token_goes_is_a_static_obstacle_and_not_awaited():
    w = Wire()
    tok = w.probe.token(keys.alive(F, "robot", 5))
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    w.tick(0, (0.0, 0.0, 0.0), ref, [(5, (1.0, 0.2, 0.0))])
    tok.close()  # robot 5 dies
    assert w.tick(1, (0.0, 0.0, 0.0), ref, [])
    mem = [0.0] * law.M_SIZE
    mem[law.M_SCALE] = 1.0
    law_command((0.0, 0.0, 0.0), ref, 0.0, [(1.0, 0.2, 0.3, 1.2, law.KIND_ROBOT)], mem)
    expected = law_command((0.0, 0.0, 0.0), ref, CFG.dt, [(1.0, 0.2, 0.3, 1.2, law.KIND_OBSTACLE)], mem)
    assert (w.cmds[1].v, w.cmds[1].w) == expected
    assert w.agent.neighbours == 0  # robots counted; the dead one is a body, not a neighbour


@pytest.mark.unit
def test_subscriptions_follow_the_cell_and_keep_the_old_block_one_tick():
    w = Wire()
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    w.tick(0, (0.1, 0.1, 0.0), ref)
    assert w.agent.subscribed_cells == robot.block(0, 0)
    w.tick(1, (1.6, 0.1, 0.0), ref)  # moved into cell (1, 0)
    assert w.agent.subscribed_cells == robot.block(0, 0) | robot.block(1, 0)
    assert w.states[-1].seq == 1  # and published its state on the new cell
    w.tick(2, (1.7, 0.1, 0.0), ref)
    assert w.agent.subscribed_cells == robot.block(1, 0)


class HintBus(MemoryBus):
    def __init__(self, net):
        super().__init__(net)
        self.hinted: list[str] = []

    def hint(self, key):
        self.hinted.append(key)


@pytest.mark.unit
def test_the_cell_keys_a_robot_hears_are_hinted_to_its_bus_once_each():
    """ZenohBus.hint: zenoh resolves a hinted key's route once. Every neighbour's cell key the agent
    heard goes to its bus at its next tick, once; a key it never heard does not."""
    w = Wire()
    w.agent.close()
    bus = HintBus(w.net)
    w.agent = robot.Agent(bus, CFG, F, wait_timeout=60.0)
    w.agent.start([])
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    nbs = [(7, (1.1, -0.3, 0.0)), (1, (-0.8, 0.2, 1.0))]
    w.tick(0, (0.1, 0.1, 0.0), ref, nbs)
    assert bus.hinted == []  # heard during tick 0: hinted when the next tick starts
    w.tick(1, (0.1, 0.1, 0.0), ref, nbs)
    heard = {keys.cell(F, *keys.cell_of(x, y, CFG.sense), j) for j, (x, y, _) in nbs}
    assert sorted(bus.hinted) == sorted(heard)
    w.tick(2, (0.1, 0.1, 0.0), ref, [(7, (1.6, -0.3, 0.0))] + nbs[1:])  # robot 7 moved into the next cell
    w.tick(3, (0.1, 0.1, 0.0), ref, nbs[1:])
    assert sorted(bus.hinted) == sorted(heard | {keys.cell(F, 1, -1, 7)}) and len(bus.hinted) == 3
    # a stranger's flood of new keys in its cells (each a robot id in each cell): hinted HINTS_PER_TICK a tick
    # at most, in the order they came
    flood = [keys.cell(F, cx, cy, j) for j in (0, 2, 4, 5, 6, 8, 9, 10, 11, 12) for cx in (-1, 0, 1) for cy in (-1, 0, 1)]
    flood = [key for key in flood if key not in bus.hinted][:robot.HINTS_PER_TICK + 10]
    for key in flood:
        w.probe.put(key, b"\xc1")  # garbage: refused and counted, but its key was parsed
    for k, total in ((4, 3 + robot.HINTS_PER_TICK), (5, 3 + len(flood)), (6, 3 + len(flood))):
        w.tick(k, (0.1, 0.1, 0.0), ref, nbs[1:])
        assert len(bus.hinted) == total
    assert bus.hinted[3:] == flood
    w.agent.close()


@pytest.mark.unit
def test_bad_messages_are_dropped_counted_and_never_reach_the_law():
    w = Wire()
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    w.tick(0, (0.0, 0.0, 0.0), ref)
    bad = [
        (keys.robot_pose(F, CFG.id), b"\xc1garbage"),
        (keys.leader_ref(F), protocol.encode(Pose(t=0.0, seq=1, x=0.0, y=0.0, theta=0.0))),  # wrong kind
        (keys.cell(F, 0, 0, 8), protocol.encode(State(id=9, t=0.02, seq=1, x=0.5, y=0.0, theta=0.0, r=0.3, R=1.2,
                                                      frozen=False))),  # id in key != id in payload
        (keys.cell(F, 0, 0, 8), b"\x81\xa1v\x01"),  # a map without kind
    ]
    for key, payload in bad:
        w.probe.put(key, payload)
    import msgpack

    nan_pose = msgpack.packb({"v": 1, "kind": "pose", "t": 0.02, "seq": 1, "x": math.nan, "y": 0.0, "theta": 0.0})
    w.probe.put(keys.robot_pose(F, CFG.id), nan_pose)
    assert w.agent.bad.count == 5
    assert 8 not in w.agent.table and 9 not in w.agent.table
    assert w.agent.pose.seq == 0  # the NaN pose was refused
    assert w.tick(1, (0.0, 0.0, 0.0), ref)  # and the agent goes on
    assert w.statuses[-1].bad == 5 or w.agent.bad.count == 5


def _capped(v, om, V):
    """(v, w) scaled together to the speed bound V (the real-time rule keeps the law's path)."""
    f = min(1.0, V / abs(v)) if v else 1.0
    return v * f, om * f


@pytest.mark.unit
def test_real_time_tick_uses_the_newest_data_and_advances_the_reference():
    cfg = protocol.replace(CFG, lockstep=False)
    w = Wire(cfg)
    w.put(keys.leader_ref(F), Ref(t=1.0, seq=50, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    # just started: it listens for LISTEN_PERIODS control periods, commanding 0 (states still on their way)
    for k in range(robot.LISTEN_PERIODS):
        w.put(keys.robot_pose(F, cfg.id), Pose(t=0.94 + 0.02 * k, seq=47 + k, x=-1.0, y=0.0, theta=0.0))
        assert w.agent.tick_realtime(0.94 + 0.02 * k)
        assert (w.cmds[-1].v, w.cmds[-1].w) == (0.0, 0.0)
    w.put(keys.robot_pose(F, cfg.id), Pose(t=1.0, seq=50, x=-1.0, y=0.0, theta=0.0))
    assert w.agent.tick_realtime(1.1)
    # the leader moved 0.05 m along its heading since its last message; the law runs as in lock-step (its
    # governor's horizon the period), then within the speed bound (nothing near holds it back)
    v, om = _capped(*law_command((-1.0, 0.0, 0.0), (0.05, 0.0, 0.0, 0.5, 0.0), 1.1, [], cfg=cfg), cfg.v_bound)
    assert w.cmds[-1].v == pytest.approx(v, abs=1e-15) and w.cmds[-1].w == pytest.approx(om, abs=1e-15)
    assert w.agent.horizon_s == cfg.dt
    # the command is valid from now for at least three periods, and the state says how far it can take the robot
    assert 1.1 + 3 * cfg.dt <= w.cmds[-1].until <= 1.1 + safety.VALIDITY_MAX_S
    plan = safety.Plan(1.0, 1.1, w.cmds[-1].until, 0.0, 1.0)
    assert w.states[-1].stop == pytest.approx(plan.reach(abs(v))) and w.states[-1].still == 0.0
    assert w.cmds[-1].t == 1.0  # the time of the pose it answers


@pytest.mark.unit
def test_a_base_that_keeps_a_command_longer_than_its_validity_makes_the_robot_s_reach_longer():
    """A ROS 2 base with its own cmd_vel timeout (the inventory's cmd_timeout) executes the last command that long
    should the agent die: the robot's reach (its state's `stop`) counts it, its command keeps its validity, and it
    goes no faster (a longer reservation asks more room of robots it has not heard)."""
    from swarm.drives.sim import SimDrive

    class SlowBase(SimDrive):
        base_timeout_s = 0.5

    cfg = protocol.replace(CFG, lockstep=False)
    reach = {}
    for drive_cls in (SimDrive, SlowBase):
        w = Wire(cfg)
        w.agent.close()
        w.agent = robot.Agent(MemoryBus(w.net), cfg, F, drive=drive_cls(MemoryBus(w.net), F, cfg.id))
        w.agent.start([])
        w.agent._first_pose_t = 0.0
        w.put(keys.leader_ref(F), Ref(t=1.0, seq=50, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
        w.put(keys.robot_pose(F, cfg.id), Pose(t=1.0, seq=50, x=-1.0, y=0.0, theta=0.0))
        assert w.agent.tick_realtime(1.0)
        reach[drive_cls.__name__] = (w.states[-1].stop, w.agent.last_cmd.v, w.agent.last_cmd.until)
        w.agent.close()
    (stop0, v0, until0), (stop1, v1, until1) = reach["SimDrive"], reach["SlowBase"]
    assert v0 >= v1 > 0.0 and until0 == until1 < 1.5
    assert stop1 >= v1 * 0.5 > stop0


@pytest.mark.unit
def test_a_real_time_robot_blocked_by_a_neighbour_stands_turns_in_place_and_promises_to_stand():
    """A neighbour 0.9 m ahead whose state is 0.5 s old may be anywhere within V x (that age plus this robot's
    reservation): no forward motion is safe, so the robot stands (turning in place as the law asks), says so in
    its state (`still`, a time ahead) and keeps to it: its next command moves it no more, whatever the law wants,
    until that time."""
    from swarm.core.clock import FakeClock

    cfg = protocol.replace(CFG, lockstep=False)
    clock = FakeClock()
    w = Wire(cfg)
    w.agent.close()
    w.agent = robot.Agent(MemoryBus(w.net), cfg, F, clock=clock)
    w.agent.start([])
    w.agent._first_pose_t = 0.0  # past the listening start
    w.agent.epoch, w.agent.speed = clock.time() - 2.0, 1.0  # the swarm's clock reads 2.0 now
    w.put(keys.leader_ref(F), Ref(t=2.0, seq=100, x=5.0, y=0.5, theta=0.0, v=0.5, w=0.0))
    w.put(keys.cell(F, 0, 0, 8), State(id=8, t=1.5, seq=75, x=0.9, y=0.02, theta=0.0, r=0.3, R=1.2, frozen=False))
    w.put(keys.robot_pose(F, cfg.id), Pose(t=2.0, seq=100, x=0.0, y=0.0, theta=0.0))
    w.agent._take_inboxes()
    assert w.agent.tick_realtime(2.0)
    law_v, law_w = law_command((0.0, 0.0, 0.0), (5.0, 0.5, 0.0, 0.5, 0.0), 2.0,
                               [(0.9, 0.02, 0.3, 1.2, law.KIND_ROBOT)], cfg=cfg)
    assert law_v > 0  # the law drives it at the neighbour
    assert w.cmds[-1].v == 0.0 and w.cmds[-1].w != 0.0  # stands, turns in place
    still = w.states[-1].still
    assert still > 2.0 and w.agent.held == 1
    clock.advance(0.02)
    w.put(keys.robot_pose(F, cfg.id), Pose(t=2.02, seq=101, x=0.0, y=0.0, theta=0.3))
    w.put(keys.cell(F, 0, 0, 8), State(id=8, t=2.02, seq=101, x=3.0, y=3.0, theta=0.0, r=0.3, R=1.2, frozen=False))
    assert w.agent.tick_realtime(2.02)  # the neighbour is gone, but the promise holds
    assert w.cmds[-1].v == 0.0 and w.states[-1].still == still
    clock.advance(still - 2.02 + 0.01)
    w.put(keys.robot_pose(F, cfg.id), Pose(t=still + 0.01, seq=102, x=0.0, y=0.0, theta=0.3))
    assert w.agent.tick_realtime(still + 0.01)
    assert w.cmds[-1].v > 0.0 and w.states[-1].still == 0.0  # past its promise, free to go
    w.agent.close()


@pytest.mark.unit
def test_a_neighbour_not_heard_is_kept_however_old_until_news_puts_it_beyond_the_cells_this_robot_hears():
    """The knowledge rule: not hearing a robot says nothing of where it is (its link may be stalled or its session
    down), so a neighbour whose newest state lies in the block of cells this robot hears is kept however old,
    its motion bound growing with its age (the safety rule holds this robot back); a newer state that puts it
    outside the block (it moved on) takes it as away, until one puts it back; a partition of the run's faults
    that cuts it off keeps it known whatever its state says."""
    from swarm.core.clock import FakeClock
    from swarm.core.faults import Partition

    cfg = protocol.replace(CFG, lockstep=False, v_bound=1.0)
    side = cfg.sense
    for partition in (False, True):
        clock = FakeClock()
        parts = (Partition(groups=((cfg.id,), (7, 8)), start=0.0, end=100.0),) if partition else ()
        agent = robot.Agent(MemoryBus(MemoryNet()), cfg, F, clock=clock, partitions=parts)
        agent.start([])
        agent.epoch, agent.speed = clock.time(), 1.0
        for j, x in ((7, 1.3), (8, 0.4)):
            agent.table[j] = State(id=j, t=0.0, seq=1, x=x, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False)
            agent.rx[j] = (0.0, clock.monotonic())

        def used(t):
            with agent.lock:
                out = agent._rt_bodies(0.0, 0.0, t, t + 0.2)
            return sorted(x for x, k in zip(out[0], out[4]) if k == law.KIND_ROBOT), sorted(b[0] for b in out[8])

        assert used(0.0) == ([0.4, 1.3], [0.4, 1.3])
        clock.advance(60.0)  # a minute without a word: both kept, each a disk 60 m wide by now
        robots, bounds = used(60.0)
        assert robots == [0.4, 1.3] and bounds == [0.4, 1.3] and agent.forgotten == 0
        with agent.lock:  # 7's state as it left: two cells on, out of the block this robot hears
            agent._take_one(State(id=7, t=60.0, seq=2, x=2.2 * side, y=0.0, theta=0.0, r=0.3, R=1.2,
                                  frozen=False), keys.cell(F, 0, 0, 7))
        robots, bounds = used(60.0)
        assert robots == [0.4] and bounds == ([0.4, 2.2 * side] if partition else [0.4])
        assert agent.forgotten == (0 if partition else 1) and (7 in agent.away) != partition
        with agent.lock:  # and back in
            agent._take_one(State(id=7, t=60.1, seq=3, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False),
                            keys.cell(F, 0, 0, 7))
        assert used(60.1)[0] == [0.4, 1.0] and 7 not in agent.away
        agent.close()


@pytest.mark.unit
def test_a_neighbour_heard_in_order_is_bounded_by_what_it_announced_and_the_gaps_in_this_robots_poses():
    """On links that keep order, a neighbour's command this robot has not heard of began no earlier than the
    newest pose came (both pass the router, the command on to the world), or in a gap of this robot's poses: a
    silent neighbour (its link stalled: so are its commands) may be within its announced stop plus V over the
    time since that pose and over each gap since its state came (plus the longest reservation), however long it
    has been silent. With a fault bus (which drops and delays messages one by one), the speed bound over its age."""
    from swarm.core.clock import FakeClock

    for faulty in (False, True):
        cfg = protocol.replace(CFG, lockstep=False, v_bound=1.0)
        clock = FakeClock()
        agent = robot.Agent(MemoryBus(MemoryNet()), cfg, F, clock=clock, counters=object() if faulty else None)
        agent.start([])
        agent.epoch, agent.speed = clock.time(), 1.0
        V, eps = cfg.v_bound, safety.CLOCK_SKEW_S

        def pose(seq, t):
            with agent.lock:
                agent._on_pose(Pose(t=t, seq=seq, x=0.0, y=0.0, theta=0.0), keys.robot_pose(F, cfg.id))

        def bound(t):
            with agent.lock:
                return agent._rt_bodies(0.0, 0.0, t, t + 0.2)[8][0][3]

        pose(1, 0.0)
        clock.advance(0.02)
        pose(2, 0.02)
        agent.table[7] = State(id=7, t=0.02, seq=1, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False,
                               stop=0.3, still=0.0)
        agent.rx[7] = (0.0, clock.monotonic() + 1e-9)  # it came after pose 2
        for k in range(3, 53):  # a second of poses, each a period on; the neighbour silent
            clock.advance(0.02)
            pose(k, 0.02 * (k - 1))
        t = 0.02 * 51
        live = V * (0.2 + (t - 0.02) + eps)
        assert bound(t) == pytest.approx(live if faulty else 0.3 + V * (0.2 + eps))
        clock.advance(0.06)  # a pose lost: states may have been missed in the 0.06 s since the last one
        pose(54, t + 0.06)
        gap = 0.3 + V * (0.2 + eps + 0.06 + safety.VALIDITY_MAX_S + safety.RAMP_S)
        assert bound(t + 0.06) == pytest.approx(V * (0.2 + (t + 0.06 - 0.02) + eps) if faulty else gap)
        for k in range(55, 105):  # heard again, a second on: it grows no more
            clock.advance(0.02)
            pose(k, t + 0.06 + 0.02 * (k - 54))
        assert bound(t + 1.06) == pytest.approx(V * (0.2 + (t + 1.06 - 0.02) + eps) if faulty else gap)
        agent.close()


@pytest.mark.unit
def test_a_real_time_robot_that_moves_to_another_cell_puts_its_states_in_the_one_it_left_for_a_while():
    """Real time: after a cell change its states go to its new cell and, for DEPART_S, to the cell it left too
    (the first at once, then every DEPART_EVERY-th: each message more makes a lossy link stall more often), so a
    robot that heard it there learns where it went; lock-step puts each state on its own cell only."""
    from swarm.core.clock import FakeClock

    for lockstep in (False, True):
        cfg = protocol.replace(CFG, lockstep=lockstep, v_bound=1.0)
        net = MemoryNet()
        agent = robot.Agent(MemoryBus(net), cfg, F, clock=FakeClock())
        seen = []
        tap = MemoryBus(net)
        tap.subscribe(f"{keys.base(F)}/cell/**", lambda k, d: seen.append(k))
        side = cfg.sense
        every = robot.DEPART_EVERY
        path = [(0.0, 0.5)] + [(0.02 * k, 1.6) for k in range(1, 2 * every + 1)] + [(0.1 + robot.DEPART_S, 1.8)]
        for seq, (t, x) in enumerate(path):
            agent._publish_state(Pose(t=t, seq=seq, x=x, y=0.0, theta=0.0), seq)
        a, b = keys.cell(F, 0, 0, cfg.id), keys.cell(F, 1, 0, cfg.id)
        assert side < 1.6 < 2 * side
        # real time: a copy on a at the change (the 1st state in b), at the 10th and the 20th; none past DEPART_S
        rt = [a, b, a] + [b] * (every - 2) + [b, a] + [b] * (every - 1) + [b, a] + [b]
        assert seen == ([a] + [b] * (2 * every + 1) if lockstep else rt)
        tap.close()
        agent.close()


@pytest.mark.integration
def test_agent_module_imports_nothing_of_the_world_nor_numpy():
    code = ("import sys, agents.robot; bad = [m for m in sys.modules if m.split('.')[0] in "
            "('world', 'numpy', 'numba', 'zenoh')]; print(','.join(bad))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == ""
    for path in Path(robot.__file__).parent.glob("*.py"):  # the process and every layer of the agent
        src = path.read_text()
        assert "world" not in [line.split()[1].split(".")[0] for line in src.splitlines()
                               if line.strip().startswith(("import ", "from "))], path


@pytest.mark.unit
def test_an_engaged_emergency_stop_is_always_obeyed_and_a_release_only_when_newer():
    """A forged release far ahead (seq 2^53) must not make the operator's later stop look old: an engage
    that decodes is obeyed whatever its t and seq (and counted when out of order); a release only when it
    moves forward and is newer than every engage obeyed."""
    w = Wire()
    stop = lambda t, seq, engaged: w.put(keys.estop(F), protocol.Estop(t=t, seq=seq, engaged=engaged, reason="test"))  # noqa: E731
    stop(1.7e9 + 5, 2**53, False)  # the forged release: adopted (nothing was engaged), the window now far ahead
    assert w.agent.estopped is None
    stop(1.7e9 + 10, 1_700_000_010_000, True)  # the operator's stop: older by the window, obeyed all the same
    assert w.agent.estopped == "test" and w.agent.bad.stale == 1
    stop(1.7e9 + 11, 1_700_000_011_000, False)  # a release is refused while the window is that far ahead
    assert w.agent.estopped == "test"
    w2 = Wire()
    stop2 = lambda seq, engaged: w2.put(keys.estop(F), protocol.Estop(t=1.7e9, seq=seq, engaged=engaged, reason="x"))  # noqa: E731
    stop2(1000, True)
    stop2(999, False)  # older than the stop obeyed: it holds
    assert w2.agent.estopped == "x"
    stop2(1001, False)
    assert w2.agent.estopped is None


@pytest.mark.unit
@pytest.mark.skipif(protocol._wire is None, reason="the compiled codec is not built here (no C compiler)")
def test_the_compiled_state_batch_takes_what_the_python_one_takes():
    """Real time: a batch of neighbour states with every case the sender windows and the agent tell apart
    (new senders, in order, duplicates, stale, far jumps repeated until they re-anchor, its own id, ahead of
    its clock, a robot whose token came back) leaves the same table, ages, windows and counts whether the
    compiled loop (swarm/proto/_wire_states.c, take_states) or the Python one takes it."""
    from swarm.core.clock import FakeClock

    cfg = protocol.replace(CFG, lockstep=False)

    def st(j, seq, t=None, x=0.5):
        return State(id=j, t=0.02 * seq if t is None else t, seq=seq, x=x, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False)

    batches = [
        [st(4, 1), st(5, 1), st(4, 2)],  # new senders (the long way), then the common case
        [st(4, 2), st(4, 1), st(5, 3), st(3, 4), st(6, 1, t=1e6)],  # duplicate, stale, ok, own id, ahead
        [st(5, 10**6), st(5, 10**6 + 1), st(5, 10**6 + 2), st(5, 4), st(4, 3, x=1.0)],  # ahead of its clock
        [st(7, 1), st(7, 1), st(4, 4), st(5, 5), st(5, 6)],  # three stale in a row that agree: its sender restarted
    ]
    results = []
    for wire in (protocol._wire, None):
        clock = FakeClock()
        agent = robot.Agent(MemoryBus(MemoryNet()), cfg, F, clock=clock)
        agent.start([])
        agent.epoch, agent.speed = clock.time() - 100.0, 1.0  # the run began 100 s ago: states are 100 s old
        agent.away.add(5)  # a newer state takes it back
        saved, protocol._wire = protocol._wire, wire
        try:
            with agent.lock:
                for b in batches:
                    clock.advance(0.1)
                    agent._on_states([(s, keys.cell(F, 0, 0, s.id)) for s in b])
        finally:
            protocol._wire = saved
        windows = {j: (w.t, w.seq, w._cand, w._run) for j, w in agent.w_state.items()}
        results.append((dict(agent.table), dict(agent.rx), set(agent.away), windows,
                        agent.states_received, agent.bad.count, agent.bad.stale, agent.bad.duplicates))
        agent.close()
    assert results[0] == results[1]
    table, _, away, _, received, bad, stale, duplicates = results[0]
    assert table[4].seq == 4 and table[5].seq == 6 and 7 in table and 3 not in table and 6 not in table
    assert away == set() and received > 0 and bad > 0 and stale > 0 and duplicates > 0


def _both_ways(seed: int, fill, act) -> list:
    """Lock-step: a fresh agent (CFG) whose table fill(agent, rng) sets, then act(agent, rng), once with the
    compiled wire module and once with the Python, from the same seeded rng; the two results."""
    import random

    results = []
    for wire in (protocol._wire, None):
        rng = random.Random(seed)
        agent = robot.Agent(MemoryBus(MemoryNet()), CFG, F)
        fill(agent, rng)
        saved, protocol._wire = protocol._wire, wire
        try:
            results.append(act(agent, rng))
        finally:
            protocol._wire = saved
            agent.close()
    return results


def _random_table(agent, rng, seqs: list[int], spread: float, awaited: float) -> None:
    """About a dozen neighbours' states with a seq of seqs, within +-spread m; 15 % dead, `awaited` waited for."""
    for j in rng.sample(range(16), 12):
        if j == CFG.id:
            continue
        agent.table[j] = State(id=j, t=1.0, seq=rng.choice(seqs), x=rng.uniform(-spread, spread),
                               y=rng.uniform(-spread, spread), theta=0.0, r=0.3, R=rng.choice([1.0, 1.2]), frozen=False)
        u = rng.random()
        if u < 0.15:
            agent.dead.add(j)
        elif u < 0.15 + awaited:
            agent.waiting.add(j)


@pytest.mark.unit
@pytest.mark.skipif(protocol._wire is None, reason="the compiled codec is not built here (no C compiler)")
def test_the_compiled_lockstep_bodies_are_the_python_ones():
    """Lock-step: bodies() over a table of live robots with this tick's state, awaited ones with an older
    state (stale), unawaited ones with an older state (left out) and dead ones, near and far, with obstacles:
    the same bodies in the same order, bit for bit, and the same counts, whether the compiled loop
    (swarm/proto/_wire_states.c, lock_bodies) or Python runs; 40 seeded tables."""
    k, seen = 50, {"fresh": 0, "stale": 0, "static": 0}

    def fill(agent, rng) -> None:
        agent.start([protocol.Obstacle(rng.uniform(-2, 2), rng.uniform(-2, 2), 0.3, 1.0) for _ in range(3)])
        _random_table(agent, rng, [k, k, k - 1], 3.0, 0.35)

    def act(agent, rng):
        with agent.lock:
            return agent.bodies(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), k), agent.oldest_state_s

    for seed in range(40):
        (a, oa), (b, ob) = _both_ways(seed, fill, act)
        assert [x.hex() for x in a[0] + a[1] + a[5]] == [x.hex() for x in b[0] + b[1] + b[5]], seed
        assert (a, oa) == (b, ob), seed
        robots, stale = a[6], a[7]
        seen["fresh"] += robots - stale
        seen["stale"] += stale
        seen["static"] += len(a[0]) - robots
    assert min(seen.values()) > 0, seen  # every kind of body was compared


@pytest.mark.unit
@pytest.mark.skipif(protocol._wire is None, reason="the compiled codec is not built here (no C compiler)")
def test_the_compiled_wait_set_is_the_python_one():
    """Lock-step, as a tick starts: the robots it waits for (live, with a state of the tick before, near where
    it was) and the states it forgets (live ones older than that), whether the compiled pass
    (swarm/proto/_wire_states.c, wait_for) or Python runs; 40 seeded tables."""
    k, seen = 50, {"waited": 0, "forgotten": 0, "kept": 0}

    def fill(agent, rng) -> None:
        agent.start([])
        agent.prev_xy = (rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5))
        _random_table(agent, rng, [k - 3, k - 2, k - 1, k - 1, k], 4.0, 0.0)

    def act(agent, rng):
        before = set(agent.table)
        agent._start_tick(protocol.Pose(t=k * CFG.dt, seq=k, x=0.0, y=0.0, theta=0.0))
        return set(agent.waiting), set(agent.table), before

    for seed in range(40):
        first, second = _both_ways(seed, fill, act)
        assert first == second, seed
        waiting, table, before = first
        seen["waited"] += len(waiting)
        seen["forgotten"] += len(before - table)
        seen["kept"] += len(table - waiting)
    assert min(seen.values()) > 0, seen  # every outcome was compared

def _lockstep_run(sink: bool, seed: int) -> tuple:
    """A lock-step agent fed 12 ticks of hostile neighbour traffic (seeded) through its bus: the compiled sink
    (swarm/proto/_wire_states.c, StateSink) or, with the sink taken away before start(), _on_state_msg. What it ends
    with, and the ticks it computed."""
    import random

    import msgpack

    rng = random.Random(seed)
    w = Wire.__new__(Wire)
    w.net = MemoryNet()
    w.agent = robot.Agent(MemoryBus(w.net), CFG, F, wait_timeout=60.0)
    assert (w.agent._state_sink is not None) == (protocol._wire is not None)
    if not sink:
        w.agent._state_sink = None
    w.agent.start([])
    w.probe = MemoryBus(w.net)
    w.cmds, w.states, w.statuses = [], [], []
    w.probe.subscribe(keys.robot_cmd(F, CFG.id), lambda k, b: w.cmds.append(protocol.decode(b, "cmd")))
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    wakes, done = [], []

    def state(j, k, x, key_id=None, seq=None, t=None):
        cx, cy = keys.cell_of(x, 0.0, CFG.sense) if math.isfinite(x) else (0, 0)
        return keys.cell(F, cx, cy, j if key_id is None else key_id), protocol.encode(State(
            id=j, t=k * CFG.dt if t is None else t, seq=k if seq is None else seq, x=x, y=0.0, theta=0.0, r=0.3,
            R=1.2, frozen=False))

    for k in range(12):
        t = k * CFG.dt
        w.put(keys.leader_ref(F), Ref(t=t, seq=k, x=ref[0], y=ref[1], theta=ref[2], v=ref[3], w=ref[4]))
        w.put(keys.robot_pose(F, CFG.id), Pose(t=t, seq=k, x=0.0, y=0.0, theta=0.0))
        w.agent.tick_lockstep()
        w.agent.wake.clear()
        msgs = [state(j, k, 0.4 * j - 1.0) for j in (1, 2, 5, 6) if rng.random() < 0.9]
        hostile = [
            state(5, k, 0.2),  # the same state again: a duplicate
            state(6, k - 2, 0.2),  # stale
            state(2, k + 2, 0.2),  # ahead of this robot's next tick
            state(CFG.id, k, 0.2),  # its own id from elsewhere
            state(7, k, 0.2, key_id=8),  # the key's id is not the payload's
            state(9, k, float("nan")),  # a NaN: the decoder refuses it
            (keys.cell(F, 0, 0, 2), b"\xc1garbage"),
            (f"swarm/{F}/cell/0/0/robot", protocol.encode(State(id=2, t=t, seq=k, x=0.0, y=0.0, theta=0.0, r=0.3,
                                                               R=1.2, frozen=False))),  # not a robot id
            (keys.cell(F, 0, 0, 10), msgpack.packb({"y": 0.0, "x": 0.5, "kind": "state", "v": protocol.VERSION,
                                                    "t": t, "seq": k, "theta": 0.0, "r": 0.3, "R": 1.2,
                                                    "frozen": False, "id": 10})),  # another key order: fine, the long way
            state(11, 10**6, 0.3, t=t),  # a seq far ahead
            state(5, k + 1, 0.2, t=1e8),  # the next tick's seq with a forged t: refused, never adopted
            state(6, k, 0.2, t=t + 0.5),  # this tick's seq, a t that is not its tick's
        ]
        msgs += rng.sample(hostile, rng.randint(0, len(hostile)))
        rng.shuffle(msgs)
        for key, data in msgs:
            w.probe.put(key, data)
            wakes.append(w.agent.wake.is_set())
        if k == 0:
            w.put(keys.world_clock(F), Clock(t=t, seq=k, epoch=0.0, speed=1.0))
        done.append(w.agent.tick_lockstep() or w.agent.tick_lockstep())
        if k == 11:
            w.agent.end()
            w.probe.put(*state(1, k + 1, 0.3))  # after the end: nothing is taken
    a = w.agent
    windows = {j: (v.t, v.seq, v._cand, v._run) for j, v in a.w_state.items()}
    out = (dict(a.table), windows, set(a.waiting), a.states_received, a.bad.count, a.bad.stale, a.bad.duplicates,
           a.k_done, [(c.seq, c.v, c.w) for c in w.cmds], wakes, done)
    a.close()
    return out


@pytest.mark.unit
@pytest.mark.skipif(protocol._wire is None, reason="the compiled codec is not built here (no C compiler)")
@pytest.mark.parametrize("seed", range(12))
def test_the_compiled_lockstep_sink_takes_what_the_python_callback_takes(seed):
    """Lock-step: neighbour states through the compiled sink or through _on_state_msg, with every case they tell
    apart (a sender's first state, the common case, duplicates, stale, ahead, its own id, a key that lies about
    the id, NaN, garbage, a key with no robot id, another key order, after the end): the same tables, windows,
    waits, counts, wake-ups after each message, commands, and ticks computed."""
    with_sink, without = _lockstep_run(True, seed), _lockstep_run(False, seed)
    assert with_sink == without
    table, _, _, received, bad, stale, duplicates, k_done, cmds, _, done = with_sink
    assert k_done >= 4 and len(cmds) == sum(done) >= 4 and received > 0 and bad > 0  # a tick missing a state waits
    assert 1 in table and CFG.id not in table


@pytest.mark.unit
@pytest.mark.parametrize("sink", [True, False])
def test_a_lockstep_state_whose_t_is_not_its_ticks_is_refused_and_the_true_ones_still_come(sink):
    """Lock-step: a state's t is its seq's tick time. A forged state of robot 5 with the next seq and t = 1e8 is
    refused and counted bad (not adopted: else every true state of 5 after it would look older and be refused);
    the true state of that tick is taken, and so are the ones after it."""
    if sink and protocol._wire is None:
        pytest.skip("the compiled codec is not built here (no C compiler)")
    w = Wire()
    if not sink:
        w.agent._state_sink = None
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    w.tick(0, (0.0, 0.0, 0.0), ref, [(5, (1.0, 0.0, 0.0))])
    bad = w.agent.bad.count
    forged = State(id=5, t=1e8, seq=1, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False)
    w.probe.put(keys.cell(F, 0, 0, 5), protocol.encode(forged))
    assert w.agent.bad.count == bad + 1 and w.agent.table[5].seq == 0 and w.agent.w_state[5].t == 0.0
    for k in (1, 2):
        w.tick(k, (0.0, 0.0, 0.0), ref, [(5, (1.0, 0.0, 0.0))])
        assert w.agent.table[5].seq == k and w.agent.table[5].t == k * CFG.dt
    assert w.agent.bad.count == bad + 1 and w.agent.k_done == 2


@pytest.mark.unit
@pytest.mark.skipif(protocol._wire is None, reason="the compiled codec is not built here (no C compiler)")
def test_the_lockstep_sink_reads_zenoh_samples_and_counts_its_own_errors():
    """The sink as zenoh calls it (a sample: key_expr, payload.to_bytes(), attachment) takes a state; an error
    inside it (here a table that refuses items) is counted as a bad message, never raised into zenoh's thread."""

    class Bytes:
        def __init__(self, b):
            self.b = b

        def to_bytes(self):
            return self.b

    class Sample:
        def __init__(self, key, payload):
            self.key_expr, self.payload, self.attachment = key, Bytes(payload), None

    w = Wire()
    sink = w.agent._state_sink
    assert sink is not None
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    w.tick(0, (0.0, 0.0, 0.0), ref, [(5, (1.0, 0.0, 0.0))])
    w.put(keys.leader_ref(F), Ref(t=0.02, seq=1, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))
    w.put(keys.robot_pose(F, CFG.id), Pose(t=0.02, seq=1, x=0.0, y=0.0, theta=0.0))
    assert not w.agent.tick_lockstep() and w.agent.waiting == {5}
    w.agent.wake.clear()
    one = protocol.encode(State(id=5, t=0.02, seq=1, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False))
    assert sink(Sample(keys.cell(F, 0, 0, 5), one)) is None
    assert w.agent.waiting == set() and w.agent.wake.is_set() and w.agent.table[5].seq == 1
    assert w.agent.tick_lockstep() and len(w.cmds) == 2

    class Refusing(dict):
        def __setitem__(self, key, value):
            raise RuntimeError("no room")

    before = w.agent.bad.count
    w.agent.table = sink.table = Refusing(w.agent.table)  # the sink takes into the table it was handed
    two = protocol.encode(State(id=5, t=0.04, seq=2, x=1.0, y=0.0, theta=0.0, r=0.3, R=1.2, frozen=False))
    w.put(keys.robot_pose(F, CFG.id), Pose(t=0.04, seq=2, x=0.0, y=0.0, theta=0.0))
    w.agent.tick_lockstep()
    assert sink(Sample(keys.cell(F, 0, 0, 5), two)) is None
    assert w.agent.bad.count == before + 1
    assert not w.agent.lock.locked()  # released on the way out of the error
    with pytest.raises(TypeError):
        sink()


@pytest.mark.unit
def test_a_real_time_robot_takes_the_still_robots_the_world_lists_as_bodies():
    """Real time: robot 5, standing where this robot never heard it (not in its table), is a static body from the
    world's bodies message, for the law and for the safety rule (static until the listing's t + BODIES_HOLD_S);
    a message older than the last one is refused by its window and changes nothing; an empty one takes it away;
    a list that stopped coming is dropped past its time to live. A dead robot the world lists is where the world
    has it, not where its last state put it; one it has not listed yet keeps its motion bound."""
    from swarm.core.clock import FakeClock
    from swarm.proto.protocol import Bodies, Body

    cfg = protocol.replace(CFG, lockstep=False)
    agent = robot.Agent(MemoryBus(MemoryNet()), cfg, F, clock=FakeClock())
    agent.start([])
    agent.epoch, agent.speed = agent.clock.time() - 1.0, 1.0  # now: t = 1.0 on the swarm's clock
    key = keys.world_bodies(F)

    def bodies(t):
        nx, ny, nr, nR, nk, na, robots, stale, safe, _delay = agent._rt_bodies(0.0, 0.0, t, t + 0.1)
        return (nx, ny, nr, nR, nk), robots, safe

    with agent.lock:
        assert bodies(1.0)[0][0] == []
        agent._on_bodies(Bodies(t=1.0, seq=50, bodies=(Body(5, 0.8, 0.1, 0.3, 1.2), Body(cfg.id, 0.0, 0.0, 0.3, 1.2),
                                                        Body(6, 40.0, 0.0, 0.3, 1.2))), key)
        (nx, ny, nr, nR, nk), robots, safe = bodies(1.0)
        # robot 5 as a static body (a dead robot, which the paper's law takes as an obstacle); not itself; not robot 6, out of this robot's cells (the rule has it, far)
        assert (nx, ny, nr, nR, nk) == ([0.8], [0.1], [0.3], [1.2], [law.KIND_DEAD]) and robots == 0
        assert (0.8, 0.1, 0.3, 0.0) in safe and (40.0, 0.0, 0.3, 0.0) in safe
        agent._on_bodies(Bodies(t=0.98, seq=49, bodies=()), key)  # older: refused, nothing changes
        assert bodies(1.0)[0][0] == [0.8] and agent.bad.stale == 1
        agent._on_bodies(Bodies(t=1.02, seq=51, bodies=()), key)  # none still any more
        assert bodies(1.02)[0][0] == []
        # a dead robot: its last state 0.2 m from where the world stopped it; until the world lists it, the law
        # has it there and the rule keeps its motion bound (the speed bound over its age and this reservation:
        # this robot's newest state of it need not be its last); then the world's place wins
        agent.table[5] = State(id=5, t=0.9, seq=45, x=0.6, y=0.1, theta=0.0, r=0.3, R=1.2, frozen=False, stop=0.3,
                               still=0.0)
        agent.dead.add(5)
        assert bodies(1.02)[0][0] == [0.6]
        assert bodies(1.02)[2] == [(0.6, 0.1, 0.3, pytest.approx(cfg.v_bound * (0.1 + safety.CLOCK_SKEW_S)))]
        agent._on_bodies(Bodies(t=1.04, seq=52, bodies=(Body(5, 0.8, 0.1, 0.3, 1.2),)), key)
        assert bodies(1.04)[0][0] == [0.8] and [b[0] for b in bodies(1.04)[2]] == [0.8]
        # listed long enough ago that it may move again: the rule lets it grow
        agent.clock.advance(safety.BODIES_HOLD_S)
        assert bodies(1.04 + safety.BODIES_HOLD_S)[2][0][3] > 0.0
        agent.clock.advance(robot.RT_BODIES_TTL_S)  # a list that stopped coming is dropped
        assert bodies(2.5)[0][0] == [0.6] and agent.rt_static == {}
    agent.close()
