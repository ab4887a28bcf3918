"""World, leader and agents together on the in-memory bus (threads): parity and decentralization."""

from __future__ import annotations

import math

import numpy as np
import pytest

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from tests.runtime.harness import run_swarm

pytestmark = pytest.mark.unit

METRIC_KEYS = ("robots", "obstacles", "duration_s", "dt", "seed", "converged_at_s", "final_position_error_max_m",
               "final_orientation_error_max_rad", "min_robot_distance_m", "min_obstacle_distance_m", "collisions",
               "last_freeze_end_s", "freeze_intervals")


def test_lockstep_equals_the_simulator_step_for_step():
    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=3.0))
    metrics, world, agents = run_swarm(scn)
    sim = Simulation(scn, record_period=scn.dt).run()
    q = np.array(world.trace)
    assert q.shape == sim.recording.q.shape == (151, 7, 3)
    assert np.abs(q - sim.recording.q).max() <= 1e-9
    assert {k: metrics[k] for k in METRIC_KEYS} == {k: sim.metrics[k] for k in METRIC_KEYS}
    assert metrics["cmd_misses"] == 0 and metrics["bad_messages"] == 0 and metrics["lockstep_overruns"] == 0
    assert all(a.ticks >= 150 for a in agents)  # tick 150 (the last state) may or may not be computed
    # the ticks the thread of their last command finished (_take_over) are in the parity above
    assert world.taken_over > 0


def test_lockstep_counts_steps_longer_than_its_wait_rule_assumes(write_scenario, caplog):
    """Two robots 4 m apart rush at each other with 0.25 s ticks: a step of more than a third of the
    cell margin brings one into the other's reach unannounced (neither waited for the other), so the
    run may differ from swarm sim. The world counts such pairs, says so, and the summary warns."""
    from swarm.cli.console import summary

    doc = {"run": {"duration": 1.5, "dt": 0.25}, "control": {"k1": 2.0}, "bodies": {"r": 0.3, "R": 0.31},
           "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 1.5, "v": 0.0, "w": 0.0}]},
           "formation": {"offsets": [[0.0, 0.0], [2.0, 0.05]]},
           "robots": {"poses": [[0.0, 0.0, 0.0], [-2.0, 0.05, 0.0]]}}
    scn = scenario_file.load(write_scenario(doc))
    with caplog.at_level("WARNING", logger="swarm.world"):
        metrics, _, _ = run_swarm(scn, trace=False)
    assert metrics["lockstep_overruns"] >= 1
    assert any("farther than the 0.100 m a lock-step tick assumes" in r.getMessage() and "unannounced" in r.getMessage()
               for r in caplog.records)
    assert "may differ from swarm sim" in summary(metrics, "t")
    assert "may differ" not in summary({**metrics, "lockstep_overruns": 0}, "t")
    # the world names each collision it counts (world.referee.log_collisions)
    said = [r.getMessage() for r in caplog.records if r.getMessage().startswith("collision at t = ")]
    assert len(said) == metrics["collisions"] and all("robots 0 and 1 are " in m for m in said), said


def test_lockstep_flags_a_robot_that_outran_its_own_subscriptions(write_scenario):
    """Robot 1 rushes at robot 0 in 0.1 s ticks: its long step into a new cell makes its subscription to
    robot 0's cell race with robot 0's state, so at the next tick it may not know robot 0 (it did not
    wait for it, though robot 0 is then within reach). Found by a review: 3 of 5 `swarm up` runs
    differed from swarm sim with nothing counted. The world now counts it whatever the race's outcome."""
    doc = {"run": {"duration": 1.2, "dt": 0.1}, "control": {"k1": 1.0},
           "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 10.0, "v": 0.0, "w": 0.0}]},
           "formation": {"offsets": [[0.0, 0.0], [1.5, 0.05]]},
           "robots": {"poses": [[0.0, 0.0, 0.0], [-4.3, 0.05, 0.0]]}}
    metrics, _, _ = run_swarm(scenario_file.load(write_scenario(doc)), trace=False)
    assert metrics["lockstep_overruns"] >= 1


def replayed_overruns(scn, q: np.ndarray | None = None, shortcut: bool = True) -> int:
    """The world's wait-rule check run over swarm sim's trajectory of `scn` (what the world sees when
    the distributed run does not diverge), or over the poses q[k] given: deterministic, no threads.
    shortcut False: the pairs are looked at every step, even when no robot moved more than L."""
    from swarm.net.bus import MemoryBus, MemoryNet
    from world.world import World

    if q is None:
        q = Simulation(scn, record_period=scn.dt).run().recording.q
    world = World(MemoryBus(MemoryNet()), scn, "replay", lockstep=True)
    world.alive[:] = True
    for k in range(1, len(q)):
        world.q = [list(row) for row in q[k]]
        if not shortcut:
            world._short_step = False
        world._check_wait_rule(k * scn.dt, q[k - 1][:, :2].copy())
    return world.overruns


def random_walk(scn, steps: int, seed: int, long_every: int = 0) -> np.ndarray:
    """Poses of scn.n robots packed around a corner of four cells, each step of length at most L (a
    quarter exactly L) in a random direction; with long_every, every long_every-th step of one robot
    is 3 L long instead."""
    from swarm.proto import keys

    L = keys.lockstep_step_bound(scn.reach, scn.cell_side)
    rng = np.random.default_rng(seed)
    q = np.zeros((steps + 1, scn.n, 3))
    q[0, :, :2] = scn.cell_side + rng.uniform(-1.2, 1.2, (scn.n, 2)) * scn.reach
    for k in range(1, steps + 1):
        a = rng.uniform(0.0, 2 * math.pi, scn.n)
        length = np.where(rng.random(scn.n) < 0.25, L, rng.uniform(0.0, L, scn.n))
        if long_every and k % long_every == 0:
            length[rng.integers(scn.n)] = 3 * L
        q[k, :, 0] = q[k - 1, :, 0] + length * np.cos(a)
        q[k, :, 1] = q[k - 1, :, 1] + length * np.sin(a)
    return q


