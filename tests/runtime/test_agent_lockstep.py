"""The robot agent in lock-step on the in-memory bus: its command is the core law (bit for bit, its freeze memory
carried over ticks), whom it waits for at each tick, a robot whose token goes taken as a static obstacle, its
traffic following its cells (the subscribed block, the cell keys hinted to its bus), bad messages dropped and
counted; and, in either mode, the emergency stop (an engage always obeyed, a release only when newer) and the
agent module importing nothing of the world nor numpy. Real time: test_agent_realtime.py; the compiled loops
against the Python ones: test_agent_compiled.py."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
import sys
import time

import pytest

from agents import robot
from swarm.proto import keys, protocol
from swarm.core import law
from swarm.core.clock import FakeClock
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.core.faults import Kill
from swarm.proto.protocol import Clock, Pose, Ref, State
from tests.runtime.agent_helpers import CFG, F, Wire, law_command


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
    w.far_states(0, but={5})
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
    bus = w.rebus(HintBus)
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
    assert w.agent.table[8].seq == w.agent.table[9].seq == 0  # their far states of tick 0 (Wire.tick), not these
    assert w.agent.pose.seq == 0  # the NaN pose was refused
    assert w.tick(1, (0.0, 0.0, 0.0), ref)  # and the agent goes on
    assert w.statuses[-1].bad == 5 or w.agent.bad.count == 5


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
    """An engage that decodes is obeyed whatever its t and seq; a release only when it comes after every engage
    obeyed, by (t, seq). Judged on the robot's own clock: neither a forged release nor a forged engage far ahead
    (seq 2^53, t 1e11) pins the order, so the operator's stop and release still work."""
    w = Wire()
    w.agent.clock = clock = FakeClock(epoch=time.time())  # the robot's own clock: the operator's is unix time
    now = clock.time()
    stop = lambda t, seq, engaged: w.put(keys.estop(F), protocol.Estop(t=t, seq=seq, engaged=engaged, reason="test"))  # noqa: E731
    stop(now + 100, 2**53, False)  # a forged release far ahead: refused, counted
    assert w.agent.estopped is None and w.agent.bad.count == 1
    stop(now, int(now * 1000), True)  # the operator's stop: obeyed
    assert w.agent.estopped == "test"
    stop(now + 0.5, int(now * 1000) + 500, False)  # the operator's release
    assert w.agent.estopped is None
    stop(1e11, 2**53, True)  # a forged engage far ahead: obeyed (safety first), counted
    assert w.agent.estopped == "test" and w.agent.bad.count == 2
    stop(now + 1, int(now * 1000) + 1000, False)  # within the span it marks (now + ESTOP_SPAN_S): the stop holds
    assert w.agent.estopped == "test" and w.agent.bad.stale == 1
    clock.advance(w.agent.estop_order.span + 1)
    later = clock.time()  # the operator's release after the span: taken (before, the forged engage held for good)
    stop(later, int(later * 1000), False)
    assert w.agent.estopped is None
    w2 = Wire()
    stop2 = lambda seq, engaged: w2.put(keys.estop(F), protocol.Estop(t=1.7e9, seq=seq, engaged=engaged, reason="x"))  # noqa: E731
    stop2(1000, True)
    stop2(999, False)  # older than the stop obeyed: it holds
    assert w2.agent.estopped == "x"
    stop2(1001, False)
    assert w2.agent.estopped is None


