"""read_recording / iter_frames / pace / write_report: the report of a recording, and clear errors."""

from __future__ import annotations

import html
import json

import numpy as np
import pytest
from mcap.writer import Writer

from swarm.view import record, report
from swarm.view.plots import TITLES, write_panels

pytestmark = pytest.mark.unit

PANELS = [f"{stem}.png" for stem in TITLES] + ["fig2.png"]


def test_report_is_the_sim_plots_of_the_recorded_samples(sim_run, tmp_path):
    out = tmp_path / "report"
    written = report.write_report(sim_run.path, out)
    assert [p.name for p in written] == PANELS + ["scenario.toml", "metrics.json", "index.html"]
    assert all(p.parent == out and p.is_file() and p.stat().st_size > 0 for p in written)
    # the very same figures `swarm sim --plots` draws from the run's own samples
    direct = write_panels(sim_run.result.recording, sim_run.scenario, tmp_path / "direct")
    for p in direct:
        assert (out / p.name).read_bytes() == p.read_bytes(), p.name
    assert json.loads((out / "metrics.json").read_text()) == sim_run.result.metrics
    page = (out / "index.html").read_text()
    for name in PANELS:
        assert f"src='{name}'" in page
    for key, value in sim_run.result.metrics.items():
        assert f"<td>{html.escape(key)}</td>" in page
        assert html.escape(json.dumps(value)) in page
        assert html.escape(report._fmt(value)) in page
    assert html.escape(sim_run.scenario.name) in page
    assert "<pre>" + html.escape((out / "scenario.toml").read_text()) + "</pre>" in page
    kinds = {e["kind"] for e in report.read_recording(sim_run.path).events}
    assert kinds and all(f"<td>{k}</td>" in page for k in kinds)
    assert "<h2>Faults</h2>" not in page  # a run without faults: no such section (tests/record/test_faults.py)


def test_report_escapes_what_it_shows(tmp_path):
    """A bad message's key and the scenario's name end up in the page: as text, never as markup."""
    from tests.record.test_events import _snap, three_robots
    from swarm.proto import keys
    from swarm.net.bus import MemoryBus, MemoryNet

    scn = three_robots().replace(name="<script>alert(1)</script>")
    net = MemoryNet()
    path = tmp_path / "esc.mcap"
    br = record.BusRecorder(MemoryBus(net), "esc", record.Recorder(path, scn, 0))
    pub = MemoryBus(net)
    pub.put(keys.world_snapshot("esc"), _snap(0.0, 0, [0.0, 2.0, 5.0]))
    pub.put("swarm/esc/robot/<img src=x>/cmd", b"junk")
    pub.put(keys.world_snapshot("esc"), _snap(0.1, 1, [0.0, 2.0, 5.0]))
    br.close({"robots": 3, "label": "<b>bold</b>"})
    written = report.write_report(path, tmp_path / "out")
    page = written[-1].read_text()
    assert "<script>" not in page and "<img src=x>" not in page and "<b>bold" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page
    assert "robot/&lt;img src=x&gt;/cmd" in page
    assert "Missing contract keys" in page  # these hand-made metrics lack most of docs/metrics.md


def test_pace_follows_simulated_time_at_the_given_speed():
    now = [100.0]
    slept = []

    def sleep(s):
        slept.append(round(s, 9))
        now[0] += s

    frames = [report.Frame(t, k, None, None, None, None) for k, t in enumerate([0.0, 0.5, 1.0, 1.0, 3.0])]
    out = list(report.pace(iter(frames), speed=2.0, clock=lambda: now[0], sleep=sleep))
    assert out == frames
    assert slept == [0.25, 0.25, 1.0]
    with pytest.raises(ValueError, match="speed"):
        list(report.pace(iter(frames), speed=0.0))
    with pytest.raises(ValueError, match="max_hz"):
        list(report.pace(iter(frames), max_hz=0.0))
    assert list(report.pace(iter([]), speed=1.0)) == []


def test_pace_for_a_viewer_limits_the_rate_and_skips_what_is_late():
    now = [0.0]

    def sleep(s):
        now[0] += s

    frames = [report.Frame(0.04 * k, k, None, None, None, None) for k in range(101)]  # 25 Hz for 4 s
    got = []
    for f in report.pace(iter(frames), speed=4.0, max_hz=30.0, clock=lambda: now[0], sleep=sleep):
        got.append((f.seq, now[0]))
        if f.seq == 40:
            now[0] += 0.5  # the consumer stalls for half a second
    seqs = [k for k, _ in got]
    assert seqs[0] == 0 and seqs[-1] == 100
    gaps = np.diff([w for _, w in got])
    assert (gaps[:-1] >= 1 / 30 - 1e-9).all()  # at most 30 frames per wall second (the last one always comes)
    assert all(abs(w - 0.04 * k / 4.0) < 1e-9 for k, w in got if k <= 40)  # on time before the stall
    after = [k for k, _ in got if k > 40]
    assert after[0] == 90  # frames due during the stall were skipped: frame 90 is due at 0.9 s, when it ends
    assert all(abs(w - 0.04 * k / 4.0) < 1e-9 for k, w in got if k > 40)
    assert len(seqs) < 40


def _mcap_with(path, messages: dict) -> None:
    """A valid MCAP file with one message per topic in `messages` (topic -> JSON object)."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        for topic, msg in messages.items():
            name, schema = record.SCHEMAS[topic]
            ch = w.register_channel(topic, "json", w.register_schema(name, "jsonschema", json.dumps(schema).encode()))
            w.add_message(ch, 0, json.dumps(msg).encode(), 0)
        w.finish()


SNAP = {"t": 0.0, "seq": 0, "id": [0], "x": [0.0], "y": [0.0], "theta": [0.0], "v": [0.0], "w": [0.0],
        "stopped": [False], "alive": [True], "frozen": [False]}


@pytest.mark.parametrize("case, reason", [
    ("missing", "no such file"),
    ("empty", "empty file"),
    ("text", "not an MCAP file"),
    ("truncated", "no footer"),  # cut before its first snapshot's chunk: nothing to recover
    ("no_scenario", "no /scenario message"),
    ("bad_toml", "the recorded scenario cannot be rebuilt"),
])
def test_bad_files_give_a_clear_error(case, reason, tmp_path, sim_run):
    path = tmp_path / f"{case}.mcap"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "text":
        path.write_text("[run]\nduration = 1.0\n")
    elif case == "truncated":
        data = sim_run.path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    elif case == "no_scenario":
        _mcap_with(path, {"/world/snapshot": SNAP})
    elif case == "bad_toml":
        from swarm.core import scenario_file

        text = scenario_file.to_toml(sim_run.scenario).replace("[control]", "[kontrol]")
        _mcap_with(path, {"/scenario": {"name": "x", "toml": text}, "/world/snapshot": SNAP})
    for read in (report.read_recording, lambda p: list(report.iter_frames(p)),
                 lambda p: report.write_report(p, tmp_path / "out")):
        with pytest.raises(report.ReportError) as err:
            read(path)
        assert str(path) in str(err.value) and reason in str(err.value)
    assert not (tmp_path / "out").exists()
