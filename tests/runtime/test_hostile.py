"""A hostile network (in process): crafted, absurd and out-of-window messages on every key of a running
lock-step swarm are dropped and counted, crash nothing, bloat nothing and cost no tick: the run equals
swarm sim step for step."""

from __future__ import annotations

import threading

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents import leader as leader_mod
from agents import robot
from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from tests.runtime.harness import run_swarm

pytestmark = pytest.mark.unit

F = "t"


def _pack(d: dict) -> bytes:
    return msgpack.packb(d, use_bin_type=True)


def corpus(n: int) -> list[tuple[str, bytes]]:
    """(key, payload) of every attack of the hostile-network findings, on every key of a swarm of n robots."""
    crafted = _pack({"v": 1, "kind": [1]})  # an unhashable kind: it crashed processes
    out: list[tuple[str, bytes]] = []
    broadcast = [keys.leader_ref(F), keys.world_clock(F), keys.world_progress(F), keys.world_run(F),
                 keys.world_snapshot(F)]
    per_robot = [f(F, i) for i in range(n) for f in (keys.robot_pose, keys.robot_cmd, keys.robot_status)]
    cells = [keys.cell(F, cx, cy, i) for i in range(n) for cx in range(-6, 8) for cy in range(-12, -3)]
    for key in broadcast + per_robot + cells[::7]:
        out += [(key, crafted), (key, b""), (key, b"\xc1\xff"), (key, _pack({"v": 1, "kind": {"x": 1}}))]
    big_seq = 2**53 - 1
    for i in range(n):
        out.append((keys.robot_pose(F, i), protocol.encode(protocol.Pose(t=1.0, seq=big_seq, x=0.0, y=0.0, theta=0.0))))
        out.append((keys.robot_cmd(F, i), _pack({"v": 1, "kind": "cmd", "t": 1.0, "seq": 3, "vel": 1.7e308, "w": 0.0})))
        out.append((keys.robot_cmd(F, i), protocol.encode(protocol.Cmd(t=1.0, seq=big_seq, v=0.1, w=0.0))))
        out.append((keys.cell(F, 0, -8, i), protocol.encode(protocol.State(id=i, t=1e8, seq=big_seq, x=0.0, y=-8.0,
                                                                            theta=0.0, r=0.3, R=1.2, frozen=False))))
    out.append((keys.world_clock(F), protocol.encode(protocol.Clock(t=1.0, seq=10**9, epoch=0.0, speed=1.0))))
    out.append((keys.leader_ref(F), protocol.encode(protocol.Ref(t=1e9, seq=7, x=60.0, y=0.0, theta=0.0, v=0.5, w=0.0))))
    out.append((keys.leader_ref(F), protocol.encode(protocol.Ref(t=1.0, seq=big_seq, x=60.0, y=0.0, theta=0.0, v=0.5,
                                                                 w=0.0))))
    for j in range(n, n + 2000):  # states with ids outside the scenario (20 000 bloated a robot's tick for good)
        out.append((keys.cell(F, 0, -8, j), protocol.encode(protocol.State(id=j, t=1.0, seq=1, x=0.0, y=-8.0, theta=0.0,
                                                                            r=0.3, R=1.2, frozen=False))))
    out.append((keys.cell(F, 0, -8, 0), b"\x00" * (10 << 20)))  # a 10 MB payload
    return out


class Attacker:
    """Sends the corpus, round after round, from its own bus on the swarm's network, from the moment the
    world reports tick `start_tick` until stopped."""

    def __init__(self, net: MemoryNet, n: int, start_tick: int = 1) -> None:
        self.bus = MemoryBus(net)
        self.msgs = corpus(n)
        self.started = threading.Event()
        self.stop = threading.Event()
        self.sent = 0
        self.bus.subscribe(keys.world_progress(F), self._progress)
        self.start_tick = start_tick
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _progress(self, key: str, payload: bytes) -> None:
        try:
            if protocol.decode(payload, "progress").seq >= self.start_tick:
                self.started.set()
        except protocol.ProtocolError:
            pass  # our own junk on the progress key

    def _run(self) -> None:
        while not self.started.wait(0.05):
            if self.stop.is_set():
                return
        while not self.stop.is_set():
            for key, payload in self.msgs:
                if self.stop.is_set():
                    return
                self.bus.put(key, payload)
                self.sent += 1

    def close(self) -> None:
        self.stop.set()
        self.thread.join(10)


