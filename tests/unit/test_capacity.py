"""Whether a machine holds a real-time swarm's control period (swarm.launch.capacity): what swarm up --mode
realtime says before it starts."""

from __future__ import annotations

import pytest

from swarm.launch import capacity

pytestmark = pytest.mark.unit


def test_the_demand_grows_with_robots_and_speed_and_a_warning_says_what_this_machine_holds():
    step = 32.0  # us: the 2-core development machine's
    assert capacity.demand(38, 0.02, 1.0, step) == 2 * capacity.demand(19, 0.02, 1.0, step)
    assert capacity.demand(19, 0.02, 2.0, step) == capacity.demand(19, 0.01, 1.0, step)
    assert capacity.verdict(19, 0.02, 2.0, cores=2, step=step) is None  # held the period in the stress bench
    note = capacity.verdict(37, 0.02, 2.0, cores=2, step=step)  # did not
    assert note is not None and "about 20 robots at --speed 2, not 37" in note and "never a collision" in note
    assert capacity.verdict(37, 0.02, 2.0, cores=4, step=step) is None


def test_a_robots_step_is_measured_here():
    assert 1.0 < capacity.step_us(rounds=3, steps=50) < 10_000.0