@pytest.mark.unit
def test_an_older_reference_of_the_tick_under_way_is_stale_not_a_restart_of_the_window():
    """Lock-step: once the robot has a tick, its window restarts on a message within the ticks it can hear only
    when the window was anchored where it cannot hear. A reference of the tick under way that comes after the
    true next one (replayed, or forged with another pose) is stale, and the tick runs on the true reference: its
    command is that of a robot that never saw the forged one."""
    dt = CFG.dt
    cmds = []
    for forged in (False, True):
        w = Wire()
        ref = (1.0, 0.5, 0.0, 0.0, 0.0)
        for k in range(5):
            w.tick(k, (0.0, 0.0, 0.0), ref)
        w.put(keys.leader_ref(F), Ref(t=5 * dt, seq=5, x=1.0, y=0.5, theta=0.0, v=0.0, w=0.0))
        w.put(keys.leader_ref(F), Ref(t=6 * dt, seq=6, x=1.0, y=0.5, theta=0.0, v=0.0, w=0.0))
        w.put(keys.robot_pose(F, CFG.id), Pose(t=5 * dt, seq=5, x=0.0, y=0.0, theta=0.0))
        stale = w.agent.bad.stale
        if forged:
            w.put(keys.leader_ref(F), Ref(t=5 * dt, seq=5, x=50.0, y=50.0, theta=0.0, v=0.0, w=0.0))
            assert w.agent.refs[5].x == 1.0 and w.agent.bad.stale == stale + 1
        w.agent.tick_lockstep()
        cmds.append((w.cmds[-1].t, w.cmds[-1].v, w.cmds[-1].w))
    assert cmds[0] == cmds[1] and cmds[0][0] == 5 * dt


@pytest.mark.unit
def test_a_pose_past_the_next_tick_is_refused_though_a_reference_may_be_a_tick_early():
    """Lock-step: the world puts a pose for the next tick only, the leader a reference a tick early.
    A pose of the tick after next, taken, would make the robot skip the next tick (a missed command, a second's
    wait): it is refused and counted, and the true next pose runs the tick."""
    w = Wire()
    ref = (1.0, 0.5, 0.0, 0.0, 0.0)
    for k in range(5):
        w.tick(k, (0.0, 0.0, 0.0), ref)
    dt = CFG.dt
    bad = w.agent.bad.count
    w.put(keys.robot_pose(F, CFG.id), Pose(t=6 * dt, seq=6, x=0.0, y=0.0, theta=0.0))
    assert w.agent.bad.count == bad + 1 and w.agent.pose.seq == 4
    for k in (5, 6):  # the reference of the next tick, and the one after it a tick early: both taken
        w.put(keys.leader_ref(F), Ref(t=k * dt, seq=k, x=1.0, y=0.5, theta=0.0, v=0.0, w=0.0))
    assert w.agent.bad.count == bad + 1 and {5, 6} <= set(w.agent.refs)
    w.tick(5, (0.0, 0.0, 0.0), ref)
    assert w.cmds[-1].t == 5 * dt and w.agent.k_done == 5


class ReliabilityBus(MemoryBus):
    """Records the congestion control of every put: {key kind: set of reliable flags}."""

    def __init__(self, net):
        super().__init__(net)
        self.reliable: dict[str, set[bool]] = {}

    def put(self, key, payload, reliable=False, loopback=True, attachment=None):
        p = keys.parse(key)
        self.reliable.setdefault(p.kind if p is not None else key, set()).add(reliable)
        super().put(key, payload, reliable=reliable, loopback=loopback, attachment=attachment)


@pytest.mark.unit
def test_a_lockstep_robot_puts_its_state_and_command_reliably():
    """Lock-step: nothing a tick depends on may be dropped by zenoh's congestion control (DROP loses a message
    when a queue is busy for a millisecond, on a loaded machine): a state_0 lost so went unnoticed (the start
    barrier waits for nobody's state) and the run differed from swarm sim. State and command are put BLOCK."""
    w = Wire()
    bus = w.rebus(ReliabilityBus)
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    for k in range(3):
        assert w.tick(k, (0.1 * k, 0.1, 0.0), ref, [(7, (1.1, -0.3, 0.0))])
    assert bus.reliable["cell"] == {True} and bus.reliable["cmd"] == {True}, bus.reliable
    w.agent.close()


