"""The built-in `turtlebot3` scenario: the paper's formation scaled to TurtleBot3 Burger, within its
speed limits at every step, converging with no collision."""

import numpy as np
import pytest

from swarm.core import scenario_file
from swarm.core.sim import Simulation

pytestmark = pytest.mark.unit


def test_turtlebot3_converges_within_the_robots_limits():
    scn = scenario_file.load("turtlebot3")
    assert scn.n == 7 and scn.control.v_max == 0.22 and scn.control.w_max == 2.84 and scn.r == 0.22
    assert (scn.obstacles[:, 2] == 0.15).all()  # the halved paper's; two Burgers (0.105 m) touch 0.21 m apart
    assert all(abs(s.v) <= 0.8 * 0.22 and abs(s.w) <= 0.8 * 2.84 for s in scn.leader.segments)
    assert scenario_file.advisories(scn) == []
    result = Simulation(scn, record_period=scn.dt).run()  # every step recorded: every command read
    m = result.metrics
    assert m["converged_at_s"] is not None and m["collisions"] == 0
    cmd = result.recording.cmd
    assert cmd.shape[0] == scn.steps + 1
    assert np.abs(cmd[:, :, 0]).max() <= 0.22 * (1 + 1e-12) and np.abs(cmd[:, :, 1]).max() <= 2.84 * (1 + 1e-12)
    assert np.abs(cmd[:, :, 0]).max() > 0.2  # the bound binds somewhere: the test sees it act