@pytest.mark.timeout(240)
def test_a_running_swarm_under_attack_equals_the_simulator():
    scn = scenario_file.load("paper-50hz", Overrides(robots=4, duration=4.0))
    net = MemoryNet()
    attacker = Attacker(net, scn.n, start_tick=1)
    try:
        metrics, world, agents = run_swarm(scn, net=net, timeout_s=120)
    finally:
        attacker.close()
    assert attacker.sent > 1000
    sim = Simulation(scn, record_period=scn.dt).run()
    q = np.array(world.trace).reshape(-1, scn.n, 3)
    assert np.abs(q - sim.recording.q).max() == 0.0  # a refused message costs no tick
    assert metrics["cmd_misses"] == 0 and metrics["collisions"] == 0 and metrics["lockstep_overruns"] == 0
    assert world.bad.count > 0 and metrics["bad_messages"] >= world.bad.count
    assert all(a.bad.count > 0 for a in agents)
    assert all(len(a.table) < scn.n for a in agents)  # no stranger in a robot's tables
    assert all(len(a.w_state) < scn.n for a in agents)


class Forger:
    """On each pose of each robot i (seq k), states of every other robot j with the next seq, k + 1, and a t
    far ahead (1e8) on the cell key i hears j on: adopted, such a state would make every true state of j after
    it look older to i, and i would wait for j until the watchdog. And a command for robot i of tick k with that
    t (before i's own), a reference and a clock of tick k + 1 with it."""

    def __init__(self, net: MemoryNet, n: int, sense: float) -> None:
        self.bus = MemoryBus(net)
        self.n, self.sense, self.sent = n, sense, 0
        for i in range(n):
            self.bus.subscribe(keys.robot_pose(F, i), self._pose)

    def _pose(self, key: str, payload: bytes) -> None:
        try:
            pose = protocol.decode(payload, "pose")
        except protocol.ProtocolError:
            return
        cx, cy = keys.cell_of(pose.x, pose.y, self.sense)
        i = int(key.split("/")[-2])
        if i == 0:  # once a tick: the leader's reference and the world's clock, forged the same way
            self.bus.put(keys.leader_ref(F), protocol.encode(protocol.Ref(
                t=1e8, seq=pose.seq + 1, x=pose.x, y=pose.y, theta=0.0, v=0.5, w=0.0)))
            self.bus.put(keys.world_clock(F), protocol.encode(protocol.Clock(t=1e8, seq=pose.seq + 1, epoch=0.0,
                                                                             speed=1.0)))
        # robot i's command of this very tick, before its own: taken, the true one would be late
        self.bus.put(keys.robot_cmd(F, i), protocol.encode(protocol.Cmd(t=1e8, seq=pose.seq, v=1.0, w=0.5)))
        for j in range(self.n):
            self.bus.put(keys.cell(F, cx, cy, j), protocol.encode(protocol.State(
                id=j, t=1e8, seq=pose.seq + 1, x=pose.x, y=pose.y, theta=0.0, r=0.3, R=1.2, frozen=False)))
            self.sent += 1


@pytest.mark.timeout(240)
def test_lockstep_states_with_forged_times_are_refused_and_the_run_equals_the_simulator():
    """Lock-step: a message's t is its seq's tick time (seq x dt). Forged states with the next tick's seq and
    t = 1e8, one per robot and neighbour every tick, forged commands of the tick under way, references and
    clocks, are refused and counted; none is adopted, so no true message looks older or late and no tick
    waits: the run equals swarm sim step for step."""
    scn = scenario_file.load("paper-50hz", Overrides(robots=4, duration=4.0))
    net = MemoryNet()
    forger = Forger(net, scn.n, scn.cell_side)
    metrics, world, agents = run_swarm(scn, net=net, timeout_s=120)
    assert forger.sent > 500
    sim = Simulation(scn, record_period=scn.dt).run()
    q = np.array(world.trace).reshape(-1, scn.n, 3)
    assert np.abs(q - sim.recording.q).max() == 0.0
    assert metrics["cmd_misses"] == 0 and metrics["collisions"] == 0 and metrics["lockstep_overruns"] == 0
    assert all(a.bad.count > 0 for a in agents)
    assert all(w.t is None or w.t < 1e3 for a in agents for w in a.w_state.values())  # none was adopted
    assert all(a.w_ref.t < 1e3 and a.w_clock.t < 1e3 for a in agents)
    assert world.bad.count >= forger.sent // (scn.n * scn.n)  # the forged commands, refused (not stale)