@pytest.mark.unit
def test_the_start_barrier_is_waited_for_past_a_ticks_wait_and_the_reference_gets_a_wait_after_the_clock():
    """clock_0 comes once every robot's state_0 is in the world, which may take longer than a tick's wait (a robot
    slow to start); the leader answers it with ref_0. A robot that went on after 1 s without them commanded zero at
    tick 0 where swarm sim moved it: the run differed from its first tick. It waits while the world is there, and
    the reference has a whole wait from the clock; without the world it goes on as before."""
    ref = Ref(t=0.0, seq=0, x=1.0, y=0.5, theta=0.2, v=0.5, w=0.05)
    for world in (True, False):
        w = Wire()
        w.agent.clock = clock = FakeClock()
        tokens = [w.probe.token(keys.alive(F, "leader"))] + ([w.probe.token(keys.alive(F, "world"))] if world else [])
        assert w.agent.world_alive == world and w.agent.leader_alive
        w.put(keys.robot_pose(F, CFG.id), Pose(t=0.0, seq=0, x=0.2, y=0.1, theta=0.4))
        w.far_states(0)
        assert not w.agent.tick_lockstep()  # tick 0 begins: it waits for the clock and the reference
        clock.advance(5 * w.agent.wait_timeout)  # the world's barrier takes 5 s
        if not world:  # nobody to wait for: on it goes, without a reference (no command), as it always did
            assert w.agent.tick_lockstep() and not w.cmds and w.agent.skipped == 1
            continue
        assert not w.agent.tick_lockstep() and not w.cmds
        w.put(keys.world_clock(F), Clock(t=0.0, seq=0, epoch=0.0, speed=1.0))
        clock.advance(0.9 * w.agent.wait_timeout)  # the leader's answer takes most of a wait: still awaited
        assert not w.agent.tick_lockstep() and not w.cmds
        w.put(keys.leader_ref(F), ref)
        assert w.agent.tick_lockstep() and w.agent._overdue == 0
        v, om = law_command((0.2, 0.1, 0.4), (ref.x, ref.y, ref.theta, ref.v, ref.w), 0.0, [])
        assert (w.cmds[0].v, w.cmds[0].w) == (v, om) != (0.0, 0.0)
        for t in tokens:
            t.close()


@pytest.mark.unit
def test_tick_0_waits_for_every_robots_state_0_even_after_the_clock_and_the_reference():
    """clock_0 says that every state_0 reached the world, not this robot: through a router, a neighbour's state_0
    may come after clock_0 and ref_0 (in CI one robot computed tick 0 without its neighbour's, and the run
    differed from swarm sim from tick 1). Tick 0 waits for the state_0 of every robot of the run, heard in every
    cell (robot 9 starts far away, in no cell this robot hears), and commands with them; then it stops hearing
    every cell. A robot whose token went is waited for all the same, as the world's barrier does (robot 7: a
    robot serving several runs, its last run's token gone, its state_0 on the way)."""
    w = Wire()
    ref = Ref(t=0.0, seq=0, x=1.0, y=0.5, theta=0.2, v=0.5, w=0.05)
    tok = w.probe.token(keys.alive(F, "robot", 7))
    tok.close()  # before tick 0
    assert w.agent._all_sub is not None  # from start(), before its token
    w.put(keys.robot_pose(F, CFG.id), Pose(t=0.0, seq=0, x=0.2, y=0.1, theta=0.4))
    w.far_states(0, but={5, 7})
    w.put(keys.world_clock(F), Clock(t=0.0, seq=0, epoch=0.0, speed=1.0))
    w.put(keys.leader_ref(F), ref)
    tok = w.probe.token(keys.alive(F, "robot", 6))
    tok.close()  # during tick 0, after its state_0 came: nothing changes
    assert not w.agent.tick_lockstep() and w.agent.waiting == {5, 7} and not w.cmds
    w.put(keys.cell(F, 0, 0, 5), State(id=5, t=0.0, seq=0, x=0.9, y=0.1, theta=0.0, r=0.3, R=1.2, frozen=False))
    assert not w.agent.tick_lockstep() and w.agent.waiting == {7}
    w.probe.token(keys.alive(F, "robot", 7))  # its new token, then its state_0
    w.far_states(0, but=set(range(16)) - {7})
    assert w.agent.tick_lockstep() and w.agent._overdue == 0
    v, om = law_command((0.2, 0.1, 0.4), (ref.x, ref.y, ref.theta, ref.v, ref.w), 0.0,
                        [(0.9, 0.1, 0.3, 1.2, law.KIND_ROBOT)])
    assert (w.cmds[0].v, w.cmds[0].w) == (v, om)
    assert w.agent._all_sub is None and w.agent.table[9].x == 1090.0


