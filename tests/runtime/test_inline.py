"""A lock-step robot that runs its ticks inline, on the bus thread whose message made them due
(agents.robot.Agent(inline=True), swarm.core.wake.Runner): the same commands as the loop thread's, no
subscription closed on a bus thread, and no tick lost or run twice."""

from __future__ import annotations

import queue
import random
import threading
import time

import pytest

from agents import robot
from swarm.core.wake import Runner, Wake
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.proto.protocol import Clock, Pose, Ref, State
from tests.runtime.agent_helpers import CFG, F, Wire, far_states

pytestmark = pytest.mark.unit

DEADLINE_S = 20.0


class ThreadedBus(MemoryBus):
    """A MemoryBus whose subscribers are called in order on one delivery thread of its own, never inside a
    put (as zenoh calls another session's messages); it records the thread that closes each subscription."""

    threaded_callbacks = True

    def __init__(self, net: MemoryNet) -> None:
        super().__init__(net)
        self.q: queue.Queue = queue.Queue()
        self.closed_on: list[str] = []
        self.errors_seen: list[BaseException] = []
        self.thread = threading.Thread(target=self._deliver, name="bus", daemon=True)
        self.thread.start()

    def _deliver(self) -> None:
        while (item := self.q.get()) is not None:
            fn, args = item
            try:
                fn(*args)
            except BaseException as e:  # a callback must never raise: the test fails on it
                self.errors_seen.append(e)

    def _recorded(self, h):
        close = h.close

        def closing() -> None:
            self.closed_on.append(threading.current_thread().name)
            close()

        h.close = closing
        return h

    def subscribe(self, key_expr, fn):
        return self._recorded(super().subscribe(key_expr, lambda k, b: self.q.put((fn, (k, b)))))

    def watch_alive(self, key_expr, fn):
        return self._recorded(super().watch_alive(key_expr, lambda k, up: self.q.put((fn, (k, up)))))

    def stop(self) -> None:
        self.q.put(None)
        self.thread.join(DEADLINE_S)


def _inputs(seed: int, ticks: int):
    """Seeded ticks: the robot's pose (it crosses cells back and forth, so subscriptions are released and taken
    back), the
    reference, and its neighbours' states (two awaited, one far away, missing now and then)."""
    rng = random.Random(seed)
    out = []
    for k in range(ticks):
        x = 1.2 + 0.09 * (k % 20 if k % 20 <= 10 else 20 - k % 20) + rng.uniform(-0.005, 0.005)  # L = 0.1 a tick at most
        pose = (x, 0.1 * rng.random(), 0.3)
        ref = (x + 0.5, 0.0, 0.0, 0.5, 0.02)
        nbs = [(j, (x + dx + rng.uniform(-0.02, 0.02), dy, 0.0)) for j, dx, dy in
               ((1, -0.9, 0.2), (5, 0.8, -0.3), (9, 4.0, 4.0)) if not (j == 9 and rng.random() < 0.3)]
        out.append((pose, ref, nbs))
    return out


def _state_msg(j, k, x, y, th):
    cx, cy = keys.cell_of(x, y, CFG.sense)
    return keys.cell(F, cx, cy, j), protocol.encode(State(id=j, t=k * CFG.dt, seq=k, x=x, y=y, theta=th, r=0.3,
                                                          R=1.2, frozen=False))


def _loop_run(inputs) -> tuple[list, set]:
    """The reference: the loop thread computes every tick (Wire.tick)."""
    w = Wire()
    for k, (pose, ref, nbs) in enumerate(inputs):
        assert w.tick(k, pose, ref, nbs)
    out = [(c.seq, c.v, c.w) for c in w.cmds], w.agent.subscribed_cells
    w.agent.close()
    return out


