"""The metrics `swarm up` writes for a run whose world was lost (from its last progress message): the same
rounding of step times as every other run's metrics (swarm.core.metrics.record)."""

from __future__ import annotations

import pytest

from swarm.cli.up import metrics_from_progress
from swarm.core import scenario_file
from swarm.proto import protocol
from swarm.proto.protocol import Progress

pytestmark = pytest.mark.unit


def test_a_lost_worlds_step_times_read_as_the_failure_line_says():
    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=3), progress=scenario_file.silent)
    t = 163 * scn.dt  # 3.2600000000000002: the world lost at tick 163 (CI once saw this exact value)
    p = Progress(t=t, seq=163, duration=scn.duration, robots=3, alive=3, converged=0, frozen=0, min_distance=1.5,
                 misses=0, bad=0, converged_at=t, last_freeze=t)
    m = metrics_from_progress(scn, "lockstep", p)
    assert t != 3.26 and f"{t:g}" == "3.26"
    assert m["duration_s"] == m["converged_at_s"] == m["last_freeze_end_s"] == 3.26 and m["steps"] == 163
    m = metrics_from_progress(scn, "lockstep", Progress(t=t, seq=163, duration=scn.duration, robots=3, alive=3,
                                                        converged=0, frozen=0, min_distance=1.5, misses=0, bad=0))
    assert m["converged_at_s"] is None and m["last_freeze_end_s"] is None  # -1: the progress said nothing


def test_swarm_up_says_when_the_robots_run_python(monkeypatch):
    """No note when both are compiled; one that says which part runs as Python, and why, when not."""
    from swarm.cli.up import python_note
    from swarm.core import fastlaw

    monkeypatch.delenv("SWARM_PURE_PYTHON", raising=False)
    monkeypatch.setattr(fastlaw, "COMPILED", True)
    assert python_note() is None
    monkeypatch.setattr(protocol, "_wire", None)
    note = python_note()
    assert "message loops run as Python" in note and "no C compiler" in note and "law" not in note
    monkeypatch.setattr(fastlaw, "COMPILED", False)
    monkeypatch.setenv("SWARM_PURE_PYTHON", "1")
    assert "message loops and law run as Python (SWARM_PURE_PYTHON is set)" in python_note()


def test_the_summary_says_when_the_host_took_the_machines_cpu():
    """A virtual machine's steal time, from /proc/stat: the share between two readings, and a note beside the
    wall time from 5 % on (none below, none when it is not known)."""
    from swarm.cli.console import cpu_counters, steal_pct, summary

    total, stolen = cpu_counters()
    assert total >= stolen >= 0
    assert steal_pct((1000, 10), (2000, 310)) == 30.0 and steal_pct((5, 1), (5, 1)) is None
    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=3), progress=scenario_file.silent)
    m = {**metrics_from_progress(scn, "lockstep", None), "wall_s": 406.0, "interrupted": False}
    for pct, said in ((31.9, True), (4.9, False), (None, False)):
        text = summary({**m, "host_steal_pct": pct}, "paper-50hz")
        assert ("the host took 31.9 % of this machine's CPU" in text) == said, text
        assert "406 s" in text


def test_a_lock_step_summary_says_how_fast_the_run_went():
    """The wall time of a lock-step run says the run's own share (launch excluded) and simulated s a wall s; a
    real-time run's does not (it runs at its --speed)."""
    from swarm.cli.console import summary

    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=3), progress=scenario_file.silent)
    m = {**metrics_from_progress(scn, "lockstep", None), "wall_s": 14.6, "run_wall_s": 11.72, "duration_s": 30.0,
         "interrupted": False}
    assert "14.6 s  (the run 11.7 s of it: 2.56 simulated s a wall s)" in summary(m, "paper-50hz")
    assert "simulated s a wall s" not in summary({**m, "mode": "realtime"}, "paper-50hz")
    assert "simulated s a wall s" not in summary({**m, "run_wall_s": None}, "paper-50hz")


