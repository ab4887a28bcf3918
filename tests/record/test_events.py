"""Events derived by hand-made cases: collisions (docs/metrics.md), freezes, faults, bad messages."""

from __future__ import annotations

import json

import numpy as np
from mcap.reader import make_reader
import pytest

from swarm.proto import keys, protocol
from swarm.view import record, report
from swarm.core import geometry, scenario_file as sf
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto.protocol import Cmd, RobotSnap, Snapshot, Status
from world.referee import Referee

pytestmark = pytest.mark.unit


def three_robots():
    """Three robots (r = 0.3, R = 1.2) and one obstacle at (10, 0) with r = 0.5."""
    doc = {"run": {"duration": 1.0, "dt": 0.1, "seed": 0},
           "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 1.0, "v": 0.0, "w": 0.0}]},
           "formation": {"offsets": [[0.0, 0.0], [2.0, 0.0], [4.0, 0.0]], "assignment": "ordered"},
           "robots": {"poses": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [5.0, 0.0, 0.0]]},
           "obstacles": [{"center": [10.0, 0.0], "r": 0.5, "R": 1.5}]}
    return sf.resolve(sf.parse(doc, "test", "three"))


# (x of robot 1, position of robot 2, alive, stopped) per snapshot; robot 0 stays at the origin
STEPS = [
    (0.25, (5.0, 0.0), [True, True, True], [True, True, True]),      # 0-1 inside at the start: counts once
    (0.28, (5.0, 0.0), [True, True, True], [False, False, False]),   # still inside: nothing new; all move
    (0.30, (5.0, 0.0), [True, True, False], [False, False, False]),  # exactly r is not a collision; 2 dies
    (0.29, (9.7, 0.2), [True, True, True], [False, True, False]),    # 0-1 again, 2 vs obstacle; 2 back; 1 stops
    (0.29, (9.7, 0.2), [True, True, True], [False, False, False]),   # nothing new; 1 moves again
]


def test_collisions_and_faults_by_hand():
    scn = three_robots()
    d = record.EventDeriver(scn)
    referee = Referee(scn)
    got = []
    for k, (x1, p2, alive, stopped) in enumerate(STEPS):
        x = np.array([0.0, x1, p2[0]])
        y = np.array([0.0, 0.0, p2[1]])
        seq = k if k < 4 else 6  # two snapshots lost before the last one
        got += [(k, e.kind, e.robot, e.other, e.obstacle, e.distance) for e in
                d.snapshot(0.1 * k, seq, x, y, np.array(alive), np.array(stopped))]
        referee.sample(0.1 * k, np.stack([x, y, np.zeros(3)], axis=1), np.array(alive), (0.0, 0.0, 0.0))
    assert got == [
        (0, "collision", 0, 1, None, 0.25),
        (2, "robot_dead", 2, None, None, None),
        (3, "collision", 0, 1, None, 0.29),
        (3, "collision", 2, None, 0, float(np.sqrt((9.7 - 10.0) ** 2 + 0.2 ** 2))),
        (3, "robot_alive", 2, None, None, None),
        (3, "robot_stopped", 1, None, None, None),
        (4, "snapshots_missed", None, None, None, None),
        (4, "robot_resumed", 1, None, None, None),
    ]
    # the metrics' definition (the referee) counts the same collisions
    assert referee.collisions == sum(1 for e in got if e[1] == "collision") == 3


def test_the_referee_names_each_collision_when_it_begins_and_the_log_stops_after_the_first_ones(caplog):
    from world import referee as rf

    scn = three_robots()
    referee = Referee(scn)
    lines = []
    for k, (x1, p2, alive, _stopped) in enumerate(STEPS):
        q = np.stack([np.array([0.0, x1, p2[0]]), np.array([0.0, 0.0, p2[1]]), np.zeros(3)], axis=1)
        referee.sample(0.1 * k, q, np.array(alive), (0.0, 0.0, 0.0))
        lines += referee.describe(0.1 * k)
    gap = float(np.hypot(0.3, 0.2)) - 0.5
    assert lines == ["collision at t = 0.000 s: robots 0 and 1 are 0.250 m apart (r = 0.3 m)",
                     "collision at t = 0.300 s: robots 0 and 1 are 0.290 m apart (r = 0.3 m)",
                     "collision at t = 0.300 s: robot 2 is inside obstacle 0 (%.3f m past its edge)" % -gap]

    # a run that keeps colliding logs the first COLLISIONS_LOGGED one by one, says it stops, then is quiet
    referee = Referee(scn)
    caplog.set_level("WARNING", logger="swarm.world")
    for k in range(2 * rf.COLLISIONS_LOGGED + 6):
        x1 = 0.25 if k % 2 == 0 else 1.0  # in, out, in, ...
        referee.sample(0.1 * k, np.array([[0.0, 0.0, 0.0], [x1, 0.0, 0.0], [5.0, 0.0, 0.0]]), np.ones(3, bool),
                       (0.0, 0.0, 0.0))
        rf.log_collisions(referee, 0.1 * k)
    said = [r.getMessage() for r in caplog.records]
    assert referee.collisions == rf.COLLISIONS_LOGGED + 3
    assert len(said) == rf.COLLISIONS_LOGGED + 1 and said[-1].startswith("more than 20 collisions")
    assert all(m.startswith("collision at t = ") for m in said[:rf.COLLISIONS_LOGGED])


def test_a_robot_dead_at_the_first_snapshot_is_an_event():
    d = record.EventDeriver(three_robots())
    evs = d.snapshot(0.0, 0, np.array([0.0, 2.0, 5.0]), np.zeros(3), np.array([True, False, True]), np.ones(3, bool))
    assert [(e.kind, e.robot) for e in evs] == [("robot_dead", 1)]


