"""BusRecorder on a real in-process swarm (world, leader, agents as threads on the in-memory bus)."""

from __future__ import annotations

import json

import numpy as np
from mcap.reader import make_reader
import pytest

from swarm.view import report
from swarm.core.sim import Simulation

pytestmark = pytest.mark.unit


def recorded(path, topic):
    with open(path, "rb") as f:
        return [json.loads(m.data) for _s, _c, m in make_reader(f).iter_messages(topics=[topic])]


def test_metrics_stored_are_the_ones_given_to_close(live_run):
    run = report.read_recording(live_run.path)
    assert run.metrics == live_run.metrics
    assert run.info["source"] == "lockstep" and run.info["fleet"] == "rec"
    assert live_run.bus_recorder.bad == 0 and live_run.bus_recorder.errors == 0


def test_replay_frames_equal_the_snapshots_on_the_bus(live_run):
    snaps = {s.seq: s for s in live_run.snapshots}
    steps = live_run.scenario.steps
    assert sorted(snaps) == list(range(steps + 1))  # the world published one per tick
    frames = list(report.iter_frames(live_run.path))
    seqs = [f.seq for f in frames]
    assert seqs == list(range(0, steps + 1, 2))  # record_hz 20 at dt 0.02: every 2nd tick, first and last
    for f in frames:
        s = snaps[f.seq]
        assert f.t == s.t
        want = np.array([(r.x, r.y, r.theta) for r in s.robots])
        assert np.array_equal(f.q, want), f.seq
        assert np.array_equal(f.alive, [r.alive for r in s.robots])
        assert np.array_equal(f.stopped, [r.stopped for r in s.robots])
    trace = np.array(live_run.world.trace)  # the world's ground truth at every tick
    assert np.array_equal(np.stack([f.q for f in frames]), trace[seqs])


def test_live_samples_match_the_simulator(live_run):
    """Lock-step equals `swarm sim` exactly, so the samples read back from the live file must equal the
    simulator's: poses, the leader and the errors recomputed against the live reference."""
    scn = live_run.scenario
    sim = Simulation(scn, record_period=2 * scn.dt).run().recording
    got = report.read_recording(live_run.path).recording
    assert got.t.tolist() == sim.t.tolist()
    for name in ("q", "leader", "err"):
        assert np.array_equal(getattr(got, name), getattr(sim, name)), name
    # commands: the one computed at each sample's tick; the final tick's may not be sent before the end
    assert np.array_equal(got.cmd[:-1], sim.cmd[:-1])


def test_commands_taken_from_the_snapshots_equal_the_robots_own(live_run, live_run_lean):
    """In lock-step the world applies exactly cmd_k over a tick, so snapshot k+1 carries it: the lean
    recorder (no subscription to N command keys) writes the same commands as the one that subscribes."""
    own = {(c["id"], c["seq"]): (c["t"], c["v"], c["w"]) for c in recorded(live_run.path, "/robot/cmd")}
    lean = {(c["id"], c["seq"]): (c["t"], c["v"], c["w"]) for c in recorded(live_run_lean.path, "/robot/cmd")}
    last = max(seq for _, seq in own)
    assert lean and {k: v for k, v in own.items() if k[1] < last} == {k: v for k, v in lean.items() if k[1] < last}
    scn = live_run_lean.scenario
    sim = Simulation(scn, record_period=2 * scn.dt).run().recording
    assert np.array_equal(report.read_recording(live_run_lean.path).recording.cmd[:-1], sim.cmd[:-1])


def test_freeze_events_are_the_status_transitions_and_snapshots_carry_the_flag(live_run):
    statuses = recorded(live_run.path, "/robot/status")
    events = recorded(live_run.path, "/events")
    assert {e["kind"] for e in events} <= {"freeze_start", "freeze_end"}
    want = []
    flag: dict[int, bool] = {}
    for s in sorted(statuses, key=lambda s: (s["t"], s["id"])):
        if s["frozen"] != flag.get(s["id"], False):
            want.append((s["t"], "freeze_start" if s["frozen"] else "freeze_end", s["id"]))
        flag[s["id"]] = s["frozen"]
    got = sorted((e["t"], e["kind"], e["robot"]) for e in events)
    assert got == sorted(want) and got, "this scenario freezes robots in its first seconds"
    # a snapshot carries each robot's newest status flag at the time it was recorded: one of the two
    # newest statuses before it (the status of the tick before may still be in flight)
    by_robot: dict[int, list] = {}
    for s in sorted(statuses, key=lambda s: s["t"]):
        by_robot.setdefault(s["id"], []).append((s["t"], s["frozen"]))
    frozen_seen = False
    for snap in recorded(live_run.path, "/world/snapshot"):
        for i, f in zip(snap["id"], snap["frozen"]):
            before = [fl for t, fl in by_robot.get(i, []) if t < snap["t"] - 1e-9]
            allowed = set(before[-2:]) if before else {False}
            assert f in allowed, (snap["t"], i, f, before[-2:])
            frozen_seen |= f
    assert frozen_seen
