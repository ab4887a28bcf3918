"""`swarm campaign --up`'s comparisons, without processes: traces bit for bit, metrics, stale rows, the line
printed for a row, the exit code of several steps."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

from swarm.cli.campaign import _worst
from swarm.cli.campaign_files import campaign_command, cell, read_campaign, write_campaign_json
from swarm.cli.campaign_up import Check, TraceDiff, compare_traces, line, metric_differences, overdue_ticks, row_differences
from swarm.cli.common import BadInput

pytestmark = pytest.mark.unit


def trace(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(50, 5, 3))


def test_identical_traces_are_identical_nans_included():
    q = trace()
    q[20:, 3] = np.nan  # however a trace marks a robot, the same marks in both are equal
    assert compare_traces(q, q.copy()) == TraceDiff(None)


def test_the_first_differing_tick_and_its_robots_by_the_last_bit():
    a = trace()
    b = a.copy()
    b[17, 2, 0] = np.nextafter(b[17, 2, 0], np.inf)  # one ulp
    b[17, 4, 2] += 1.0
    b[30, 0, 1] = np.nan
    d = compare_traces(a, b)
    assert (d.first_tick, d.robots, d.ticks, d.shape) == (17, (2, 4), 2, None)


def test_traces_of_different_shapes_are_named():
    d = compare_traces(trace()[:40], trace())
    assert d.first_tick is None and "(40, 5, 3)" in d.shape and "(50, 5, 3)" in d.shape


def test_metric_differences_go_down_to_the_faults_leaves():
    sim = {"collisions": 0, "converged_at_s": 40.5, "faults": {"dropped": {"state": 10, "pose": 3}, "killed": 1},
           "wall_s": 1.0}
    assert metric_differences(dict(sim, wall_s=9.0), sim) == []
    assert metric_differences({"collisions": 0, "robots_alive_at_end": 7}, {"collisions": 0}) == []  # no faults
    assert metric_differences({"collisions": 0}, {"collisions": 0, "robots_alive_at_end": 7}) == [
        "robots_alive_at_end: None (swarm up) != 7 (swarm sim)"]
    up = {**sim, "converged_at_s": 40.52, "faults": {"dropped": {"state": 11, "pose": 3}, "killed": 1}}
    assert metric_differences(up, sim, keys=("collisions", "converged_at_s", "faults")) == [
        "converged_at_s: 40.52 (swarm up) != 40.5 (swarm sim)",
        "faults.dropped.state: 11 (swarm up) != 10 (swarm sim)"]


def test_a_row_of_runs_csv_is_stale_when_swarm_sim_no_longer_gives_it():
    m = {"collisions": 0, "converged_at_s": None, "min_robot_distance_m": 0.4123, "faults": {"killed": 1},
         "interrupted": False, "wall_s": 2.0}
    row = {k: cell(v) for k, v in {"collisions": 0, "converged_at_s": None, "min_robot_distance_m": 0.4123,
                                   "faults.killed": 1, "interrupted": False, "wallclock.wall_s": 5.0}.items()}
    assert row_differences(row, m) == []
    assert row_differences({**row, "min_robot_distance_m": "0.41230000000000006"}, m) == [
        "min_robot_distance_m: '0.41230000000000006' in runs.csv, '0.4123' now"]
    del row["faults.killed"]
    assert row_differences(row, m) == ["faults.killed: no such column in runs.csv"]


def test_the_line_of_a_row_that_differs_names_the_tick_the_robots_and_what_swarm_up_said():
    c = Check(3, "paper-50hz", 1, 0.3, result="differs", trace=TraceDiff(3097, (2, 4), 12),
              metrics=["converged_at_s: 65.24 (swarm up) != 61.32 (swarm sim)"],
              up={"mode": "lockstep", "cmd_misses": 214, "robots_lost": 5}, up_s=400.0, sim_s=3.6, out="up/row-3")
    text = line(c, 4, 0.02)
    assert text.startswith("up 3/4, seed 1 drop 0.3: DIFFERS at tick 3097 (t = 61.94 s), robots 2, 4; 12 ticks differ")
    assert "converged_at_s: 65.24" in text and "swarm up says: 214 missed commands, 5 robots lost" in text
    assert "swarm up 400.0 s; swarm sim 3.60 s" in text and "its files: up/row-3/" in text
    ok = Check(1, "paper-50hz", 0, 0.0, result="identical", up_s=5.0, sim_s=0.1)
    assert line(ok, 4, 0.02) == ("up 1/4, seed 0 drop 0: OK, identical to swarm sim: every tick of every robot "
                                 "and the metrics (swarm up 5.0 s; swarm sim 0.10 s)")


def test_a_row_that_differs_quotes_its_robots_ticks_without_all_their_inputs(tmp_path):
    """What makes a lock-step run differ when nothing in the schedule does: a robot that went on without an
    input. The first such lines of its robots' logs, in robot order (10 after 2), go into the row's line and why."""
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "robot-10.log").write_text(
        "2026-12-06 16:19:14,041 swarm.robot WARNING: robot 10: no reference for tick 7, no command\n")
    (logs / "robot-2.log").write_text(
        "2026-12-06 16:19:14,041 swarm.robot INFO: robot 2: run r (lock-step, 7 robots)\n"
        "2026-12-06 16:19:15,000 swarm.robot WARNING: robot 2: tick 0 goes on after 1 s without the states of "
        "robots [5] (1 ticks so far)\n")
    (logs / "world.log").write_text("2026-12-06 16:19:15,000 swarm.world WARNING: world: tick 3 goes on after 1 s\n")
    said = overdue_ticks(logs)
    assert said == ["robot 2: tick 0 goes on after 1 s without the states of robots [5] (1 ticks so far)",
                    "robot 10: no reference for tick 7, no command"]
    assert overdue_ticks(logs, most=1) == said[:1] and overdue_ticks(tmp_path / "none") == []
    c = Check(2, "paper-50hz", 1, 0.3, result="differs", trace=TraceDiff(1, (3,), 500), up={"mode": "lockstep"},
              why="; ".join(said), out="up/row-2")
    assert "; its robots' logs: robot 2: tick 0 goes on after 1 s without the states of robots [5]" in line(c, 2, 0.02)


@pytest.mark.parametrize("codes, worst", [((0, 0), 0), ((0, 3), 3), ((3, 1), 1), ((1, 130), 130), ((3, 0), 3)])
def test_the_exit_code_of_the_grid_and_the_check(codes, worst):
    assert _worst(*codes) == worst


def test_campaign_json_reads_back_with_files_as_absolute_paths(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "f.toml").write_text("[faults]\n")
    args = argparse.Namespace(scenario="my.toml", seeds=(0, 2), drop=(0.3, 0.0), robots=7, duration=10.0, dt=None,
                              governor=False, faults="f.toml", kill="3@5")
    write_campaign_json(args, tmp_path, "swarm campaign ...")
    (tmp_path / "runs.csv").write_text("scenario,seed,drop,failure\nmy,0,0.3,\nmy,2,0.3,\n")
    back, rows = read_campaign(tmp_path)
    assert vars(back) == dict(vars(args), scenario=str(tmp_path / "my.toml"), faults=str(tmp_path / "f.toml"))
    assert [(r["seed"], r["drop"]) for r in rows] == [("0", "0.3"), ("2", "0.3")]
    (tmp_path / "runs.csv").write_text("scenario,seed,drop,failure\nmy,x,0.3,\n")
    with pytest.raises(BadInput, match=r"runs.csv: row 1: seed 'x' or drop '0.3' is not a number"):
        read_campaign(tmp_path)
    (tmp_path / "campaign.json").write_text('{"v": 1, "scenario": "paper"}')
    with pytest.raises(BadInput, match="not a campaign file of version 1 \\(missing: seeds, drop"):
        read_campaign(tmp_path)


def test_the_campaign_s_command_names_where_its_runs_ran():
    """campaign.json and index.html give the command that ran: --cluster ADDRESS for a Dask cluster (never -j,
    which --cluster refuses), else -j N."""
    args = argparse.Namespace(scenario="paper-50hz", seeds=(0, 1, 2, 3), drop=(0.0, 0.1), robots=None, duration=20.0,
                              dt=None, governor=None, faults=None, kill=None, jobs=2, out="out", allow_violations=False,
                              cluster="local:2")
    assert campaign_command(args).endswith("--duration 20.0 --cluster local:2 -o out") and " -j " not in \
        campaign_command(args)
    args.cluster = None
    assert campaign_command(args).endswith("--duration 20.0 -j 2 -o out")