@pytest.mark.parametrize("seed", range(4))
def test_no_pair_is_flagged_while_every_step_is_at_most_l(seed):
    """The premise of the check's shortcut (World._check_wait_rule looks at the pairs only after a step
    longer than L): with every step at most L, the full check flags nothing, whatever the cells."""
    scn = scenario_file.load("paper-50hz", Overrides(robots=12))
    assert replayed_overruns(scn, random_walk(scn, 300, seed), shortcut=False) == 0


@pytest.mark.parametrize("seed", range(4))
def test_the_checks_shortcut_counts_what_the_full_check_counts(seed):
    """Where robots do step further than L, the check with its shortcut counts exactly what it counts
    looking at every step."""
    scn = scenario_file.load("paper-50hz", Overrides(robots=12))
    q = random_walk(scn, 300, seed, long_every=7)
    full = replayed_overruns(scn, q, shortcut=False)
    assert full > 0 and replayed_overruns(scn, q) == full


def test_the_wait_rule_check_follows_the_cells_an_agent_really_holds(write_scenario):
    """A review's race: robot 0 crosses a cell edge at tick 1 (dropping the block around its start cell)
    while robot 1, 1.36 m away, dashes into a cell only that dropped block held. Robot 0 may then wait for
    a state it never gets (3 of 3 `swarm up` runs differed from swarm sim with nothing counted when the
    check took the whole older block as held). Paper-50hz runs flag nothing."""
    doc = {"run": {"duration": 1.0, "dt": 0.1}, "control": {"k1": 0.1, "threshold": "off"},
           "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 10.0, "v": 0.0, "w": 0.0}]},
           "formation": {"offsets": [[8.0, 0.75], [-50.0, 0.75]]},
           "robots": {"poses": [[1.44, 0.75, 0.0], [0.8, 0.75, math.pi]]}}
    scn = scenario_file.load(write_scenario(doc))
    assert replayed_overruns(scn) >= 1 and replayed_overruns(scn) == replayed_overruns(scn, shortcut=False)
    assert replayed_overruns(scenario_file.load("paper-50hz", Overrides(robots=19, duration=60.0))) == 0


def clusters_doc(clusters: int) -> dict:
    """Triangles of 3 robots 1.3 m apart, clusters 40 m apart, already in their slots; the leader stands still."""
    offsets, poses = [], []
    for c in range(clusters):
        for dx, dy in ((0.0, 0.0), (1.3, 0.0), (0.65, 1.126)):
            offsets.append([40.0 * c + dx, dy])
            poses.append([40.0 * c + dx, dy, 0.0])
    return {"run": {"duration": 1.0, "dt": 0.02, "seed": 0},
            "control": {"governor": True},
            "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 1.0, "v": 0.0, "w": 0.0}]},
            "formation": {"offsets": offsets, "assignment": "ordered"},
            "robots": {"poses": poses}}


@pytest.mark.parametrize("clusters", [2, 6])
def test_state_traffic_per_robot_depends_on_neighbours_not_on_n(clusters, write_scenario):
    scn = scenario_file.load(write_scenario(clusters_doc(clusters)))
    metrics, world, agents = run_swarm(scn, trace=False)
    ticks = metrics["steps"]
    assert ticks == 50 and metrics["cmd_misses"] == 0
    # each robot hears its two cluster mates once a tick (ticks 0..50; the last may end the run
    # before it is sent), whatever the number of robots
    assert all(2 * ticks <= a.states_received <= 2 * (ticks + 1) for a in agents)


def test_lockstep_under_faults_equals_the_simulator_bit_for_bit(tmp_path):
    """Every kind of fault, played by the schedule (no supervisor: each agent idles through its dead or
    hung ticks): the world's trace, every fault counter and the metrics equal swarm sim's."""
    faults = tmp_path / "faults.toml"
    faults.write_text("[faults]\nseed = 5\n[[faults.drop]]\nclass = \"state\"\np = 0.3\n[[faults.drop]]\n"
                      "class = \"all\"\np = 0.1\n[[faults.delay]]\nclass = \"all\"\nticks = 2\njitter = 1\n"
                      "[[faults.partition]]\ngroups = [[0, 1, 2]]\nstart = 1.0\nend = 2.0\n"
                      "[[faults.kill]]\nrobot = 5\nat = 2.0\nrestart = 1.0\n"
                      "[[faults.hang]]\nrobot = 3\nat = 3.5\nduration = 1.0\n")
    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=6.0, faults=str(faults)))
    metrics, world, agents = run_swarm(scn)
    sim = Simulation(scn, record_period=scn.dt).run()
    q = np.array(world.trace)
    assert q.shape == sim.recording.q.shape == (301, 7, 3)
    assert np.array_equal(q, sim.recording.q)
    same = METRIC_KEYS + ("messages_dropped", "faults", "robots_alive_at_end")
    assert {k: metrics[k] for k in same} == {k: sim.metrics[k] for k in same}
    assert metrics["faults"]["killed"] == metrics["faults"]["hung"] == 1 and metrics["messages_dropped"] > 0
    assert metrics["cmd_misses"] == 0 and metrics["bad_messages"] == 0 and metrics["robots_lost"] == 0