@pytest.mark.unit
@pytest.mark.parametrize("kill, listens", [(None, True), (Kill(3, 0.0), False), (Kill(3, 0.0, restart=1.0), True),
                                           (Kill(3, 2.0), True), (Kill(5, 0.0), True)])
def test_under_faults_only_a_robot_that_runs_a_tick_hears_every_cell(kill, listens):
    """A robot the schedule has dead from tick 0 for good runs no tick: hearing every state of the run would be for
    nothing (a SIGSTOPped process's router queue filling with the whole swarm's). One that runs at 0, or returns
    later (a restart: its first tick is a return), hears every cell from its start."""
    from swarm.core.faults import Faults

    faults = Faults(seed=1, kills=() if kill is None else (kill,))
    net = MemoryNet()
    agent = robot.Agent(MemoryBus(net), CFG, F, wait_timeout=60.0, faults=faults)
    agent.start([])
    assert (agent._all_sub is not None) == listens
    agent.close()


@pytest.mark.unit
def test_a_bad_message_heard_in_every_cell_is_counted_by_the_all_cells_path_only_where_no_cell_hears_it():
    """Until tick 0 is done a robot hears every cell too: a bad message on a cell it subscribes (or is letting go
    of, or a put on a wildcard, which zenoh hands every subscription it meets) is counted once, by its cell's
    path."""
    w = Wire()
    ours, theirs = keys.cell(F, 0, 0, 8), keys.cell(F, 40, 40, 8)
    assert w.agent._hears_cell(ours) and not w.agent._hears_cell(theirs)
    assert w.agent._hears_cell(f"swarm/{F}/cell/*/*/8") and w.agent._hears_cell(f"swarm/{F}/cell/0/0/abc")
    for key in (ours, theirs):
        w.probe.put(key, b"\xc1garbage")
    assert w.agent.bad.count == 2  # one each, though the first came twice


@pytest.mark.unit
def test_a_robot_whose_session_came_back_rejoins_at_the_worlds_tick_holding_still_for_it():
    """A robot stopped past its lease is lost; the world goes on and, once its token is back, waits for its
    commands again. It refused the world's poses as ahead of its own tick, so it never caught up (every later tick
    cost the world its tick timeout). Once the world's token is back, the world's next pose is taken whatever its
    tick (with its tick's time), once: it rejoins there, holding still that tick (it knows nobody's state of the
    tick before), then runs the law again. What the swarm sent ahead meanwhile passes by uncounted. The first pose
    taken in step ends the chance (the world's own session came back: its robots were not away); any other pose
    ahead is refused and counted."""
    w = Wire()
    ref = (0.0, 0.0, 0.0, 0.5, 0.0)
    world = w.probe.token(keys.alive(F, "world"))
    leader = w.probe.token(keys.alive(F, "leader"))
    for k in range(2):
        assert w.tick(k, (0.1 * k, 0.1, 0.0), ref)

    def pose(k, t=None):
        w.put(keys.robot_pose(F, CFG.id), Pose(t=k * CFG.dt if t is None else t, seq=k, x=0.2, y=0.1, theta=0.0))

    pose(50)
    assert not w.agent.tick_lockstep() and w.agent.bad.count == 1  # ahead: refused (a forger's, or a lost one)
    world.close()  # the world's session blipped: its next pose is in step, and ends the chance to skip ticks
    world = w.probe.token(keys.alive(F, "world"))
    assert w.tick(2, (0.2, 0.1, 0.0), ref)
    pose(60)
    assert not w.agent.tick_lockstep() and w.agent.bad.count == 2 and w.agent.rejoined == 0
    world.close()  # this robot's session dropped (it was stopped): every token went, and came back with it
    world = w.probe.token(keys.alive(F, "world"))
    w.put(keys.cell(F, 0, 0, 7), State(id=7, t=70 * CFG.dt, seq=70, x=0.5, y=0.5, theta=0.0, r=0.3, R=1.2,
                                        frozen=False))  # the swarm went on: ahead, passed by uncounted
    pose(60, t=0.5)  # its t is not its tick's: forged, refused and counted
    assert not w.agent.tick_lockstep() and w.agent.bad.count == 3 and w.agent.rejoined == 0
    pose(60)
    assert w.agent.tick_lockstep() and w.agent.rejoined == 1 and w.agent.bad.count == 3
    assert (w.cmds[-1].seq, w.cmds[-1].v, w.cmds[-1].w) == (60, 0.0, 0.0)  # no reference needed: it holds still
    assert w.tick(61, (0.2, 0.1, 0.0), ref)
    assert w.cmds[-1].seq == 61 and (w.cmds[-1].v, w.cmds[-1].w) == law_command((0.2, 0.1, 0.0), ref, 61 * CFG.dt, [])
    pose(90)
    assert not w.agent.tick_lockstep() and w.agent.bad.count == 4  # once only
    world.close()
    leader.close()


