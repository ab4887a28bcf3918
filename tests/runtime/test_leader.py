"""The leader process on the in-memory bus."""

import threading
import time

import numpy as np
import pytest

from agents import leader as leader_mod
from swarm.proto import keys, protocol
from swarm.core import kinematics
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto.protocol import Clock
from swarm.core.scenario import Leader, Segment

pytestmark = pytest.mark.unit

F = "t"


@pytest.mark.timeout(30)
def test_realtime_refs_every_period_and_at_every_segment_start():
    """Real time: a reference every REF_PERIOD_S and one at each segment start, each the leader's exact
    state at its time, so an agent that advances the newest along its arc is exact at any time."""
    lead_scn = Leader((0.0, 0.0, 0.0), (Segment(0.25, 0.5, 0.0), Segment(0.33, 0.5, 0.3), Segment(1.0, 0.5, -0.2)))
    table = lead_scn.table()
    net = MemoryNet()
    got: list[protocol.Ref] = []
    cond = threading.Condition()

    def on_ref(k, b):
        with cond:
            got.append(protocol.decode(b, "ref"))
            cond.notify_all()

    MemoryBus(net).subscribe(keys.leader_ref(F), on_ref)
    lead = leader_mod.Leader(MemoryBus(net), table, 0.02, F, lockstep=False)
    lead.start()
    stop = threading.Event()
    th = threading.Thread(target=lead.run, args=(stop,), daemon=True)
    th.start()
    speed = 2.0  # slow enough that a loaded machine's wake-up jitter (a few ms) stays inside the bounds below
    MemoryBus(net).put(keys.world_clock(F), protocol.encode(Clock(t=0.0, seq=0, epoch=time.time(), speed=speed)))
    with cond:  # the leader runs on the wall clock: ~0.65 s at speed 2
        cond.wait_for(lambda: bool(got) and got[-1].t >= 1.3, timeout=10)
    stop.set()
    th.join(5)
    lead.close()
    ts = np.array([r.t for r in got])
    assert ts[-1] >= 1.3, "the leader stopped publishing"
    for start in (0.25, 0.58):  # the segment starts: each has a reference within 0.02 s (10 ms of wall time)
        assert np.min(np.abs(ts - start)) < 0.02, f"no reference at the segment start {start}"
    gaps = np.diff(ts)
    # about every REF_PERIOD_S: a loaded machine delays a wake-up by tens of ms (53 ms of simulated time
    # seen in a full test run), so the bound is twice the period; a stalled leader still fails it
    assert gaps.max() <= 2 * leader_mod.REF_PERIOD_S
    assert len(got) < 1.3 / 0.02 / 2  # far fewer than one per control period
    for r in got:  # exact: the leader's state at the message's own time
        assert (r.x, r.y, r.theta, r.v, r.w) == tuple(kinematics.leader_state(table, r.t))