def _callbacks(net: MemoryNet):
    """Every bus callback of a lock-step agent, a real-time agent, a world and a leader, with the key it
    listens on: (key, callable(key, payload))."""
    scn = scenario_file.load("paper-50hz", Overrides(robots=3, duration=1.0))
    from world.world import World

    world = World(MemoryBus(net), scn, F, lockstep=True)
    world.start()
    cfg = robot.fetch_config(MemoryBus(net), F, 1, 1.0)
    agent = robot.Agent(MemoryBus(net), cfg, F)
    agent.start([])
    lead = leader_mod.Leader(MemoryBus(net), scn.leader.table(), scn.dt, F)
    lead.start()
    cbs = [(keys.robot_pose(F, 1), agent._on_pose_msg), (keys.leader_ref(F), agent._on_ref_msg),
           (keys.world_clock(F), agent._on_clock_msg), (keys.cell(F, 0, -8, 2), agent._on_state_msg),
           (keys.world_clock(F), lead.on_clock)]
    cbs += [(keys.robot_cmd(F, 2), world._on_cmd), ("swarm/t/robot/9/cmd", world._on_cmd)]  # as subscribed
    for tag, key in (("status", keys.robot_status(F, 2)), ("state", keys.cell(F, 0, 0, 2))):
        cbs.append((key, lambda k, b, tag=tag: world.event((tag, k, b))))
    return cbs, (world, agent, lead)


def test_the_world_wakes_its_loop_when_the_last_awaited_command_comes():
    """Lock-step: commands come on zenoh's thread (World._on_cmd). The run loop is woken by the last
    command it awaits, not before (nor by a refused, stale or foreign one), and each command is counted
    as the long way (event) counts it."""
    from world.world import World

    scn = scenario_file.load("paper-50hz", Overrides(robots=3, duration=1.0))
    world = World(MemoryBus(MemoryNet()), scn, F, lockstep=True)
    world.alive[:] = True
    world.k = 5
    world._await = 5  # as the run loop does: the tick awaited, then who has not answered it
    world._awaited = set(world._missing())

    def cmd(i, seq, v=0.1):
        world._on_cmd(keys.robot_cmd(F, i), protocol.encode(protocol.Cmd(t=seq * scn.dt, seq=seq, v=v, w=0.0)))

    cmd(0, 5)
    cmd(0, 5)  # the same again: stale
    cmd(1, 4)  # late: stale
    cmd(1, 6)  # ahead of the world: refused
    world._on_cmd(keys.robot_cmd(F, 2), b"\x93garbage")  # refused
    world._on_cmd("swarm/t/robot/9/cmd", protocol.encode(protocol.Cmd(t=0.1, seq=5, v=0.0, w=0.0)))  # not ours
    cmd(2, 5, v=1e9)  # beyond the speed limit: refused
    assert not world.wake.is_set() and world._missing() == [1, 2]
    assert world.bad.stale == 2 and world.bad.count == 4
    cmd(1, 5)
    assert not world.wake.is_set()
    cmd(2, 5)
    assert world.wake.is_set() and world._missing() == [] and sorted(world._pending) == [0, 1, 2]


def _waiting_world(n: int = 3, k: int = 5):
    """A lock-step world whose run loop waits for the commands of tick k, its bookkeeping of k done (as
    World._run_lockstep leaves it), every robot and the leader alive, and what it publishes."""
    from world.world import World

    scn = scenario_file.load("paper-50hz", Overrides(robots=n, duration=1.0))
    net = MemoryNet()
    world = World(MemoryBus(net), scn, F, lockstep=True)
    world.alive[:] = True
    world.leader_alive = True
    world.k, world.t = k, k * scn.dt
    world._await = world._inline_from = k
    world._awaited = set(world._missing())
    heard: list = []
    MemoryBus(net).subscribe(keys.robot_any(F, "pose"), lambda key, b: heard.append(protocol.decode(b, "pose")))
    return world, scn, heard


