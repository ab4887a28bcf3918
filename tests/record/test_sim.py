"""record_simulation: the file holds exactly the simulator's samples and metrics, decimated as asked."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.view import record, report
from swarm.core import scenario_file as sf
from swarm.core.sim import Simulation
from tests.record.conftest import small_scenario

pytestmark = pytest.mark.unit


def expected_samples(steps: int, every: int) -> int:
    """Samples at k % every == 0 for k = 0..steps, plus the last step when off the grid."""
    return steps // every + 1 + (1 if steps % every else 0)


def test_recorded_sim_equals_the_recording_and_the_metrics_exactly(sim_run):
    run = report.read_recording(sim_run.path)
    want = sim_run.result.recording
    got = run.recording
    for name in ("t", "q", "cmd", "frozen", "leader", "err"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.shape == b.shape and a.dtype == b.dtype, name
        assert np.array_equal(a, b), f"{name} differs by {np.abs(a.astype(float) - b.astype(float)).max()}"
    assert run.metrics == sim_run.result.metrics  # the exact dict: same keys, same values, same types
    assert run.info["source"] == "sim"
    assert sf.to_toml(run.scenario) == sf.to_toml(sim_run.scenario)
    np.testing.assert_array_equal(run.scenario.poses, sim_run.scenario.poses)
    np.testing.assert_array_equal(run.scenario.offsets, sim_run.scenario.offsets)
    np.testing.assert_array_equal(run.scenario.obstacles, sim_run.scenario.obstacles)


def test_frames_are_the_recorded_poses(sim_run):
    frames = list(report.iter_frames(sim_run.path))
    rec = sim_run.result.recording
    assert [f.t for f in frames] == rec.t.tolist()
    assert np.array_equal(np.stack([f.q for f in frames]), rec.q)
    assert np.array_equal(np.stack([f.frozen for f in frames]), rec.frozen)
    assert all(f.alive.all() and not f.stopped.any() for f in frames)


@pytest.mark.parametrize("duration, record_hz, every", [
    (3.0, 20.0, 2),   # 1 / (20 * 0.02) = 2.5 rounds to 2 (the simulator's own rule)
    (3.0, 15.0, 3),
    (3.02, 20.0, 2),  # 151 steps: the last one is off the grid and kept
    (3.0, 0, 1),      # every step
    (3.0, None, 1),
])
def test_record_hz_decimation_gives_the_expected_sample_count(tmp_path, duration, record_hz, every):
    scn = small_scenario(robots=3, duration=duration)
    assert record.record_every(record_hz, scn.dt) == every
    result = Simulation(scn, record_period=scn.dt).run()  # every step: record_simulation decimates
    path = record.record_simulation(tmp_path / "r.mcap", scn, result, record_hz)
    got = report.read_recording(path).recording
    steps = scn.steps
    k = np.rint(got.t / scn.dt).astype(int)
    assert len(got.t) == expected_samples(steps, every)
    assert k[0] == 0 and k[-1] == steps
    assert np.all(k[:-1] % every == 0)
    rows = np.searchsorted(np.rint(result.recording.t / scn.dt).astype(int), k)
    assert np.array_equal(got.q, result.recording.q[rows])
    assert np.array_equal(got.cmd, result.recording.cmd[rows])


def test_samples_sparser_than_record_hz_are_refused(tmp_path):
    scn = small_scenario(robots=3, duration=1.0)
    result = Simulation(scn, record_period=0.1).run()  # every 5 steps
    with pytest.raises(record.RecordError, match="record_period"):
        record.record_simulation(tmp_path / "r.mcap", scn, result, 0)


def test_a_simulation_object_is_run_and_recorded(tmp_path):
    scn = small_scenario(robots=3, duration=1.0)
    sim = Simulation(scn, record_period=record.record_period(10.0, scn.dt))
    path = record.record_simulation(tmp_path / "r.mcap", scn, sim, 10.0)
    run = report.read_recording(path)
    assert sim.done
    assert np.array_equal(run.recording.q, sim.recording().q)
    assert run.metrics["robots"] == 3 and run.metrics["duration_s"] == 1.0


def test_an_interrupted_run_is_recorded_as_it_ended(tmp_path):
    scn = small_scenario(robots=3, duration=5.0)
    calls = []
    sim = Simulation(scn, record_period=record.record_period(20.0, scn.dt))
    result = sim.run(should_stop=lambda: calls.append(1) or len(calls) > 1)  # stops after the first chunk
    assert result.metrics["interrupted"] and result.recording.t[-1] < scn.duration
    path = record.record_simulation(tmp_path / "r.mcap", scn, result, 20.0)
    run = report.read_recording(path)
    for name in ("t", "q", "cmd", "frozen", "err"):
        assert np.array_equal(getattr(run.recording, name), getattr(result.recording, name)), name
    assert run.metrics == result.metrics
