"""Faults in a recording: the /faults channel (the world's fault events, or the schedule's in `swarm sim`),
bad events dropped and counted, the frames' fault marks for replay, and the report's Faults section."""

from __future__ import annotations

import html
import json

import numpy as np
import pytest

from swarm.cli.main import main
from swarm.core import faults as fl
from swarm.net.bus import MemoryBus, MemoryNet
from swarm.proto import keys, protocol
from swarm.view import record, report
from swarm.core.faulttable import first_tick

pytestmark = pytest.mark.unit


def _faults(path) -> list[tuple]:
    return [(e["t"], e["seq"], e["event"], tuple(e["robots"]), e["detail"]) for e in report.read_recording(path).faults]


def test_a_live_lockstep_recording_has_the_worlds_fault_events_as_swarm_sim_writes_them(sim_faults_run,
                                                                                          live_faults_run):
    scn = sim_faults_run.scenario
    want = [(t, first_tick(t, scn.dt), event, robots, detail) for t, event, robots, detail in
            fl.timeline(scn.faults, scn.n)]
    assert [e[2] for e in want] == ["hang", "kill", "partition", "resume", "partition_end"]
    assert _faults(live_faults_run.path) == want  # as the world told them on world/events
    assert _faults(sim_faults_run.path) == want  # as the schedule has them
    assert live_faults_run.bus_recorder.faults == len(want) and live_faults_run.bus_recorder.bad == 0
    # the counters of the final metrics go with the recording
    for run in (sim_faults_run, live_faults_run):
        m = report.read_recording(run.path).metrics
        assert m["faults"]["killed"] == 1 and m["faults"]["hung"] == 1 and m["faults"]["partitions"] == 1


def test_a_swarm_sim_recording_marks_the_robots_the_schedule_killed_as_not_alive(sim_faults_run):
    run = report.read_recording(sim_faults_run.path)
    frames = list(report.iter_frames(sim_faults_run.path))
    for f in frames:
        assert f.alive.tolist() == [fl.process_state(run.scenario.faults, i, f.t) != "dead" for i in range(5)]
    assert [(e["kind"], e["robot"], e["t"]) for e in run.events if e["kind"].startswith("robot_")] == \
        [("robot_dead", 4, 0.4)]


def test_the_frames_carry_the_fault_marks_of_their_time(sim_faults_run, live_faults_run):
    """killed, hung and cut follow the schedule frame by frame (an event at te shows from the first frame at
    or after te), in the live recording (the world's events) as in the sim one (the schedule's)."""
    f = sim_faults_run.scenario.faults
    for run in (sim_faults_run, live_faults_run):
        frames = list(report.iter_frames(run.path, faults=True))
        assert len(frames) == 51  # 2 s at 25 Hz, and t = 0
        for fr in frames:
            assert fr.killed.tolist() == [fl.process_state(f, i, fr.t) == "dead" for i in range(5)], fr.t
            assert fr.hung.tolist() == [fl.process_state(f, i, fr.t) == "hung" for i in range(5)], fr.t
            assert fr.cut.tolist() == [fl.partition_group(f, i, fr.t) != 0 for i in range(5)], fr.t
        assert {fr.t for fr in frames if fr.hung.any()} and {fr.t for fr in frames if fr.cut.any()}
    plain = next(iter(report.iter_frames(live_faults_run.path)))
    assert plain.killed is None and plain.cut is None  # without faults=True nothing more is read


def test_a_frame_marks_the_robots_whose_fresh_status_counts_stale_neighbours(tmp_path):
    """Robot 1 says it used 2 stale neighbour states at t = 0.1 s: its frames show it for STATUS_FRESH_S of
    simulated time, until a status without stale states; robot 2 never says so."""
    from tests.record.test_events import _snap, three_robots

    net = MemoryNet()
    path = tmp_path / "stale.mcap"
    br = record.BusRecorder(MemoryBus(net), "st", record.Recorder(path, three_robots(), 0))
    pub = MemoryBus(net)

    def status(i: int, t: float, stale: int) -> None:
        pub.put(keys.robot_status("st", i), protocol.encode(protocol.Status(
            t=t, ex=0.0, ey=0.0, etheta=0.0, frozen=False, neighbours=2, stale=stale, bad=0)))

    status(2, 0.0, 0)
    for k in range(30):
        t = round(0.1 * k, 9)
        if k == 1:
            status(1, t, 2)
        if k == 20:
            status(1, t, 0)
        pub.put(keys.world_snapshot("st"), _snap(t, k, [0.0, 2.0, 5.0]))
    br.close({"robots": 3})
    shown = [(round(f.t, 9), f.stale_data.tolist()) for f in report.iter_frames(path, faults=True)]
    marked = [t for t, s in shown if s[1]]
    assert marked == [round(0.1 * k, 9) for k in range(1, 12)]  # 0.1 s up to 1.1 s: 1 s old
    assert not any(s[0] or s[2] for _t, s in shown)