def test_the_last_awaited_command_ends_the_tick_as_the_run_loop_would():
    """Lock-step without faults: the thread of the tick's last awaited command steps every robot (with the run
    loop's function, on the same bits) and publishes the next tick's poses itself; refused, stale and foreign
    commands step nothing; the run loop is left the wait rule's check of the step."""
    from swarm.core import kinematics

    world, scn, heard = _waiting_world()
    start = [list(p) for p in world.q]

    def cmd(i, seq, v):
        world._on_cmd(keys.robot_cmd(F, i), protocol.encode(protocol.Cmd(t=seq * scn.dt, seq=seq, v=v, w=0.3)))

    cmd(0, 5, 0.2)
    cmd(1, 4, 9.0)  # late: stale
    cmd(1, 6, 9.0)  # ahead of the world: refused
    cmd(2, 5, 1e9)  # beyond the speed limit: refused
    assert world.k == 5 and not heard and world.q == start
    cmd(1, 5, 0.3)
    cmd(2, 5, 0.4)
    assert world.k == 6 and world.t == 6 * scn.dt and world.taken_over == 1 and not world._inline_busy
    assert world._await == world._inline_from == -1  # nothing more to end before the run loop's next wait
    for i, v in enumerate((0.2, 0.3, 0.4)):
        q, c = list(start[i]), [0.0, 0.0, 0.0]
        kinematics.step_pose(q, c, v, 0.3, scn.dt)
        assert world.q[i] == q and world.cmd[i] == (v, 0.3)  # bit for bit
    assert [(p.seq, p.x, p.y, p.theta) for p in heard] == [(6, *world.q[i]) for i in range(3)]
    later = world._inline_later
    assert later[0] == 5 * scn.dt + scn.dt and np.array_equal(later[1], np.array(start)[:, :2])
    assert world.wake.is_set()  # the run loop: the metrics sample of tick 6 and that check


def test_a_tick_is_left_to_the_run_loop_when_anything_else_is_due():
    """A robot lost, the leader away, or the run loop not waiting (its bookkeeping under way): the last command
    only wakes the run loop, which ends the tick its own way."""
    for what in ("lost", "leader", "busy"):
        world, scn, heard = _waiting_world()
        if what == "lost":
            world.alive[1] = False
            world._awaited = set(world._missing())
        elif what == "leader":
            world.leader_alive = False
        else:
            world._inline_from = -1
        for i in range(3):
            world._on_cmd(keys.robot_cmd(F, i), protocol.encode(protocol.Cmd(t=5 * scn.dt, seq=5, v=0.1, w=0.0)))
        assert world.k == 5 and world.taken_over == 0 and not heard and world.wake.is_set(), what


def test_poses_that_cannot_be_published_end_the_run_with_the_reason():
    world, scn, heard = _waiting_world()

    def refuse(*a, **kw):
        raise RuntimeError("session closed")

    world._publish_tick = refuse
    for i in range(3):
        world._on_cmd(keys.robot_cmd(F, i), protocol.encode(protocol.Cmd(t=5 * scn.dt, seq=5, v=0.1, w=0.0)))
    assert world.failure == "the clock and poses of tick 6 could not be published: RuntimeError: session closed"
    assert not world._inline_busy and world.wake.is_set()


_values = st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(), st.text(max_size=8),
                    st.binary(max_size=8), st.lists(st.integers(-2**63, 2**63 - 1), max_size=3))
_maps = st.dictionaries(st.sampled_from(["v", "kind", "t", "seq", "x", "y", "theta", "vel", "w", "id", "r", "R", "frozen",
                                         "epoch", "speed", "ex", "ey", "etheta", "neighbours", "stale", "bad"]),
                        st.one_of(_values, st.sampled_from(list(protocol.KINDS)), st.just(1)), max_size=12)


@settings(max_examples=150, deadline=None)
@given(payloads=st.lists(st.one_of(st.binary(max_size=64), _maps.map(_pack)), min_size=1, max_size=20),
       which=st.integers(0, 8))
def test_fuzz_every_callback_raises_nothing(payloads, which):
    """Any bytes into any callback of any process: nothing escapes (no exception reaches the bus's
    thread), and the process still takes a true message afterwards."""
    net = MemoryNet()
    cbs, (world, agent, lead) = _callbacks(net)
    key, cb = cbs[which]
    try:
        for p in payloads:
            cb(key, p)  # must not raise
        agent.w_pose.reset()
        agent._on_pose_msg(keys.robot_pose(F, 1), protocol.encode(protocol.Pose(t=0.0, seq=0, x=1.0, y=-8.0, theta=0.0)))
        assert agent.pose is not None and agent.pose.x == 1.0
    finally:
        agent.close()
        lead.close()
        world.close()


def test_hostile_corpus_into_every_callback_is_counted():
    net = MemoryNet()
    cbs, (world, agent, lead) = _callbacks(net)
    for key, cb in cbs:
        for _, payload in corpus(3)[:60]:
            cb(key, payload)
    assert world.bad.count > 0 and agent.bad.count > 0 and lead.bad.count > 0
    assert agent.pose is None and agent.ref is None and not agent.table and lead.sent == 0


