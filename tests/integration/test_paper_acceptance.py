"""The acceptance of the paper experiment, seeds 0-9 of both built-ins (about 10 s)."""

import pytest

from swarm.core import scenario_file as sf
from swarm.core.sim import Simulation

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def _runs(name):
    return [Simulation(sf.load(name, sf.Overrides(seed=s))).run().metrics for s in range(10)]


def test_paper_seeds_0_to_9():
    runs = _runs("paper")
    for m in runs:
        assert m["collisions"] == 0, m["seed"]
        assert m["min_robot_distance_m"] > 0.4, m["seed"]
    good = [m for m in runs if m["converged_at_s"] is not None and m["converged_at_s"] <= 60.0
            and m["final_position_error_max_m"] < 1e-9 and m["final_orientation_error_max_rad"] < 1e-9]
    assert len(good) >= 9, [(m["seed"], m["converged_at_s"]) for m in runs]


def test_paper_50hz_seeds_0_to_9():
    runs = _runs("paper-50hz")
    assert all(m["collisions"] == 0 for m in runs)
    good = [m for m in runs if m["converged_at_s"] is not None and m["converged_at_s"] <= 90.0]
    assert len(good) >= 9, [(m["seed"], m["converged_at_s"]) for m in runs]


@pytest.mark.parametrize("n", [7, 19, 61, 91, 50])
def test_paper_scales_with_robots(n):
    m = Simulation(sf.load("paper-50hz", sf.Overrides(robots=n, seed=1))).run().metrics
    assert m["robots"] == n
    assert m["collisions"] == 0
    assert m["converged_at_s"] is not None