def _inline_run(inputs) -> tuple[list, set, robot.Agent, ThreadedBus, threading.Thread]:
    """The same ticks to an inline agent whose loop runs on a thread of its own, each tick's pose sent once
    the previous command came (the world's order)."""
    net = MemoryNet()
    bus = ThreadedBus(net)
    agent = robot.Agent(bus, CFG, F, wait_timeout=60.0, inline=True)
    assert isinstance(agent.kick, Runner)
    agent.start([])
    probe = MemoryBus(net)
    cmds: queue.Queue = queue.Queue()
    probe.subscribe(keys.robot_cmd(F, CFG.id), lambda k, b: cmds.put(protocol.decode(b, "cmd")))
    stop = threading.Event()
    loop = threading.Thread(target=robot._loop_lockstep, args=(agent, stop), name="loop", daemon=True)
    loop.start()
    got = []
    for k, (pose, ref, nbs) in enumerate(inputs):
        t = k * CFG.dt
        probe.put(keys.leader_ref(F), protocol.encode(Ref(t=t, seq=k, x=ref[0], y=ref[1], theta=ref[2], v=ref[3],
                                                          w=ref[4])))
        probe.put(keys.robot_pose(F, CFG.id), protocol.encode(Pose(t=t, seq=k, x=pose[0], y=pose[1], theta=pose[2])))
        for j, (x, y, th) in nbs:
            probe.put(*_state_msg(j, k, x, y, th))
        if k == 0:  # the rest of the run (Wire.tick's), and the start barrier
            for key, data in far_states(k, CFG, {j for j, _ in nbs}):
                probe.put(key, data)
            probe.put(keys.world_clock(F), protocol.encode(Clock(t=t, seq=k, epoch=0.0, speed=1.0)))
        c = cmds.get(timeout=DEADLINE_S)
        got.append((c.seq, c.v, c.w))
    cells = agent.subscribed_cells
    stop.set()
    loop.join(DEADLINE_S)
    return got, cells, agent, bus, loop


@pytest.mark.timeout(120)
@pytest.mark.parametrize("seed", range(3))
def test_an_inline_robot_commands_what_the_loop_thread_commands(seed):
    inputs = _inputs(seed, 40)
    want_cmds, want_cells = _loop_run(inputs)
    got, cells, agent, bus, loop = _inline_run(inputs)
    try:
        assert not loop.is_alive() and bus.errors_seen == [] and agent.kick.error is None
        assert got == want_cmds and len(got) == 40  # bit for bit, every tick once
        assert cells == want_cells
        assert agent.ticks == 40 and agent.bad.count == 0
        assert agent.kick.cpu_s > 0.0 and agent.loop_cpu_s >= agent.kick.cpu_s
        # the robot crossed cells, and every subscription it let go was closed by its loop, never on the bus's thread
        assert bus.closed_on and set(bus.closed_on) == {"loop"}
        assert agent._closing == {}
    finally:
        agent.close()
        bus.stop()


@pytest.mark.timeout(60)
def test_an_error_in_an_inline_tick_ends_the_loop_with_it():
    """A tick that raises on the bus's thread: the bus thread goes on, the loop thread raises the error."""
    net = MemoryNet()
    bus = ThreadedBus(net)
    agent = robot.Agent(bus, CFG, F, wait_timeout=60.0, inline=True)
    agent.start([])

    def broken():
        raise RuntimeError("the tick broke")

    agent.kick._work = broken
    errors = []

    def loop():
        try:
            robot._loop_lockstep(agent, threading.Event())
        except RuntimeError as e:
            errors.append(e)

    t = threading.Thread(target=loop, daemon=True)
    t.start()
    MemoryBus(net).put(keys.robot_pose(F, CFG.id), protocol.encode(Pose(t=0.0, seq=0, x=0.0, y=0.0, theta=0.0)))
    t.join(DEADLINE_S)
    assert not t.is_alive() and [str(e) for e in errors] == ["the tick broke"] and bus.errors_seen == []
    agent.close()
    bus.stop()