def _ahead_of(pose, v, w, dt=CFG.dt):
    """The pose after one world step from `pose` (compensations 0) under (v, w): what the world integrates."""
    from swarm.core import kinematics

    q, c = list(pose), [0.0, 0.0, 0.0]
    kinematics.step_pose(q, c, v, w, dt)
    return q, c


@pytest.mark.unit
def test_a_robot_ahead_sends_its_next_state_with_its_command_as_the_world_integrates_it():
    """States a tick ahead: after tick k a robot sends state_(k+1) with cmd_k, its pose the world's own step of
    cmd_k (swarm.core.kinematics, bit for bit, compensations kept over ticks), and its cells of tick k + 1 are
    subscribed before; pose_(k+1) as predicted sends no second state. The world's two steps land where it said."""
    from swarm.core import kinematics

    w = Wire(ahead=True)
    ref = (1.0, 0.5, 0.2, 0.5, 0.05)
    world, comp = [0.2, 0.1, 0.4], [0.0, 0.0, 0.0]
    for k in range(3):
        assert w.tick(k, tuple(world), ref)
        c = w.cmds[-1]
        assert c.seq == k
        kinematics.step_pose(world, comp, c.v, c.w, CFG.dt)  # the world's step
        s = w.states[-1]
        assert (s.seq, s.t, s.x, s.y, s.theta) == (k + 1, (k + 1) * CFG.dt, world[0], world[1], world[2])
        assert keys.cell_of(world[0], world[1], CFG.sense) in {(a, b) for a, b in w.agent.subscribed_cells}
    assert [s.seq for s in w.states] == [0, 1, 2, 3]  # state_0 on its pose, each later one ahead, none twice
    assert w.agent.mispredicted == 0 and w.agent.bad.count == 0


def _two_neighbours(sink):
    """A robot (through the compiled sink or the Python) that did tick 0 with robots 5 and 6 near, in cell (0, 0):
    (the Wire, its reference, its pose, the neighbours' (x, y, theta), state(j, k, x): a state of j in that cell)."""
    if sink and protocol._wire is None:
        pytest.skip("the compiled codec is not built here (no C compiler)")
    w = Wire()
    if not sink:
        w.agent._state_sink = None
    ref, pose = (1.0, 0.5, 0.2, 0.5, 0.05), (0.2, 0.1, 0.4)
    nb = {5: (1.1, -0.3, 0.0), 6: (-0.8, 0.2, 1.0)}
    assert w.tick(0, pose, ref, list(nb.items()))

    def state(j, k, x):
        return keys.cell(F, 0, 0, j), protocol.encode(State(id=j, t=k * CFG.dt, seq=k, x=x, y=nb[j][1],
                                                            theta=0.0, r=0.3, R=1.2, frozen=False))
    return w, ref, pose, nb, state


