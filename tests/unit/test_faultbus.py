"""The fault-injecting bus (swarm.net.faultbus) on the in-memory bus: every decision is the shared
model's (FaultTable.link(...).decide(seq, t)), lost messages never reach a subscriber or an inbox, late
ones are held dt x ticks / speed and come in order of their due time, partitions cut what decide cuts,
undecodable payloads and other keys pass through, and hostile sequence numbers cost nothing."""

from __future__ import annotations

import threading

import pytest

from swarm.core import faultgen as fg
from swarm.core import faults as F
from swarm.core.clock import FakeClock
from swarm.net import faultbus
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.net.faultbus import FaultBus
from swarm.proto import keys, protocol
from swarm.proto.protocol import Cmd, Pose, Ref, State, Status
from swarm.core.faulttable import FaultTable

pytestmark = pytest.mark.unit

FLEET = "fb"
N = 5
DT = 0.02
ME = 3


def table(doc: dict, seed: int = 11) -> FaultTable:
    return FaultTable.of(F.parse_faults(doc, "test.toml", N, 60.0, seed), N, DT)


def state(j: int, seq: int, t: float | None = None) -> bytes:
    return protocol.encode(State(id=j, t=seq * DT if t is None else t, seq=seq, x=0.1 * j, y=0.0, theta=0.0,
                                 r=0.3, R=1.2, frozen=False))


def ref(seq: int, t: float | None = None) -> bytes:
    return protocol.encode(Ref(t=seq * DT if t is None else t, seq=seq, x=0.0, y=0.0, theta=0.0, v=0.5, w=0.0))


def pose(seq: int) -> bytes:
    return protocol.encode(Pose(t=seq * DT, seq=seq, x=1.0, y=2.0, theta=0.0))


def cmd(seq: int) -> bytes:
    return protocol.encode(Cmd(t=seq * DT, seq=seq, v=0.1, w=0.0))


def seqs(items, kind: str) -> list[int]:
    return [protocol.decode(p, kind).seq for _k, p in items]


class Pair:
    """A sender and a fault bus around a receiver, on one MemoryNet."""

    def __init__(self, tab, me: int = ME, speed: float = 2.0, clock=None, timer: bool = False):
        self.net = MemoryNet()
        self.clock = clock or FakeClock()
        self.tx = MemoryBus(self.net)
        self.rx = FaultBus(MemoryBus(self.net), tab, me, DT, FLEET, speed=speed, clock=self.clock, timer=timer)

    def close(self):
        self.rx.close()
        self.tx.close()


@pytest.mark.parametrize("how", ["subscribe", "subscribe_raw", "inbox"])
def test_drops_are_exactly_the_models_decisions_and_are_counted(how):
    tab = table({"drop": [{"class": "state", "p": 0.3}, {"class": "ref", "p": 0.5, "burst": 4.0}]})
    w = Pair(tab)
    got: list[tuple[str, bytes]] = []
    key_s, key_r = keys.cell(FLEET, 0, 0, 1), keys.leader_ref(FLEET)
    if how == "inbox":
        boxes = [w.rx.inbox(keys.cell_any(FLEET, 0, 0), depth=1000), w.rx.inbox(key_r, depth=1000)]
    elif how == "subscribe":
        w.rx.subscribe(keys.cell_any(FLEET, 0, 0), lambda k, b: got.append((k, b)))
        w.rx.subscribe(key_r, lambda k, b: got.append((k, b)))
    else:
        w.rx.subscribe_raw(keys.cell_any(FLEET, 0, 0), lambda k, b, a: got.append((k, b)))
        w.rx.subscribe_raw(key_r, lambda k, b, a: got.append((k, b)))
    for k in range(400):
        w.tx.put(key_s, state(1, k))
        w.tx.put(key_r, ref(k))
    if how == "inbox":
        got = boxes[0].drain() + boxes[1].drain()
    link_s, link_r = tab.link(fg.CLS_STATE, 1, ME), tab.link(fg.CLS_REF, fg.LEADER, ME)
    want_s = [k for k in range(400) if not link_s.decide(k, k * DT)[0]]
    want_r = [k for k in range(400) if not link_r.decide(k, k * DT)[0]]
    assert seqs([g for g in got if g[0] == key_s], "state") == want_s
    assert seqs([g for g in got if g[0] == key_r], "ref") == want_r
    assert 60 < 400 - len(want_s) < 180 and 100 < 400 - len(want_r) < 300  # the rules did lose messages
    c = w.rx.counters()
    assert c["dropped"] == {"state": 400 - len(want_s), "pose": 0, "cmd": 0, "ref": 400 - len(want_r)}
    assert c["delayed"] == {"state": 0, "pose": 0, "cmd": 0, "ref": 0}
    w.close()