def test_the_summary_counts_in_words_and_says_never_for_a_run_that_did_not_converge():
    from swarm.cli.console import summary

    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=1), progress=scenario_file.silent)
    m = {**metrics_from_progress(scn, "lockstep", None), "obstacles": 1, "duration_s": 3.0, "interrupted": False,
         "converged_at_s": None, "cmd_braked": 1}
    text = summary(m, "paper-50hz")
    assert "(1 robot, 1 obstacle," in text and "converged at     never (not by the end of the run)" in text
    assert "(2 robots, 3 obstacles," in summary({**m, "robots": 2, "obstacles": 3}, "paper-50hz")


def test_the_summary_names_the_lost_and_stranded_robots_and_how_real_time_held_up():
    """The failed checks name the robots lost and stranded (stranded fails only a real-time run), and a real-time
    run's summary says how it held up under its load: the round trip's p99, the share of commands the safety rule
    held back, the commands that ran out or came too late."""
    from swarm.cli.console import exit_status, summary
    from swarm.core.metrics import violations

    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=7), progress=scenario_file.silent)
    m = {**metrics_from_progress(scn, "realtime", None), "wall_s": 30.0, "interrupted": False,
         "round_trip_ms_p99": 41.2, "held_back": 0.027, "cmd_braked": 250, "cmd_expired": 12, "robots_lost": 3,
         "lost_robots": [1, 3, 5], "stranded": [0], "stranded_detail": ["robot 0 stranded 21.8 m from its slot since t = 43 s"],
         "robot_restarts": 2, "leader_restarts": 1}
    text = summary(m, "paper-50hz")
    assert "robot restarts   2" in text and "leader restarts  1" in text  # every supervisor action
    assert "round trip p99 41 ms: robots held back 2.7 % of the time; 250 commands ran out (braked), 12 commands came too late" \
        in text
    assert "robot 0 stranded 21.8 m from its slot since t = 43 s" in text
    assert violations(m) == ["3 robots lost (1, 3, 5)", "robot 0 stranded"] and exit_status(m) == 3
    assert violations({**m, "mode": "lockstep"}) == ["3 robots lost (1, 3, 5)"]  # (the paper jams a few seeds too)
    # a link that dropped and came back is still a failed check, and the check says they came back
    assert violations({**m, "lost_robots_back": [1, 5]})[0] == "3 robots lost (1, 3, 5; 1, 5 came back)"
    assert violations({**m, "lost_robots_back": [1, 3, 5]})[0] == "3 robots lost (1, 3, 5; each came back)"
    assert "Lossy links" not in text


def test_a_slow_real_time_round_trip_points_to_lossy_links_unless_the_faults_delayed_it():
    """A real-time round trip's p99 of 100 ms or more that no delay rule made names the usual cause (a link that
    loses packets, and TCP's minimum retransmission timeout) and where the docs say what to do."""
    from swarm.cli.console import realtime_text

    slow = {"mode": "realtime", "round_trip_ms_p99": 131.0, "held_back": 0.088}
    assert "Lossy links" in realtime_text(slow) and "200 ms" in realtime_text(slow)
    assert "Lossy links" not in realtime_text({**slow, "round_trip_ms_p99": 99.0})
    assert "Lossy links" not in realtime_text({**slow, "faults": {"delayed": {"state": 40, "cmd": 0}}})
    assert "Lossy links" in realtime_text({**slow, "faults": {"delayed": {"state": 0}}})


def test_a_collision_without_the_governor_points_to_it():
    """The paper's law collides between control steps, not in continuous time: the summary of such a run says
    that --governor is the cure; a run with the governor on (or without collisions) gets no hint."""
    from swarm.cli.console import summary

    scn = scenario_file.load("paper-50hz", scenario_file.Overrides(robots=3), progress=scenario_file.silent)
    m = {**metrics_from_progress(scn, "lockstep", None), "wall_s": 3.0, "interrupted": False, "collisions": 28,
         "governor": False}
    assert "28  (the safety governor was off" in summary(m, "paper") and "--governor limits" in summary(m, "paper")
    for quiet in ({**m, "governor": True}, {**m, "collisions": 0}):
        assert "safety governor was off" not in summary(quiet, "paper")