@pytest.mark.unit
@pytest.mark.parametrize("sink", [True, False])
def test_a_neighbours_state_of_the_next_tick_waits_aside_until_this_tick_is_done(sink):
    """A neighbour ahead sends state_(k+1) with cmd_k, which may come while this robot still waits at tick k, or
    before its pose_k: the law of tick k takes the neighbour's state_k (bit for bit), and tick k + 1 does not wait
    for it; a state two ticks past the one under way is refused. Through the compiled sink and the Python."""
    w, ref, pose, nb, state = _two_neighbours(sink)
    w.probe.put(*state(5, 1, nb[5][0]))  # robot 5's state_1 before this robot's pose_1: taken
    w.probe.put(*state(5, 2, 0.7))  # and its state_2, sent with its cmd_1: aside, not bad
    w.put(keys.leader_ref(F), Ref(t=CFG.dt, seq=1, x=ref[0], y=ref[1], theta=ref[2], v=ref[3], w=ref[4]))
    w.put(keys.robot_pose(F, CFG.id), Pose(t=CFG.dt, seq=1, x=pose[0], y=pose[1], theta=pose[2]))
    assert not w.agent.tick_lockstep() and w.agent.waiting == {6}
    w.probe.put(*state(5, 3, 0.6))  # two past the tick under way: refused
    assert w.agent.bad.count == 1 and w.agent.table[5].seq == 1 and w.agent.early[5].seq == 2
    w.probe.put(*state(6, 1, nb[6][0]))
    assert w.agent.tick_lockstep()
    bodies = [(nb[j][0], nb[j][1], 0.3, 1.2, law.KIND_ROBOT) for j in (5, 6)]  # by id
    mem = [0.0] * law.M_SIZE
    assert (w.cmds[0].v, w.cmds[0].w) == law_command(pose, ref, 0.0, bodies, mem)
    assert (w.cmds[1].v, w.cmds[1].w) == law_command(pose, ref, CFG.dt, bodies, mem)  # robot 5 at its state_1
    assert w.agent.table[5].seq == 2 and not w.agent.early  # tick 1 done: state_2 in the table
    w.put(keys.leader_ref(F), Ref(t=2 * CFG.dt, seq=2, x=ref[0], y=ref[1], theta=ref[2], v=ref[3], w=ref[4]))
    w.put(keys.robot_pose(F, CFG.id), Pose(t=2 * CFG.dt, seq=2, x=pose[0], y=pose[1], theta=pose[2]))
    assert not w.agent.tick_lockstep() and w.agent.waiting == {6}  # not for 5: its state_2 is here
    assert w.agent.bad.count == 1


@pytest.mark.unit
def test_a_pose_not_as_predicted_is_said_and_its_states_go_out_on_poses_from_then_on(caplog):
    """A world that did not apply cmd_k as sent (it held an older command: a miss) puts pose_(k+1) elsewhere than
    the state this robot sent ahead: it says so, counts it, sends no second state_(k+1), and from then on sends each
    state on its pose (its prediction is not the world's bits any more); its cells follow the pose it got."""
    w = Wire(ahead=True)
    ref = (1.0, 0.5, 0.2, 0.5, 0.05)
    assert w.tick(0, (0.2, 0.1, 0.4), ref)
    assert [s.seq for s in w.states] == [0, 1]
    with caplog.at_level("WARNING", logger="swarm.robot"):
        assert w.tick(1, (4.0, 0.1, 0.4), ref)  # not where the world's step of cmd_0 puts it
    assert w.agent.mispredicted == 1 and "is not the one its state 1 said ahead" in caplog.text
    assert [s.seq for s in w.states] == [0, 1]  # no state_1 again, none ahead
    assert keys.cell_of(4.0, 0.1, CFG.sense) in w.agent.subscribed_cells
    q, _ = _ahead_of((4.0, 0.1, 0.4), w.cmds[-1].v, w.cmds[-1].w)
    assert w.tick(2, tuple(q), ref)  # even where its own step would put it: on its pose
    assert [s.seq for s in w.states] == [0, 1, 2] and (w.states[-1].x, w.states[-1].y) == (q[0], q[1])
    assert w.agent.mispredicted == 1