def test_late_messages_are_held_ticks_times_dt_over_speed_then_delivered():
    tab = table({"delay": [{"class": "pose", "ticks": 3}]})
    w = Pair(tab, speed=2.0)
    box = w.rx.inbox(keys.robot_pose(FLEET, ME), depth=8)
    w.tx.put(keys.robot_pose(FLEET, ME), pose(0))
    assert box.drain() == []  # held: 3 x 0.02 s / 2 = 0.03 wall s
    w.clock.advance(0.03 - 1e-6)
    assert box.drain() == []
    w.clock.advance(2e-6)
    assert seqs(box.drain(), "pose") == [0]
    assert w.rx.counters()["delayed"]["pose"] == 1 and w.rx.counters()["dropped"]["pose"] == 0
    w.close()


def test_jitter_reorders_by_due_time_and_callbacks_get_held_messages_when_due():
    tab = table({"delay": [{"class": "state", "ticks": 0, "jitter": 4}]}, seed=5)
    w = Pair(tab, speed=1.0)
    key = keys.cell(FLEET, 2, -1, 4)
    got: list[int] = []
    w.rx.subscribe(keys.cell_all(FLEET), lambda k, b: got.append(protocol.decode(b, "state").seq))
    box = w.rx.inbox(keys.cell_any(FLEET, 2, -1), depth=100)
    for k in range(40):
        w.tx.put(key, state(4, k))
    link = tab.link(fg.CLS_STATE, 4, ME)
    late = {k: link.decide(k, k * DT)[1] for k in range(40)}
    now = [k for k in range(40) if late[k] == 0]
    assert got == now and seqs(box.drain(), "state") == now  # the rest is held
    w.clock.advance(1.0)
    w.rx.pump()
    order = now + sorted((k for k in range(40) if late[k] > 0), key=lambda k: (late[k], k))
    assert got == order and seqs(box.drain(), "state") == order[len(now):]
    assert got != sorted(got)  # reordered
    assert w.rx.counters()["delayed"]["state"] == 2 * (40 - len(now))  # two subscriptions: two receptions each
    w.close()


def test_a_partition_cuts_what_decide_cuts_and_never_a_pose_or_a_command():
    tab = table({"partition": [{"groups": [[0, 1], [3, 4]], "start": 1.0, "end": 2.0}]})
    w = Pair(tab)
    cells = w.rx.inbox(keys.cell_all(FLEET), depth=1000)
    refs = w.rx.inbox(keys.leader_ref(FLEET), depth=1000)
    poses = w.rx.inbox(keys.robot_pose(FLEET, ME), depth=1000)
    for k in range(150):  # 0 .. 2.98 s
        w.tx.put(keys.cell(FLEET, 0, 0, 0), state(0, k))
        w.tx.put(keys.cell(FLEET, 0, 0, 4), state(4, k))
        w.tx.put(keys.leader_ref(FLEET), ref(k))
        w.tx.put(keys.robot_pose(FLEET, ME), pose(k))
    got = cells.drain()
    from0 = seqs([g for g in got if g[0].endswith("/0")], "state")
    assert from0 == [k for k in range(150) if not (1.0 - 1e-9 <= k * DT < 2.0 - 1e-9)]
    assert seqs([g for g in got if g[0].endswith("/4")], "state") == list(range(150))  # same group
    assert seqs(refs.drain(), "ref") == from0  # the world and the leader are in the first group
    assert seqs(poses.drain(), "pose") == list(range(150))  # its own body's sensor: never cut
    w.close()


def test_the_world_side_decides_commands_and_leaves_everything_else():
    tab = table({"drop": [{"class": "all", "p": 0.4}]})
    w = Pair(tab, me=fg.WORLD)
    cmds = w.rx.inbox(keys.robot_any(FLEET, "cmd"), depth=1000)
    statuses = w.rx.inbox(keys.robot_any(FLEET, "status"), depth=1000)
    assert type(statuses).__name__ != "FaultInbox"  # a key with no link: the plain inbox
    for k in range(200):
        w.tx.put(keys.robot_cmd(FLEET, 2), cmd(k))
        w.tx.put(keys.robot_status(FLEET, 2), protocol.encode(Status(t=k * DT, ex=0.0, ey=0.0, etheta=0.0,
                                                                       frozen=False, neighbours=0, stale=0, bad=0)))
    link = tab.link(fg.CLS_CMD, 2, fg.WORLD)
    assert seqs(cmds.drain(), "cmd") == [k for k in range(200) if not link.decide(k, k * DT)[0]]
    assert len(statuses.drain()) == 200
    w.close()


