"""The robot agent's compiled loops (swarm/proto/_wire_states.c) held to their Python twins on the in-memory
bus: the real-time state batch (take_states), the lock-step bodies (lock_bodies) and wait set (wait_for) over
seeded tables, and the lock-step state sink (StateSink) against _on_state_msg under seeded hostile traffic; a
lock-step state whose t is not its tick's is refused either way; the sink reads zenoh samples and counts its
own errors. The tests that need the compiled codec skip where it is not built (no C compiler)."""

from __future__ import annotations

import math

import pytest

from agents import robot
from swarm.proto import keys, protocol
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto.protocol import Clock, Pose, Ref, State
from tests.runtime.agent_helpers import CFG, F, Wire


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
        acted = w.agent.tick_lockstep()  # the states it waits for may all be in (robot 1's, a tick ahead)
        w.agent.wake.clear()
        msgs = [state(j, k, 0.4 * j - 1.0) for j in (1, 2, 5, 6) if rng.random() < 0.9 or k == 0]
        if k == 0:  # tick 0 waits for every robot of the run: the others start far away
            w.far_states(0, but={1, 2, 5, 6})
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
            state(1, k + 1, -0.6),  # the next tick's, sent with robot 1's command (states a tick ahead): aside
        ]
        msgs += rng.sample(hostile, rng.randint(0, len(hostile)))
        rng.shuffle(msgs)
        for key, data in msgs:
            w.probe.put(key, data)
            wakes.append(w.agent.wake.is_set())
        if k == 0:
            w.put(keys.world_clock(F), Clock(t=t, seq=k, epoch=0.0, speed=1.0))
        done.append(acted or w.agent.tick_lockstep() or w.agent.tick_lockstep())
        if k == 11:
            w.agent.end()
            w.probe.put(*state(1, k + 1, 0.3))  # after the end: nothing is taken
    a = w.agent
    windows = {j: (v.t, v.seq, v._cand, v._run) for j, v in a.w_state.items()}
    out = (dict(a.table), dict(a.early), windows, set(a.waiting), a.states_received, a.bad.count, a.bad.stale, a.bad.duplicates,
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
    table, early, _, _, received, bad, stale, duplicates, k_done, cmds, _, done = with_sink
    assert k_done >= 4 and len(cmds) == sum(done) >= 4 and received > 0 and bad > 0  # a tick missing a state waits
    assert (1 in table or 1 in early) and CFG.id not in table


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
