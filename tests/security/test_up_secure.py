"""`swarm up --secure DIR`: every process with its own certificate and role; lock-step still equals
swarm sim. The flags that cannot go together are refused before anything starts."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from tests.integration.helpers import free_port

pytestmark = pytest.mark.integration

CLI = [sys.executable, "-m", "swarm.cli"]


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet") / "sec"
    port = free_port()
    out = subprocess.run(CLI + ["secure", "init", str(d), "--robots", "7", "--fleet", "s", "--port", str(port)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return d


def test_secure_lockstep_run_equals_the_simulator(tmp_path, fleet_dir):
    metrics, trace = tmp_path / "m.json", tmp_path / "t.npz"
    out = subprocess.run(CLI + ["up", "--robots", "7", "--duration", "6", "--secure", str(fleet_dir), "--fleet", "s",
                                "--no-viz", "--quiet", "--metrics", str(metrics), "--trace", str(trace),
                                "--log-dir", str(tmp_path / "logs")], capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr + "".join(p.read_text() for p in (tmp_path / "logs").glob("*.log"))
    m = json.loads(metrics.read_text())
    assert m["collisions"] == 0 and m["cmd_misses"] == 0 and m["bad_messages"] == 0 and m["failure"] is None
    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=6.0))
    sim = Simulation(scn, record_period=scn.dt).run()
    assert np.abs(np.load(trace)["q"] - sim.recording.q).max() == 0.0


@pytest.mark.parametrize("extra, message", [
    (["--zenoh-config", __file__], "not both"),
    (["--robots", "8"], "robot-7"),
    (["--fleet", "other"], "fleet 's'"),
    (["--listen", "tcp/127.0.0.1:7447"], "tls/"),
])
def test_bad_secure_flags_are_refused_up_front(fleet_dir, extra, message):
    args = ["up", "--robots", "7", "--fleet", "s", "--secure", str(fleet_dir), "--no-viz", "--duration", "1"]
    for flag, value in zip(extra[::2], extra[1::2]):  # a flag given twice: the test's value wins
        if flag in args:
            args[args.index(flag) + 1] = value
        else:
            args += [flag, value]
    out = subprocess.run(CLI + args, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and message in out.stderr, out.stderr


def test_a_robot_id_that_disagrees_with_its_certificate_is_refused(fleet_dir):
    out = subprocess.run(CLI + ["robot", "--id", "5", "--secure", str(fleet_dir / "robot-3"), "--fleet", "s",
                                "--start-timeout", "1"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "robot-3" in out.stderr, out.stderr