def test_what_does_not_decode_passes_through_unchanged():
    tab = table({"drop": [{"class": "all", "p": 1.0}]})
    w = Pair(tab)
    box = w.rx.inbox(keys.cell_all(FLEET), depth=100)
    junk = [b"\xc1 not msgpack", state(2, 1)[:-3], protocol.encode(Ref(t=0.0, seq=1, x=0.0, y=0.0, theta=0.0, v=0.0,
                                                                        w=0.0))]
    for j in junk:
        w.tx.put(keys.cell(FLEET, 0, 0, 2), j)
    w.tx.put(keys.cell(FLEET, 0, 0, 2), state(1, 7))  # the id in the payload is not the key's
    w.tx.put(keys.cell(FLEET, 0, 0, 2), state(2, 7))  # a real one: lost (p = 1)
    w.tx.put(keys.cell(FLEET, 0, 0, ME), state(ME, 7))  # its own state: no link
    w.tx.put(keys.cell(FLEET, 0, 0, 99), state(4, 7))  # an id beyond the scenario: no link
    got = [p for _k, p in box.drain()]
    assert got == junk + [state(1, 7), state(ME, 7), state(4, 7)]
    assert w.rx.counters()["dropped"]["state"] == 1
    w.close()


def test_a_hostile_sequence_number_is_passed_through_without_walking_the_burst_chain():
    tab = table({"drop": [{"class": "state", "p": 0.2, "burst": 5.0}]})
    w = Pair(tab)
    box = w.rx.inbox(keys.cell_all(FLEET), depth=100)
    w.tx.put(keys.cell(FLEET, 0, 0, 1), state(1, 2**53 - 1, t=1.0))
    w.tx.put(keys.cell(FLEET, 0, 0, 1), state(1, faultbus.MAX_CHAIN_STEPS + 5, t=1.0))
    assert len(box.drain()) == 2 and w.rx.undecided == 2
    w.tx.put(keys.cell(FLEET, 0, 0, 1), state(1, 3))  # an honest one is decided as usual
    box.drain()
    assert w.rx.undecided == 2
    w.close()


def test_a_closed_subscription_gets_nothing_it_held_and_detach_stops_the_timer():
    tab = table({"delay": [{"class": "ref", "ticks": 1}]})
    w = Pair(tab)
    got: list[bytes] = []
    sub = w.rx.subscribe(keys.leader_ref(FLEET), lambda k, b: got.append(b))
    w.tx.put(keys.leader_ref(FLEET), ref(0))
    sub.close()
    w.clock.advance(1.0)
    w.rx.pump()
    assert got == []
    w.close()


def test_a_held_pose_wakes_a_blocked_wait_on_the_wall_clock():
    """The drive's loop blocks in wait(): the timer thread wakes it when a held pose falls due
    (ticks 5 at speed 1: 0.1 s); the join below bounds the test."""
    tab = table({"delay": [{"class": "pose", "ticks": 5}]})
    net = MemoryNet()
    tx = MemoryBus(net)
    rx = FaultBus(MemoryBus(net), tab, ME, DT, FLEET, speed=1.0)
    box = rx.inbox(keys.robot_pose(FLEET, ME), depth=8)
    got: list = []

    def loop():
        while not got:
            got.extend(box.wait())

    t = threading.Thread(target=loop, daemon=True)
    t.start()
    tx.put(keys.robot_pose(FLEET, ME), pose(0))
    t.join(10.0)
    assert not t.is_alive() and seqs(got, "pose") == [0]
    rx.close()
    tx.close()


def test_held_messages_are_bounded_per_inbox():
    tab = table({"delay": [{"class": "state", "ticks": 100}]})
    w = Pair(tab)
    box = w.rx.inbox(keys.cell_all(FLEET), depth=10_000)
    for k in range(faultbus.HELD_MAX + 3):
        w.tx.put(keys.cell(FLEET, 0, 0, 1), state(1, k))
    early = box.drain()
    assert seqs(early, "state") == [0, 1, 2] and len(box.held) == faultbus.HELD_MAX and w.rx.overflow == 3
    w.close()


def test_intersects_follows_zenoh_wildcards():
    assert faultbus.intersects("a/*/c", "a/b/*")
    assert faultbus.intersects("a/**", "a/b/c/d")
    assert faultbus.intersects("**", "x")
    assert not faultbus.intersects("a/*/status", "a/*/cmd")
    assert not faultbus.intersects("a/b", "a/b/c")
