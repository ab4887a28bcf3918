"""A killed run's recording reads back up to its last complete chunk, and report/replay say how much.

The recorder closes a chunk and flushes the file at least every second (swarm.view.record.FLUSH_S);
a file without its footer is read sequentially (swarm.view.report). Cases: a recording cut at many
points (every recovered snapshot equals the finished file's), a recorder process killed with SIGKILL
while it writes, then `swarm report` and `swarm replay` of what it left.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from swarm.view import record, report
from tests.record.conftest import small_scenario

# A recorder process: a long paper-50hz run of 5 robots written snapshot by snapshot, 200 ticks a
# wall second, every message as a live lock-step run writes it; one line per 50 ticks on stdout.
WRITER = r"""
import sys, time
from swarm.core import scenario_file as sf
from swarm.proto.protocol import Cmd, Status
from swarm.view import record
scn = sf.load("paper-50hz", sf.Overrides(robots=5, duration=600.0, seed=1))
rec = record.Recorder(sys.argv[1], scn, 0, source="lockstep")
q = scn.poses.copy()
for k in range(scn.steps + 1):
    t = k * scn.dt
    q[:, 0] += 0.01
    rec.snapshot(t, k, list(range(5)), q[:, 0], q[:, 1], q[:, 2], [0.5] * 5, [0.0] * 5, [False] * 5, [True] * 5,
                 [False] * 5)
    for i in range(5):
        rec.cmd(i, Cmd(t=t, seq=k, v=0.5, w=0.0))
        rec.status(i, Status(t=t, ex=0.0, ey=0.0, etheta=0.0, frozen=False, neighbours=0, stale=0, bad=0))
    if k % 50 == 0:
        print(f"tick {k} flushes {rec.flushes}", flush=True)
    time.sleep(0.005)