@pytest.mark.timeout(60)
def test_a_runner_runs_its_work_on_one_thread_at_a_time_and_loses_no_set():
    """Four threads each count a set, set() the runner and wait until a work() that began after their count
    has run (work() reads the count when it begins), as a callback that made a tick due needs that tick run.
    work() never runs on two threads at once, and no thread waits in vain: a set() that found work() under
    way on another thread has that thread run it once more."""
    inside, overlaps, seen, sets = [0], [0], [0], [0]
    cond = threading.Condition()
    missed = []

    def work():
        inside[0] += 1
        if inside[0] > 1:
            overlaps[0] += 1
        with cond:
            begun = sets[0]
        time.sleep(0.0002)  # lets the GIL go: the other threads come and find it busy
        inside[0] -= 1
        with cond:
            seen[0] = max(seen[0], begun)
            cond.notify_all()

    r = Runner(work, Wake())

    def setter():
        for _ in range(1000):
            with cond:
                sets[0] += 1
                mine = sets[0]
            r.set()
            with cond:
                if not cond.wait_for(lambda: seen[0] >= mine, DEADLINE_S / 4):
                    missed.append(mine)
                    return

    threads = [threading.Thread(target=setter) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(DEADLINE_S)
    assert not any(t.is_alive() for t in threads)
    assert missed == [] and overlaps[0] == 0 and seen[0] == sets[0] == 4000 and r.error is None and r.cpu_s > 0.0


def test_a_stopped_runner_runs_nothing():
    ran = []
    r = Runner(lambda: ran.append(1), Wake())
    r.set()
    assert ran == [1] and r.stop(1.0)
    r.set()
    assert ran == [1]


def _realtime_run(inline: bool, seed: int, periods: int = 30) -> tuple[list, robot.Agent, ThreadedBus]:
    """A real-time robot on a fake clock, its simulated drive's poses a period apart (it crosses cells), with
    its neighbours' states before each pose; after the last pose the clock moves on 1.5 periods, so the
    waker makes a step without a pose. Inline, the steps run on the bus's thread and the waker's; else on
    the loop thread, which blocks on the drive's inbox. Each command is awaited before the clock moves on."""
    from swarm.core.clock import FakeClock
    from swarm.drives.sim import SimDrive

    cfg = protocol.replace(CFG, lockstep=False)
    net = MemoryNet()
    bus = ThreadedBus(net)
    clock = FakeClock()
    agent = robot.Agent(bus, cfg, F, clock=clock, drive=SimDrive(bus, F, cfg.id), inline=inline)
    assert isinstance(agent.kick, Runner) == inline
    agent.start([])
    probe = MemoryBus(net)
    cmds: queue.Queue = queue.Queue()
    probe.subscribe(keys.robot_cmd(F, cfg.id), lambda k, b: cmds.put(protocol.decode(b, "cmd")))
    probe.put(keys.world_clock(F), protocol.encode(Clock(t=0.0, seq=0, epoch=clock.epoch, speed=1.0)))
    stop = threading.Event()
    loop = threading.Thread(target=robot._loop_realtime, args=(agent, stop), name="loop", daemon=True)
    loop.start()
    got = []
    for k, (pose, ref, nbs) in enumerate(_inputs(seed, periods)):
        t = k * cfg.dt
        clock.elapsed = t
        probe.put(keys.leader_ref(F), protocol.encode(Ref(t=t, seq=k, x=ref[0], y=ref[1], theta=ref[2], v=ref[3],
                                                          w=ref[4])))
        for j, (x, y, th) in nbs:
            probe.put(*_state_msg(j, k, x, y, th))
        probe.put(keys.robot_pose(F, cfg.id), protocol.encode(Pose(t=t, seq=k, x=pose[0], y=pose[1], theta=pose[2])))
        c = cmds.get(timeout=DEADLINE_S)
        got.append((c.t, c.v, c.w))
    clock.elapsed = (periods - 1 + robot.POSE_LATE_PERIODS) * cfg.dt  # no pose this time: a step without one
    c = cmds.get(timeout=DEADLINE_S)
    got.append((c.t, c.v, c.w))
    stop.set()
    loop.join(DEADLINE_S)
    assert not loop.is_alive() and bus.errors_seen == []
    return got, agent, bus


@pytest.mark.timeout(120)
def test_an_inline_real_time_robot_steps_as_its_loop_does():
    """Real time: the simulated drive's pose callback runs the step (and the waker a step without a pose): the
    same commands as the loop thread's, bit for bit, a step without a pose included; the cell inboxes it let
    go are closed by the loop thread."""
    want, a0, b0 = _realtime_run(False, 1)
    got, a1, b1 = _realtime_run(True, 1)
    try:
        assert got == want and len(got) == 31 and any(v != 0.0 for _, v, _ in got)
        assert a1.reckoned == a0.reckoned == 1 and a1.kick.error is None and a1.kick.cpu_s > 0.0
        assert a1.ticks == a0.ticks == 31 and a1.bad.count == 0
        assert b1.closed_on and set(b1.closed_on) == {"loop"} and a1._closing == {}
    finally:
        for a, b in ((a0, b0), (a1, b1)):
            a.close()
            b.stop()
