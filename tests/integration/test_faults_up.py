"""Faults in the distributed runtime: a faulty lock-step `swarm up` equals `swarm sim` with the same faults,
bit for bit, with real SIGKILL / SIGSTOP / SIGCONT (bounded waits, processes killed by PID)."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from tests.integration.helpers import up

pytestmark = pytest.mark.integration

# every kind of fault at once: the acceptance file of the distributed fault issue
FAULTS = """
[faults]
seed = 3

[[faults.drop]]
class = "state"
p = 0.3

[[faults.drop]]
class = "all"
p = 0.1

[[faults.delay]]
class = "all"
ticks = 2
jitter = 1

[[faults.partition]]
groups = [[0, 1, 2]]
start = 8.0
end = 10.0

[[faults.kill]]
robot = 5
at = 12.0
restart = 2.0

[[faults.hang]]
robot = 3
at = 18.0
duration = 3.0
"""

SAME = ("collisions", "min_robot_distance_m", "min_obstacle_distance_m", "final_position_error_max_m",
        "final_orientation_error_max_rad", "converged_at_s", "messages_dropped", "faults", "robots_alive_at_end")


def test_faulty_lockstep_up_equals_faulty_sim_bit_for_bit(tmp_path):
    faults = tmp_path / "faults.toml"
    faults.write_text(FAULTS)
    cmd, metrics = up(tmp_path, "--robots", "7", "--duration", "30", "--faults", str(faults),
                      "--trace", str(tmp_path / "trace.npz"), "--quiet")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    logs = "".join(p.read_text() for p in (tmp_path / "logs").glob("*.log"))
    assert out.returncode == 0, out.stderr + logs
    m = json.loads(metrics.read_text())
    sim = Simulation(scenario_file.load("paper-50hz", Overrides(robots=7, duration=30.0, faults=str(faults))),
                     record_period=0.02).run()
    q = np.load(tmp_path / "trace.npz")["q"]
    assert q.shape == sim.recording.q.shape == (1501, 7, 3)
    assert np.array_equal(q, sim.recording.q), f"first differing tick: {np.flatnonzero((q != sim.recording.q).any(axis=(1, 2)))[:3]}"
    assert {k: m[k] for k in SAME} == {k: sim.metrics[k] for k in SAME}
    f = m["faults"]
    assert f["killed"] == f["restarted"] == f["hung"] == f["partitions"] == 1 and f["cmd_held"] > 0
    assert all(f["dropped"][c] > 0 for c in ("state", "pose", "cmd", "ref"))
    # scheduled kills are not restarts of the policy; membership followed the schedule: nobody was lost,
    # no command missed, nothing refused
    assert m["robot_restarts"] == 0 and m["robots_lost"] == 0 and m["cmd_misses"] == 0 and m["bad_messages"] == 0
    done = (tmp_path / "logs" / "faults.log").read_text()
    assert "robot 5 killed (SIGKILL" in done and "robot 5's new process started (pid" in done
    assert "robot 3 stopped (SIGSTOP" in done and "robot 3 resumed (SIGCONT" in done


@pytest.mark.parametrize("text", [
    # a hang at t = 0: the world went on at tick 1 without the robot (its SIGCONT came at tick 196), counted it
    # lost and missed its commands (exit 3; with a 3 s hang, "robot 0 did not come back", exit 1). The world
    # now waits for it before tick 0 begins, and the robot, stopped before its first tick, says it is back
    "[[faults.hang]]\nrobot = 0\nat = 0.0\nduration = 0.02\n",
    # a kill with a restart at 1 s and a hang at 1 s: the new process, stopped before its first tick, never said
    # it was back (exit 1), then missed its command at the resume (it did not hear every cell)
    "[[faults.kill]]\nrobot = 2\nat = 0.5\nrestart = 0.5\n[[faults.hang]]\nrobot = 2\nat = 1.0\nduration = 0.5\n",
], ids=["hang at t = 0", "hang at the restart"])
def test_a_robot_stopped_before_its_first_tick_returns_and_the_run_equals_sim(tmp_path, text):
    """Found by a contract audit."""
    faults = tmp_path / "faults.toml"
    faults.write_text("[faults]\n" + text)
    cmd, metrics = up(tmp_path, "--robots", "7", "--duration", "3", "--faults", str(faults), "--quiet")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    logs = "".join(p.read_text() for p in (tmp_path / "logs").glob("*.log"))
    assert out.returncode == 0, out.stderr + logs
    m = json.loads(metrics.read_text())
    sim = Simulation(scenario_file.load("paper-50hz", Overrides(robots=7, duration=3.0, faults=str(faults)))).run()
    assert {k: m[k] for k in SAME} == {k: sim.metrics[k] for k in SAME}
    assert m["robots_lost"] == 0 and m["cmd_misses"] == 0 and m["faults"]["hung"] == 1