def test_bad_fault_events_are_dropped_and_counted(tmp_path):
    from tests.record.test_events import _snap, three_robots

    scn = three_robots()
    net = MemoryNet()
    path = tmp_path / "bad.mcap"
    br = record.BusRecorder(MemoryBus(net), "bf", record.Recorder(path, scn, 0))
    pub = MemoryBus(net)
    pub.put(keys.world_snapshot("bf"), _snap(0.0, 0, [0.0, 2.0, 5.0]))
    good = protocol.Event(t=0.1, seq=1, event="kill", robots=(2,), detail="its process is killed (for good)")
    pub.put(keys.world_events("bf"), protocol.encode(good))
    pub.put(keys.world_events("bf"), b"\x93junk")  # not msgpack
    pub.put(keys.world_events("bf"), protocol.encode(protocol.Event(t=0.2, seq=2, event="hang", robots=(7,),
                                                                    detail="")))  # no such robot
    pub.put(keys.world_events("bf"), protocol.encode(protocol.Event(t=0.2, seq=2, event="hang", robots=(1,),
                                                                    detail="x"))[:-3])  # cut short
    pub.put(keys.world_snapshot("bf"), _snap(0.2, 2, [0.0, 2.0, 5.0]))
    br.close({"robots": 3})
    assert br.bad == 3 and br.faults == 1
    run = report.read_recording(path)
    assert [(e["event"], e["robots"]) for e in run.faults] == [("kill", [2])]
    bad = [e for e in run.events if e["kind"] == "bad_message"]
    assert len(bad) == 3 and all(e["detail"].startswith(keys.world_events("bf")) for e in bad)
    assert "names robot 7" in bad[1]["detail"]


