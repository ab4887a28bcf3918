"""Recording end to end through the CLI: `swarm up --record` with 37 robot processes, `swarm sim --record`,
`swarm report`, `swarm replay` (bounded waits, loopback, every process killed by the launcher's own cleanup)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from swarm.view import record, report
from swarm.cli.playback import replay_into
from tests.integration.test_up import METRIC_KEYS, up

pytestmark = pytest.mark.integration

CLI = [sys.executable, "-m", "swarm.cli"]


ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[2]),
                                                    os.environ.get("PYTHONPATH", "")])}


def cli(*args: str, timeout: float = 120, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=ENV)


def mcap_messages(path: Path) -> dict[str, list[dict]]:
    """Every message of the file by topic, read by the mcap library itself (JSON decoded)."""
    out: dict[str, list[dict]] = {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            out.setdefault(channel.topic, []).append(json.loads(message.data))
    return out


@pytest.fixture(scope="module")
def up37(tmp_path_factory):
    """A recorded 37-robot lock-step `swarm up` run of 3 simulated seconds (about 10 s here)."""
    tmp = tmp_path_factory.mktemp("up37")
    cmd, metrics = up(tmp, "--robots", "37", "--duration", "3", "--record", str(tmp / "run.mcap"), fleet="rec37")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr + "".join(p.read_text() for p in (tmp / "logs").glob("*.log"))
    return tmp, json.loads(metrics.read_text()), out.stdout


def test_up_records_a_37_robot_run_that_mcap_reads_back(up37):
    tmp, metrics, stdout = up37
    assert f"record:  {tmp / 'run.mcap'}" in stdout
    msgs = mcap_messages(tmp / "run.mcap")
    assert {"/scenario", "/world/snapshot", "/leader/ref", "/robot/cmd", "/robot/status", "/metrics"} <= set(msgs)
    assert msgs["/scenario"][0]["robots"] == 37 and msgs["/scenario"][0]["source"] == "lockstep"
    snaps = msgs["/world/snapshot"]
    # 20 Hz at dt = 0.02 s: every 2nd step of 150: t = 0, 0.04, ..., 3.0. Snapshots are best effort
    # (the world never waits for a viewer): one lost on the way is replaced by the next step's and
    # written down as an event.
    times = [round(s["t"], 9) for s in snaps]
    missed = [e for e in msgs.get("/events", []) if e["kind"] == "snapshots_missed"]
    assert times[0] == 0.0 and times[-1] == 3.0 and len(times) == 76
    off_grid = [t for t in times if round(t / 0.04, 6) % 1]
    assert len(off_grid) <= len(missed) <= 3
    assert all(len(s["x"]) == 37 for s in snaps)
    assert f"snapshots received, {len(snaps)} of them kept" in stdout  # what the file holds, said
    assert msgs["/metrics"] == [metrics]  # the stored metrics are the run's --metrics, exactly
    assert {c["id"] for c in msgs["/robot/cmd"]} == set(range(37))


def test_report_of_the_recorded_run_writes_panels_and_summary_with_its_metrics(up37):
    tmp, metrics, _ = up37
    out = cli("report", str(tmp / "run.mcap"), "-o", str(tmp / "report"))
    assert out.returncode == 0, out.stderr
    files = {p.name for p in (tmp / "report").iterdir()}
    assert {"a_paths.png", "k_distances.png", "l_errors.png", "fig2.png", "index.html", "metrics.json"} <= files
    assert json.loads((tmp / "report" / "metrics.json").read_text()) == metrics
    html = (tmp / "report" / "index.html").read_text()
    assert f"{metrics['min_robot_distance_m']:.4g}"[:5] in html and "paper-50hz" in html
    run = report.read_recording(tmp / "run.mcap")
    assert run.metrics == metrics and run.recording.q.shape == (76, 37, 3)
    assert {k: run.metrics[k] for k in METRIC_KEYS} == {k: metrics[k] for k in METRIC_KEYS}


class CaptureViewer:
    """Stands in for swarm.view.viz.Viewer: keeps what a replay draws."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, np.ndarray, np.ndarray]] = []

    def draw(self, t, q, codes, leader=None) -> None:
        self.frames.append((t, np.array(q), np.array(codes)))