class Pinner:
    """From the pose of tick `start` on: on each pose of robot 0 (tick k), runs of 3 well-formed messages far
    ahead, each within the window of the one before (a window re-anchors on such a run from a sender that
    jumped): robot 1's poses, the reference and the world's clock at ticks 10^9 + m, with t = seq x dt (the
    lock-step rule), and a run at old ticks (1, 2, 3) behind. And, once, liveliness tokens of a world and a
    leader with ids of their own (1 and 7) that come and go."""

    def __init__(self, net: MemoryNet, dt: float, start: int = 20) -> None:
        self.bus = MemoryBus(net)
        self.dt, self.start, self.sent, self.m = dt, start, 0, 0
        self.bus.subscribe(keys.robot_pose(F, 0), self._pose)

    def _runs(self, seq0: int):
        dt = self.dt
        for s in range(seq0, seq0 + 3):
            yield keys.robot_pose(F, 1), protocol.encode(protocol.Pose(t=s * dt, seq=s, x=0.0, y=0.0, theta=0.0))
            yield keys.leader_ref(F), protocol.encode(protocol.Ref(t=s * dt, seq=s, x=60.0, y=0.0, theta=0.0, v=0.5,
                                                                   w=0.0))
            yield keys.world_clock(F), protocol.encode(protocol.Clock(t=s * dt, seq=s, epoch=0.0, speed=1.0))

    def _pose(self, key: str, payload: bytes) -> None:
        try:
            k = protocol.decode(payload, "pose").seq
        except protocol.ProtocolError:
            return
        if k < self.start:
            return
        if k == self.start:
            for role, i in (("world", 1), ("leader", 7)):
                self.bus.token(keys.alive(F, role, i)).close()
        for key, msg in [*self._runs(10**9 + self.m), *self._runs(1)]:
            self.bus.put(key, msg)
            self.sent += 1
        self.m += 3


@pytest.mark.timeout(240)
def test_runs_of_messages_ahead_or_behind_of_a_receivers_own_tick_never_re_anchor_its_window():
    """A window follows a sender that jumped after 3 messages in a row, each within the window of the one
    before. A forger can send such runs too: far ahead, they would pin robot 1's pose window and the robots'
    and the leader's reference and clock windows there (every true message after them stale: a robot without a
    pose or a reference waits a second a tick; a leader would publish a reference for every tick up to 10^9);
    behind, at old ticks, likewise. A receiver judges them by its own tick first, so they never count toward
    re-anchoring; and a world's or a leader's token with another id than 0 is refused. The run equals swarm
    sim step for step, with no missed command."""
    scn = scenario_file.load("paper-50hz", Overrides(robots=4, duration=3.0))
    net = MemoryNet()
    pinner = Pinner(net, scn.dt)
    metrics, world, agents = run_swarm(scn, net=net, timeout_s=120)
    assert pinner.sent > 500
    sim = Simulation(scn, record_period=scn.dt).run()
    q = np.array(world.trace).reshape(-1, scn.n, 3)
    assert np.abs(q - sim.recording.q).max() == 0.0
    assert metrics["cmd_misses"] == 0 and metrics["failure"] is None
    assert all(a.w_ref.t < 1e3 and a.w_clock.t < 1e3 and a.w_pose.t < 1e3 for a in agents)
    assert all(a.bad.count > 0 for a in agents)


@pytest.mark.timeout(240)
def test_a_robot_dead_by_the_schedule_to_the_end_passes_the_later_references_by_uncounted():
    """Played faults: a robot killed for good (and one hung past the end) keeps its process, which hears the
    references and clocks of ticks it will never run. Past the ticks it can hear they pass it by, as states do:
    neither bad nor taken. The run equals swarm sim."""
    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=4.0, kill="5@1"))
    metrics, world, agents = run_swarm(scn, timeout_s=120)
    sim = Simulation(scn, record_period=scn.dt).run()
    assert np.abs(np.array(world.trace).reshape(-1, scn.n, 3) - sim.recording.q).max() == 0.0
    dead = next(a for a in agents if a.id == 5)
    assert dead.k_done < 60 and dead.bad.count == 0 and dead.refs_taken < 60
    assert all(a.bad.count == 0 for a in agents) and metrics["bad_messages"] == 0