def test_swarm_sim_record_then_report_lists_the_kill_and_the_partition(tmp_path, capsys):
    """The commands as a user types them: a kill and a partition, recorded by `swarm sim`, listed by
    `swarm report` (the fault events and the fault counters of the final metrics); the summary lists the
    counters too."""
    faults = tmp_path / "cut.toml"
    faults.write_text("[faults]\n[[faults.partition]]\ngroups = [[0, 1, 2]]\nstart = 0.5\nend = 1.0\n")
    rec, out = tmp_path / "run.mcap", tmp_path / "report"
    assert main(["sim", "--scenario", "paper-50hz", "--robots", "7", "--duration", "1.5", "--faults", str(faults),
                 "--kill", "5@0.25", "--record", str(rec)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert any(line.split() == ["faults", "killed", "1,", "restarted", "0,", "hung", "0,", "partitions", "1"]
               for line in said), said
    assert any(line.split()[:2] == ["messages", "dropped"] for line in said)
    assert main(["report", str(rec), "-o", str(out)]) == 0
    page = (out / "index.html").read_text()
    section = page[page.index("<h2>Faults</h2>"):page.index("<h2>Events")]
    detail = html.escape("groups 0, 1, 2 | 3, 4, 5, 6 (the world and the leader with the first)")
    assert "<tr><td>0.25</td><td>kill</td><td>5</td><td>its process is killed (for good)</td></tr>" in section
    assert f"<tr><td>0.5</td><td>partition</td><td>3-6</td><td>{detail}</td></tr>" in section
    assert "<tr><td>1</td><td>partition_end</td><td>3-6</td>" in section
    assert "<h3>Fault events (3)</h3>" in section
    m = json.loads((out / "metrics.json").read_text())
    assert "<tr><td>processes killed</td><td><code>faults.killed</code></td><td>1</td></tr>" in section
    assert "<tr><td>partitions</td><td><code>faults.partitions</code></td><td>1</td></tr>" in section
    dropped = m["faults"]["dropped"]
    assert f"<td>{sum(dropped.values())} (" in section and f"ref {dropped['ref']}" in section
    assert "<tr><td>robots alive at the end</td><td><code>robots_alive_at_end</code></td><td>6 of 7</td></tr>" \
        in section


def test_a_recording_without_a_faults_channel_takes_the_schedule(sim_faults_run, tmp_path):
    """A file recorded before /faults existed: the scenario's schedule stands in."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    old = tmp_path / "old.mcap"
    with open(sim_faults_run.path, "rb") as f, open(old, "wb") as g:
        w = Writer(g)
        w.start()
        channels = {}
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            if channel.topic == record.TOPIC_FAULTS:
                continue
            if channel.topic not in channels:
                channels[channel.topic] = w.register_channel(
                    channel.topic, "json", w.register_schema(schema.name, "jsonschema", schema.data))
            w.add_message(channels[channel.topic], message.log_time, message.data, message.publish_time)
        w.finish()
    marks = report.fault_marks(old)
    assert marks.timeline == fl.timeline(sim_faults_run.scenario.faults, 5)
    new = [[fr.killed.tolist(), fr.hung.tolist(), fr.cut.tolist()] for fr in report.iter_frames(old, faults=True)]
    assert new == [[fr.killed.tolist(), fr.hung.tolist(), fr.cut.tolist()]
                   for fr in report.iter_frames(sim_faults_run.path, faults=True)]
    assert np.any([any(k) for k, _h, _c in new])


def test_a_snapshot_larger_than_the_runs_robots_can_be_is_counted_bad_unread(tmp_path, monkeypatch):
    """A snapshot of 100 000 rows on a 3-robot run (8 MB, 0.6 s to decode) is refused by its size before it is
    queued or decoded: counted bad, the real snapshots recorded; a flood of them no longer costs a gigabyte."""
    from swarm.proto.messages import RobotSnap, Snapshot
    from tests.record.test_events import _snap, three_robots

    decoded = []
    real_decode = protocol.decode
    monkeypatch.setattr(protocol, "decode", lambda b, kind=None: decoded.append(len(b)) or real_decode(b, kind))
    net = MemoryNet()
    path = tmp_path / "big.mcap"
    br = record.BusRecorder(MemoryBus(net), "big", record.Recorder(path, three_robots(), 0))
    pub = MemoryBus(net)
    huge = protocol.encode(Snapshot(t=0.05, seq=1, robots=tuple(
        RobotSnap(id=i % 3, x=0.0, y=0.0, theta=0.0, v=0.0, w=0.0, stopped=False, alive=True) for i in range(100_000))))
    for k in range(10):
        pub.put(keys.world_snapshot("big"), _snap(round(0.1 * k, 9), k, [0.0, 2.0, 5.0]))
        pub.put(keys.world_snapshot("big"), huge)
    br.close({"robots": 3})
    assert br.bad == 10 and br.snapshots == 10
    assert max(decoded) < br.snapshot_max  # the big ones were never decoded
    assert len(list(report.iter_frames(path))) == 10


def test_forged_snapshots_far_ahead_are_counted_bad_not_recorded_nor_counted_as_lost(tmp_path):
    """A snapshot with seq 10^6 among the world's is refused by the recorder's window: counted bad, never
    written, and the world's next snapshots are not '999 990 lost on the way'."""
    from tests.record.test_events import _snap, three_robots

    net = MemoryNet()
    path = tmp_path / "forged.mcap"
    br = record.BusRecorder(MemoryBus(net), "fs", record.Recorder(path, three_robots(), 0))
    pub = MemoryBus(net)
    for k in range(10):
        pub.put(keys.world_snapshot("fs"), _snap(round(0.1 * k, 9), k, [0.0, 2.0, 5.0]))
        if k == 4:
            pub.put(keys.world_snapshot("fs"), _snap(1e5, 10**6, [9.0, 9.0, 9.0]))
    br.close({"robots": 3})
    assert br.bad == 1 and br.snapshots == 10 and br.snapshots_missed == 0
    assert [round(f.t, 9) for f in report.iter_frames(path)] == [round(0.1 * k, 9) for k in range(10)]