def test_replay_draws_the_recorded_poses_exactly(up37):
    tmp, _, _ = up37
    recorded = mcap_messages(tmp / "run.mcap")["/world/snapshot"]
    by_t = {s["t"]: np.stack([s["x"], s["y"], s["theta"]], axis=1) for s in recorded}
    viewer = CaptureViewer()
    drawn, early = replay_into(tmp / "run.mcap", viewer, speed=1000.0, stop=threading.Event(), max_hz=None)
    assert not early and drawn == len(recorded) == len(viewer.frames)
    for t, q, codes in viewer.frames:
        assert np.array_equal(q, by_t[t])  # bit for bit: JSON round trips doubles exactly
        assert len(codes) == 37


def test_replay_command_serves_the_viewer_and_exits(up37):
    tmp, _, _ = up37
    out = cli("replay", str(tmp / "run.mcap"), "--speed", "20", "--no-wait", "--exit", timeout=60)
    assert out.returncode == 0, out.stderr
    assert "viewer: http://127.0.0.1:" in out.stdout and "frames drawn" in out.stdout


def test_sim_record_every_step_and_report(tmp_path):
    path = tmp_path / "sim.mcap"
    out = cli("sim", "--scenario", "paper-50hz", "--robots", "7", "--duration", "2", "--record", str(path),
              "--record-hz", "0", "--metrics", str(tmp_path / "m.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    msgs = mcap_messages(path)
    assert len(msgs["/world/snapshot"]) == 101  # every step of 2 s at dt = 0.02, t = 0 included
    assert msgs["/metrics"] == [json.loads((tmp_path / "m.json").read_text())]
    assert record.record_every(0, 0.02) == 1


@pytest.mark.parametrize("args, message", [
    (("report", "nope.mcap", "-o", "out"), "no such file"),
    (("replay", "nope.mcap", "--exit"), "no such file"),
    (("sim", "--record", "no/such/dir/x.mcap"), "does not exist"),
    (("sim", "--record", "x.mcap", "--record-hz", "-1"), "must be a finite number >= 0"),
    (("up", "--record", "no/such/dir/x.mcap", "--robots", "3"), "does not exist"),
    (("sim", "--record-hz", "5"), "--record-hz needs --record"),
    (("sim", "--record", "x.txt"), "--record x.txt: a recording is an MCAP file, name it *.mcap"),
    (("sim", "--trace", "x.txt"), "--trace x.txt: a trace is a numpy .npz file, name it *.npz"),
    (("up", "--trace", "x.txt", "--dry-run"), "--trace x.txt: a trace is a numpy .npz file, name it *.npz"),
    (("up", "--record-hz", "5", "--dry-run"), "--record-hz needs --record"),
])
def test_bad_recording_input_is_refused_with_exit_2(tmp_path, args, message):
    out = cli(*args, timeout=60, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert message in out.stderr


def test_report_of_a_file_that_is_not_a_recording_names_it(tmp_path):
    bad = tmp_path / "notes.mcap"
    bad.write_text("not an mcap file\n")
    out = cli("report", str(bad), "-o", str(tmp_path / "r"))
    assert out.returncode == 2 and str(bad) in out.stderr


def test_a_second_ctrl_c_still_leaves_a_complete_recording(tmp_path):
    """Ctrl-C twice in a row during `swarm up --record`: the shutdown finishes (exit 130, nothing left
    running) and the recording is closed with the interrupted metrics."""
    import signal
    import time

    from tests.integration.test_up import descendants, kill_all, wait_for_ticks

    cmd, metrics = up(tmp_path, "--robots", "4", "--duration", "300", "--record", str(tmp_path / "r.mcap"),
                      fleet="twice")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    children = []
    try:
        wait_for_ticks(cmd, "twice", 25, proc)
        children = descendants(proc.pid)
        proc.send_signal(signal.SIGINT)
        time.sleep(0.1)  # the point of the test: a second Ctrl-C right behind the first
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        assert proc.returncode == 130, err
        msgs = mcap_messages(tmp_path / "r.mcap")
        assert msgs["/metrics"] == [json.loads(metrics.read_text())] and msgs["/metrics"][0]["interrupted"] is True
    finally:
        kill_all(descendants(proc.pid) + children)
        if proc.poll() is None:
            proc.kill()


def test_up_refuses_a_router_port_that_is_taken(tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        out = cli("up", "--robots", "3", "--listen", f"tcp/127.0.0.1:{port}", "--no-viz", timeout=60, cwd=tmp_path)
    assert out.returncode == 2 and "cannot listen there" in out.stderr, out.stderr