"""


def killed_recording(path: Path, flushes: int = 3, timeout_s: float = 60.0) -> int:
    """Run WRITER into `path` and SIGKILL it once it has flushed `flushes` times; returns its last tick."""
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)
    last = -1
    try:
        end = time.monotonic() + timeout_s
        for line in proc.stdout:
            _, tick, _, done = line.split()
            last = int(tick)
            if int(done) >= flushes:
                break
            assert time.monotonic() < end, f"the recorder flushed only {done} times in {timeout_s} s"
        assert last >= 0, "the recorder printed nothing"
        os.killpg(proc.pid, signal.SIGKILL)
        assert proc.wait(10) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    return last


@pytest.mark.unit
def test_a_cut_recording_gives_back_every_complete_chunk(sim_run, tmp_path):
    """Cut a finished file anywhere: what comes back is a prefix of its snapshots, growing with the cut."""
    scn = small_scenario()
    path = tmp_path / "full.mcap"
    rec = record.Recorder(path, scn, 0, source="lockstep", chunk_size=4096)  # many chunks in a small file
    q = scn.poses.copy()
    for k in range(scn.steps + 1):
        q[:, 1] += 0.001
        rec.snapshot(k * scn.dt, k, list(range(scn.n)), q[:, 0], q[:, 1], q[:, 2], [0.0] * scn.n, [0.0] * scn.n,
                     [False] * scn.n, [True] * scn.n, [False] * scn.n)
    rec.close({"robots": scn.n})
    full = report.read_recording(path)
    assert full.recovered is None and report.recovery(path) is None
    data = path.read_bytes()
    previous = 0
    for frac in np.linspace(0.2, 0.98, 9):
        cut = tmp_path / f"cut{frac:.2f}.mcap"
        cut.write_bytes(data[: int(len(data) * frac)])
        found = report.recovery(cut)
        run = report.read_recording(cut)
        k = len(run.recording.t)
        assert found.snapshots == run.recovered.snapshots == k >= previous
        np.testing.assert_array_equal(run.recording.q, full.recording.q[:k])
        assert found.last_t == run.recording.t[-1] and found.duration == scn.duration
        assert run.metrics is None or k == len(full.recording.t)  # written last: lost unless the data all came
        assert 0 < found.bytes_read <= found.size == cut.stat().st_size
        previous = k
    assert previous > len(full.recording.t) // 2


@pytest.mark.integration
def test_a_recorder_killed_with_sigkill_leaves_a_readable_file(tmp_path):
    path = tmp_path / "killed.mcap"
    last_tick = killed_recording(path)
    found = report.recovery(path)
    assert found is not None and found.duration == 600.0
    run = report.read_recording(path)
    k = len(run.recording.t)
    assert k == found.snapshots
    # the run got to last_tick before the kill; flushed chunks hold at least up to one flush period earlier
    assert 0 < k <= last_tick + 51
    np.testing.assert_allclose(np.diff(run.recording.t), 0.02, rtol=1e-9)  # no hole: a prefix of the run
    scn = small_scenario(duration=600.0)
    np.testing.assert_allclose(run.recording.q[:, :, 0], scn.poses[None, :, 0] + 0.01 * np.arange(1, k + 1)[:, None])
    text = found.message()
    assert f"recovered {k} snapshots up to t = " in text and "of the 600 s run" in text and "no footer" in text


@pytest.mark.integration
def test_report_and_replay_say_what_they_recovered(tmp_path):
    path = tmp_path / "killed.mcap"
    killed_recording(path, flushes=2)
    k = report.recovery(path).snapshots
    out = tmp_path / "report"
    done = subprocess.run([sys.executable, "-m", "swarm.cli", "report", str(path), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"swarm report: warning: {path}: recovered {k} snapshots up to t = " in done.stderr
    page = (out / "index.html").read_text()
    assert "Incomplete recording" in page and f"recovered {k} snapshots" in page
    assert (out / "scenario.toml").is_file() and not (out / "metrics.json").exists()
    played = subprocess.run([sys.executable, "-m", "swarm.cli", "replay", str(path), "--speed", "1000", "--no-wait",
                             "--exit"], capture_output=True, text=True, timeout=120, start_new_session=True)
    assert played.returncode == 0, played.stderr
    assert f"swarm replay: warning: {path}: recovered {k} snapshots" in played.stderr
    assert "replay: done," in played.stdout


@pytest.mark.unit
def test_a_file_killed_before_any_snapshot_says_so(tmp_path, sim_run):
    """Only the scenario (flushed at once) came back: a clear error, not a crash."""
    scn = small_scenario()
    path = tmp_path / "early.mcap"
    rec = record.Recorder(path, scn, 0, source="lockstep")
    rec.snapshot(0.0, 0, list(range(scn.n)), scn.poses[:, 0], scn.poses[:, 1], scn.poses[:, 2], [0.0] * scn.n,
                 [0.0] * scn.n, [False] * scn.n, [True] * scn.n, [False] * scn.n)  # in the open chunk
    size = path.stat().st_size
    assert size > 0  # the header and the scenario's chunk are on disk already
    with pytest.raises(report.ReportError, match="recovered 0 snapshots.*no footer"):
        report.read_recording(path)
    with pytest.raises(report.ReportError, match="recovered 0 snapshots"):
        report.recovery(path)
    rec.close()
    assert report.recovery(path) is None and len(report.read_recording(path).recording.t) == 1


@pytest.mark.unit
def test_the_recorder_flushes_on_its_period_and_when_idle(tmp_path):
    scn = small_scenario()
    wall = [0.0]
    rec = record.Recorder(tmp_path / "f.mcap", scn, 0, source="lockstep", flush_s=1.0, clock=lambda: wall[0])
    ids, zeros, no, yes = list(range(scn.n)), [0.0] * scn.n, [False] * scn.n, [True] * scn.n
    q = scn.poses
    for k in range(10):
        wall[0] += 0.3
        rec.snapshot(k * scn.dt, k, ids, q[:, 0], q[:, 1], q[:, 2], zeros, zeros, no, yes, no)
    assert rec.flushes == 2  # at 1.2 s and 2.4 s of wall time
    assert report.recovery(rec.path).snapshots == 8  # those written up to the second flush
    wall[0] += 0.5
    rec.flush_if_due()  # an idle writer (what BusRecorder's worker calls every poll)
    assert rec.flushes == 3 and report.recovery(rec.path).snapshots == 10
    rec.close()
    with pytest.raises(record.RecordError, match="flush_s"):
        record.Recorder(tmp_path / "g.mcap", scn, 0, flush_s=0.0)