def test_large_swarms_use_the_sweep_and_find_the_same_pairs():
    rng = np.random.default_rng(7)
    x, y = rng.uniform(0, 30, 600), rng.uniform(0, 30, 600)
    i, j, dist = geometry.pairs_within(x, y, 0.5)  # sort and sweep (N > 256)
    full = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
    wi, wj = np.nonzero(np.triu(full < 0.5, 1))
    assert len(wi) > 10
    assert sorted(zip(i.tolist(), j.tolist())) == sorted(zip(wi.tolist(), wj.tolist()))
    order = np.lexsort((j, i))
    np.testing.assert_allclose(dist[order], full[wi, wj], rtol=0, atol=1e-12)


def _snap(t, seq, xs):
    return protocol.encode(Snapshot(t, seq, tuple(RobotSnap(i, x, 0.0, 0.0, 0.0, 0.0, False, True)
                                                  for i, x in enumerate(xs))))


def _status(t, frozen):
    return protocol.encode(Status(t, 0.1, 0.2, 0.3, frozen, 1, 0, 0))


def test_bus_recorder_freezes_flags_and_bad_messages(tmp_path):
    """Statuses drive freeze events and the snapshots' frozen column; garbage is dropped, counted and
    written as an event; nothing raises into the bus."""
    scn = three_robots()
    net = MemoryNet()
    path = tmp_path / "hand.mcap"
    br = record.BusRecorder(MemoryBus(net), "hand", record.Recorder(path, scn, 0, fleet="hand"))
    pub = MemoryBus(net)
    f = "hand"
    xs = [0.0, 2.0, 5.0]
    pub.put(keys.world_snapshot(f), _snap(0.0, 0, xs))
    pub.put(keys.robot_status(f, 1), _status(0.0, True))
    pub.put(keys.robot_cmd(f, 1), protocol.encode(Cmd(0.0, 0, 0.5, 0.1)))
    pub.put(keys.world_snapshot(f), _snap(0.1, 1, xs))
    pub.put(keys.robot_status(f, 1), _status(0.1, True))
    pub.put(keys.robot_status(f, 2), _status(0.1, False))
    pub.put(keys.robot_cmd(f, 0), b"\xc1 not msgpack")
    pub.put(keys.world_snapshot(f), b"garbage")
    pub.put(keys.robot_status(f, 9), _status(0.1, True))  # robot 9: not in this scenario
    pub.put(f"swarm/{f}/robot/<b>/cmd", protocol.encode(Cmd(0.1, 1, 0.0, 0.0)))  # not a robot key
    pub.put(keys.robot_cmd(f, 1), protocol.encode(Cmd(0.1, 1, 0.5, 0.1)))
    pub.put(keys.world_snapshot(f), _snap(0.2, 2, xs))
    pub.put(keys.robot_status(f, 1), _status(0.2, False))
    pub.put(keys.world_snapshot(f), _snap(0.3, 3, xs))
    br.close({"robots": 3, "note": "hand-made"})
    assert br.bad == 4 and br.errors == 0
    run = report.read_recording(path)
    kinds = [(e["t"], e["kind"], e.get("robot")) for e in run.events]
    assert [k for k in kinds if k[1].startswith("freeze")] == [(0.0, "freeze_start", 1), (0.2, "freeze_end", 1)]
    bad = [e for e in run.events if e["kind"] == "bad_message"]
    assert len(bad) == 4
    assert [e.get("robot") for e in bad] == [0, None, 9, None]
    assert bad[0]["detail"].startswith(keys.robot_cmd(f, 0)) and "not msgpack" in bad[0]["detail"]
    assert bad[1]["detail"].startswith(keys.world_snapshot(f)) and "not msgpack" in bad[1]["detail"]
    assert "robot/9/status" in bad[2]["detail"] and "does not name a robot of this scenario" in bad[2]["detail"]
    assert "robot/<b>/cmd" in bad[3]["detail"]
    assert run.recording.frozen.tolist() == [[False, False, False], [False, True, False], [False, True, False],
                                             [False, False, False]]
    assert run.metrics == {"robots": 3, "note": "hand-made"}
    # commands: robot 1's at 0.0 and 0.1; the others have none and keep the snapshot's v, w (0)
    assert run.recording.cmd[:, 1].tolist() == [[0.5, 0.1], [0.5, 0.1], [0.5, 0.1], [0.5, 0.1]]
    assert run.recording.cmd[:, 0].tolist() == [[0.0, 0.0]] * 4
    with open(path, "rb") as fh:
        snaps = [json.loads(m.data) for _s, _c, m in make_reader(fh).iter_messages(topics=["/world/snapshot"])]
    assert [s["seq"] for s in snaps] == [0, 1, 2, 3]


def test_bad_message_events_are_capped_but_all_counted(tmp_path):
    scn = three_robots()
    net = MemoryNet()
    path = tmp_path / "flood.mcap"
    br = record.BusRecorder(MemoryBus(net), "flood", record.Recorder(path, scn, 0), threaded=False)
    pub = MemoryBus(net)
    for _ in range(record.MAX_BAD_EVENTS + 50):
        pub.put(keys.robot_cmd("flood", 0), b"junk")
    pub.put(keys.world_snapshot("flood"), _snap(0.0, 0, [0.0, 2.0, 5.0]))
    br.close(None)
    assert br.bad == record.MAX_BAD_EVENTS + 50
    run = report.read_recording(path)
    bad = [e for e in run.events if e["kind"] == "bad_message"]
    assert len(bad) == record.MAX_BAD_EVENTS + 1
    assert f"{record.MAX_BAD_EVENTS + 50} bad messages in all" in bad[-1]["detail"]
    assert run.metrics is None