@pytest.mark.unit
@pytest.mark.parametrize("sink", [True, False])
def test_a_tick_left_for_a_newer_pose_takes_the_states_kept_aside_for_the_new_one(sink):
    """The world went on without this robot's cmd_1 (its --tick-timeout: robot 6 never answered tick 1): pose_2
    comes while tick 1 still waits. Robot 5's state_2, sent ahead with its cmd_1 and kept aside, is tick 2's: tick 2
    takes it and does not wait for robot 5 (nor compute without it)."""
    w, ref, pose, nb, state = _two_neighbours(sink)
    for k in (1, 2):
        w.put(keys.leader_ref(F), Ref(t=k * CFG.dt, seq=k, x=ref[0], y=ref[1], theta=ref[2], v=ref[3], w=ref[4]))
    w.put(keys.robot_pose(F, CFG.id), Pose(t=CFG.dt, seq=1, x=pose[0], y=pose[1], theta=pose[2]))
    assert not w.agent.tick_lockstep() and w.agent.waiting == {5, 6}
    w.probe.put(*state(5, 1, 1.1))
    w.probe.put(*state(5, 2, 1.05))  # robot 5 ahead: its state_2 with its cmd_1, kept aside
    assert w.agent.early[5].seq == 2
    w.put(keys.robot_pose(F, CFG.id), Pose(t=2 * CFG.dt, seq=2, x=pose[0], y=pose[1], theta=pose[2]))
    # robot 6's newest state is of tick 0: tick 2 neither waits for it nor takes it (the run has a miss already)
    assert w.agent.tick_lockstep() and w.agent.k_done == 2
    assert w.agent.table[5].seq == 2 and not w.agent.early and w.agent.bad.count == 0
    bodies = [(1.05, nb[5][1], 0.3, 1.2, law.KIND_ROBOT)]
    mem = [0.0] * law.M_SIZE
    law_command(pose, ref, 0.0, [(nb[j][0], nb[j][1], 0.3, 1.2, law.KIND_ROBOT) for j in (5, 6)], mem)
    assert (w.cmds[-1].seq, w.cmds[-1].v, w.cmds[-1].w) == (2, *law_command(pose, ref, 2 * CFG.dt, bodies, mem))


@pytest.mark.unit
def test_a_robot_not_sending_ahead_keeps_the_block_it_left_for_one_more_tick():
    """After a pose not as predicted a robot's prediction is no longer the world's bits, but still says where its
    cells go: it moves them ahead once a tick, and the pose that comes a few bits off in the same cell does not
    move them again (that let the block around its cell of the tick before go a tick early, and robot 5, waited
    for, stepped into it unheard: a wait of wait_timeout)."""
    w = Wire(ahead=True)
    ref = (3.0, 0.5, 0.0, 2.0, 0.0)  # a leader ahead in +x: the robot drives +x
    a = w.agent
    assert w.tick(0, (0.0, 0.2, 0.0), ref, [(5, (0.0, 0.2, 0.0))])
    assert w.tick(1, (0.5, 0.2, 0.0), ref, [(5, (0.05, 0.2, 0.0))])  # not where its step of cmd_0 said
    assert a.mispredicted == 1 and not a._exact
    assert w.tick(2, (1.45, 0.2, 0.0), ref, [(5, (0.06, 0.2, 0.0))])  # cell (0, 0); robot 5 1.39 m away
    p = list(a._pred)
    assert keys.cell_of(p[0], p[1], CFG.sense) == (1, 0)  # its prediction of tick 3
    w.put(keys.leader_ref(F), Ref(t=3 * CFG.dt, seq=3, x=ref[0], y=ref[1], theta=ref[2], v=ref[3], w=ref[4]))
    w.put(keys.robot_pose(F, CFG.id), Pose(t=3 * CFG.dt, seq=3, x=p[0] + 1e-15, y=p[1], theta=p[2]))
    assert not a.tick_lockstep() and a.waiting == {5}
    a.close_released()
    assert {(cx, cy) for cx in (-1, 0, 1) for cy in (-1, 0, 1)} <= a.subscribed_cells  # the block it left
    assert w.states[-1].seq == 3 and w.states[-1].x == p[0] + 1e-15  # on its pose
    w.put(keys.cell(F, -1, 0, 5), State(id=5, t=3 * CFG.dt, seq=3, x=-0.02, y=0.2, theta=0.0, r=0.3, R=1.2,
                                          frozen=False))
    assert a.tick_lockstep() and a.table[5].seq == 3
