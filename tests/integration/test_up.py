"""`swarm up` end to end: real processes over a zenoh router on loopback (bounded waits, killed by PID)."""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import re
import signal
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation
from tests.integration.helpers import descendants, free_port, kill_all, up, wait_for_ticks

METRIC_KEYS = ("robots", "obstacles", "duration_s", "dt", "seed", "converged_at_s", "final_position_error_max_m",
               "final_orientation_error_max_rad", "min_robot_distance_m", "min_obstacle_distance_m", "collisions",
               "last_freeze_end_s")


@pytest.mark.integration
def test_up_lockstep_equals_sim_step_for_step(tmp_path):
    cmd, metrics = up(tmp_path, "--robots", "7", "--duration", "6", "--trace", str(tmp_path / "trace.npz"),
                      "--quiet")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr + "".join(p.read_text() for p in (tmp_path / "logs").glob("*.log"))
    m = json.loads(metrics.read_text())
    scn = scenario_file.load("paper-50hz", Overrides(robots=7, duration=6.0))
    sim = Simulation(scn, record_period=scn.dt).run()
    q = np.load(tmp_path / "trace.npz")["q"]
    assert q.shape == sim.recording.q.shape == (301, 7, 3)
    assert np.abs(q - sim.recording.q).max() <= 1e-9
    assert {k: m[k] for k in METRIC_KEYS} == {k: sim.metrics[k] for k in METRIC_KEYS}
    # as a user compares them: swarm sim --trace writes the same file, equal element for element
    done = subprocess.run([sys.executable, "-m", "swarm.cli", "sim", "--robots", "7", "--duration", "6", "--scenario",
                           "paper-50hz", "--trace", str(tmp_path / "sim.npz"), "--quiet"], capture_output=True,
                          text=True, timeout=180)
    assert done.returncode == 0, done.stderr
    up_trace, sim_trace = np.load(tmp_path / "trace.npz"), np.load(tmp_path / "sim.npz")
    assert np.array_equal(up_trace["q"], sim_trace["q"]) and np.array_equal(up_trace["t"], sim_trace["t"])
    assert float(sim_trace["dt"]) == scn.dt
    assert m["mode"] == "lockstep" and m["cmd_misses"] == 0 and m["bad_messages"] == 0
    assert m["interrupted"] is False and m["processes"] == 10 and m["launch_s"] > 0
    # the contract's keys first, in docs/metrics.md's order (failure last of them), then the extra keys
    contract = ["robots", "obstacles", "duration_s", "dt", "seed", "converged_at_s", "final_position_error_max_m",
                "final_orientation_error_max_rad", "min_robot_distance_m", "min_obstacle_distance_m", "collisions",
                "last_freeze_end_s", "wall_s", "messages_dropped", "cmd_misses", "bad_messages", "interrupted",
                "failure"]
    assert list(m)[:len(contract)] == contract
    # --metrics elsewhere: the log directory keeps the same metrics too
    assert metrics.parent != tmp_path / "logs"
    assert json.loads((tmp_path / "logs" / "metrics.json").read_text()) == m


@pytest.mark.integration
def test_robots_without_the_compiled_parts_say_so_and_give_the_same_run(tmp_path):
    """SWARM_PURE_PYTHON=1, as where setup.py found no C compiler: `swarm up` says so, every robot runs the
    Python message loops and law, and lock-step still equals swarm sim step for step."""
    cmd, _ = up(tmp_path, "--robots", "7", "--duration", "6", "--trace", str(tmp_path / "trace.npz"))
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=180, env={**os.environ, "SWARM_PURE_PYTHON": "1"})
    logs = "".join(p.read_text() for p in (tmp_path / "logs").glob("robot-*.log"))
    assert out.returncode == 0, out.stderr + logs
    assert "message loops and law run as Python (SWARM_PURE_PYTHON is set)" in out.stdout + out.stderr
    assert logs.count("law Python, message loops Python") == 7 and "compiled" not in logs
    # its summary names its twin in swarm sim (whose default scenario is not swarm up's): run as printed
    twin = next(line for line in out.stdout.splitlines() if line.startswith("the same run in swarm sim: "))
    assert twin == "the same run in swarm sim: swarm sim --scenario paper-50hz --robots 7 --duration 6.0", twin
    sim = subprocess.run([sys.executable, "-m", "swarm.cli", *shlex.split(twin.split(": swarm ", 1)[1]), "--trace",
                          str(tmp_path / "sim.npz"), "--quiet"], capture_output=True, text=True, timeout=120)
    assert sim.returncode == 0, sim.stderr
    q = np.load(tmp_path / "trace.npz")["q"]
    assert np.abs(q - np.load(tmp_path / "sim.npz")["q"]).max() <= 1e-9


@pytest.mark.integration
def test_sigint_mid_run_stops_everything_and_writes_interrupted_metrics(tmp_path):
    cmd, metrics = up(tmp_path, "--robots", "5", "--duration", "300")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    children: list[psutil.Process] = []
    try:
        wait_for_ticks(cmd, "t", 50, proc)  # every process up and the run a second in
        children = descendants(proc.pid)
        assert len(children) >= 8  # router, world, leader, 5 robots
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=15)
        assert proc.returncode == 130, err
        gone, alive = psutil.wait_procs(children, timeout=5)
        assert not alive, f"left behind: {[p.pid for p in alive]}"
        m = json.loads(metrics.read_text())
        assert m["interrupted"] is True
        assert 0 < m["duration_s"] < 300
    finally:
        kill_all(descendants(proc.pid) + children)
        if proc.poll() is None:
            proc.kill()


@pytest.mark.integration
def test_a_failed_launch_reports_its_own_empty_metrics_not_an_earlier_runs(tmp_path):
    cmd, metrics = up(tmp_path, "--robots", "3", "--duration", "5", "--start-timeout", "0.05")
    metrics.write_text(json.dumps({"converged_at_s": 12.34, "collisions": 7, "launch_s": 1.0}))  # a stale file
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 1 and "not alive after 0.05 s" in out.stderr, out.stderr
    m = json.loads(metrics.read_text())
    assert m["converged_at_s"] is None and m["collisions"] == 0 and m["launch_s"] is None
    assert "12.34" not in out.stdout
    keys_ = list(m)  # rebuilt by swarm up (no world wrote them): failure still in the contract's place
    assert m["failure"] and keys_.index("failure") == keys_.index("interrupted") + 1


@pytest.mark.integration
def test_a_killed_robot_is_restarted_and_the_run_completes(tmp_path):
    cmd, metrics = up(tmp_path, "--robots", "4", "--duration", "20", "--quiet")
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_ticks(cmd, "t", 25, proc)  # every process up and the run under way
        victim = None
        for p in descendants(proc.pid):
            with contextlib.suppress(psutil.NoSuchProcess):
                line = p.cmdline()
                if "robot" in line and line[line.index("--id") + 1] == "2":
                    victim = p
        assert victim is not None
        victim.kill()
        _, err = proc.communicate(timeout=120)
        # a robot lost that no fault scheduled is a failed check: the run completes, but exits 3
        assert proc.returncode == 3 and "1 robot lost" in err, err
        m = json.loads(metrics.read_text())
        assert m["robot_restarts"] >= 1 and m["robots_lost"] == 1 and m["failure"] is None
        assert m["duration_s"] == 20.0 and m["collisions"] == 0
    finally:
        kill_all(descendants(proc.pid))
        if proc.poll() is None:
            proc.kill()


@pytest.mark.integration
@pytest.mark.parametrize("args, message", [
    (["--robots", "0"], "must be >= 1"),
    (["--scenario", "/nonexistent/x.toml"], "x.toml"),
    (["--listen", "garbage"], "--listen"),
    (["--rate", "50", "--dt", "0.02"], "--dt or --rate"),
    (["--fleet", "a/b"], "--fleet"),
    (["--rate", "nan"], "--rate"),
    (["--listen", "tcp/127.0.0.1:7447", "--connect", "tcp/127.0.0.1:7447"], "not both"),
    (["--scenario", "/tmp"], "is a directory"),
    (["--log-dir", "/nonexistent/logs"], "directory /nonexistent does not exist"),
])
def test_bad_input_is_refused_before_anything_starts(args, message):
    out = subprocess.run([sys.executable, "-m", "swarm.cli", "up", *args], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 2
    assert message in out.stderr


@pytest.mark.integration
def test_up_against_no_router_fails_in_its_start_timeout_and_shows_no_run(tmp_path):
    """`swarm up --connect DEAD --start-timeout 3`: gives up after 3 s (not a fixed 15), says where it
    tried without zenoh's Rust source paths, and prints no table of zeros that reads like a clean run."""
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--connect", f"tcp/127.0.0.1:{free_port()}", "--start-timeout", "3",
           "--robots", "2", "--duration", "2", "--no-viz", "--log-dir", str(tmp_path / "logs")]
    started = time.monotonic()
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert out.returncode == 1
    assert "within 3 s" in out.stderr and "is a router running there" in out.stderr and ".rs:" not in out.stderr
    assert "no run: nothing was simulated" in out.stdout and "collisions" not in out.stdout
    assert json.loads((tmp_path / "logs" / "metrics.json").read_text())["failure"].startswith("cannot open")
    assert time.monotonic() - started < 30  # not the former fixed 15 s plus the rest


@pytest.mark.unit
def test_old_default_log_folders_are_pruned_to_the_newest_of_this_users_and_no_one_elses(tmp_path):
    """Only folders swarm up made (its marker inside) for this user go, beyond the 10 newest; another user's runs
    (here two folders handed to uid 65534, when this test may: root) and folders without the marker stay."""
    from swarm.cli.up import LOG_MARKER, prune_logs

    def folder(name: str, age: int, marked: bool = True):
        d = tmp_path / name
        d.mkdir()
        if marked:
            (d / LOG_MARKER).write_text("")
        os.utime(d, (1_000_000 + age, 1_000_000 + age))
        return d

    made = [folder(f"swarm-f-{4_000_000 + k}", k) for k in range(14)]  # no such processes
    theirs = [folder(f"swarm-f-{4_100_000 + k}", -10 + k) for k in range(2)]  # older than every one of ours
    if os.getuid() == 0:
        for d in theirs:
            os.chown(d, 65534, 65534)
    unmarked = folder("swarm-f-4200000", -20, marked=False)  # a folder of that name swarm up did not make
    other = folder("swarm-g-4000001", 1)  # another fleet's, and a file of the user's
    (tmp_path / "swarm-f-notes").mkdir()
    current = folder("swarm-f-3999999", -1000)  # the oldest, but this run's: kept
    removed = prune_logs(tmp_path, "f", keep=10, current=current)
    assert [d.exists() for d in made] == [False] * 5 + [True] * 9
    assert current.exists() and other.exists() and (tmp_path / "swarm-f-notes").exists() and unmarked.exists()
    if os.getuid() == 0:
        assert removed == 5 and all(d.exists() for d in theirs)
    else:  # without root the two are this user's: the oldest, they go too
        assert removed == 7


@pytest.mark.integration
def test_robot_without_a_world_says_what_it_waited_for(tmp_path):
    port = free_port()
    router = subprocess.Popen([sys.executable, "-m", "swarm.cli", "router", "--listen", f"tcp/127.0.0.1:{port}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        out = subprocess.run([sys.executable, "-m", "swarm.cli", "robot", "--id", "0", "--connect",
                              f"tcp/127.0.0.1:{port}", "--start-timeout", "4", "--fleet", "lonely"],
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 1
        # within 5 s of its start: the cause (said at 3 s), and again in the final error
        said = [ln for ln in out.stderr.splitlines() if "no answer for the current run after 3 s" in ln]
        assert said and "no world of fleet 'lonely' on this router" in said[0], out.stderr
        assert "swarm robot: failed: no answer for the current run" in out.stderr
        assert out.stderr.count("no world of fleet 'lonely' on this router") == 2, out.stderr
    finally:
        router.send_signal(signal.SIGTERM)
        try:
            router.wait(10)
        except subprocess.TimeoutExpired:
            router.kill()
    assert router.returncode in (130, -signal.SIGTERM, -signal.SIGKILL)


@pytest.mark.integration
def test_realtime_mode_runs_on_the_wall_clock_and_measures_the_round_trip(tmp_path):
    cmd, metrics = up(tmp_path, "--robots", "4", "--duration", "6", "--mode", "realtime", "--speed", "2", "--quiet",
                      "--trace", str(tmp_path / "trace.npz"))
    started = time.monotonic()
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    m = json.loads(metrics.read_text())
    assert m["mode"] == "realtime" and m["duration_s"] == pytest.approx(6.0, abs=0.03)
    assert 2.5 <= m["run_wall_s"] <= 3.0 + 2.0  # 6 simulated s at twice the wall clock
    assert m["round_trips"] > 100 and 0 < m["round_trip_ms_median"] <= m["round_trip_ms_p99"]
    assert m["collisions"] == 0 and m["min_robot_distance_m"] > 0.3
    assert time.monotonic() - started < 60
    # each robot logs its loop's CPU per tick at exit, and its whole process's (bench/up_speed.py reads these lines)
    loops = [re.search(r"(\d+) ticks, .* loop CPU (\d+) us a tick, process CPU (\d+) us a tick",
                       (tmp_path / "logs" / f"robot-{i}.log").read_text()) for i in range(4)]
    assert all(lp and int(lp.group(1)) > 100 and 0 < int(lp.group(2)) <= int(lp.group(3)) < 20_000 for lp in loops), loops
    # the trace carries each sample's time: a period the world fell behind on is missing, and counted
    trace = np.load(tmp_path / "trace.npz")
    t = trace["t"]
    assert trace["q"].shape == (len(t), 4, 3) and len(t) == m["samples"] and t[0] == 0.0 and t[-1] == pytest.approx(6.0)
    period = np.floor(t / 0.02 + 1e-9)  # a sample is taken at the first 1 ms step of its period, or later
    assert np.all(np.diff(period) >= 1) and m["samples"] + m["samples_missed"] <= 301
    gaps = np.diff(period) - 1  # periods with no sample between consecutive samples
    assert int(gaps[t[1:] > 1.0].sum()) <= m["samples_missed"] <= int(gaps.sum())  # counted from the start barrier on


@pytest.mark.integration
def test_up_lockstep_equals_sim_with_speed_limits_on(tmp_path):
    """The built-in turtlebot3 scenario (control.v_max, w_max): the limits act alike in every agent."""
    cmd, metrics = up(tmp_path, "--scenario", "turtlebot3", "--robots", "4", "--duration", "8",
                      "--trace", str(tmp_path / "trace.npz"), "--quiet")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr
    scn = scenario_file.load("turtlebot3", Overrides(robots=4, duration=8.0))
    sim = Simulation(scn, record_period=scn.dt).run()
    q = np.load(tmp_path / "trace.npz")["q"]
    assert np.abs(q - sim.recording.q).max() == 0.0
    assert np.abs(sim.recording.cmd[:, :, 0]).max() > 0.2  # the bound binds in this stretch


@pytest.mark.integration
def test_a_viewer_that_does_not_start_in_time_leaves_the_run_going_and_says_how_to_attach_one(tmp_path):
    """--viz-timeout (default 60 s): a meshcat server slower than that (here: 10 ms) fails the viewer
    only; the swarm runs to its end and the line says how to attach a viewer later."""
    cmd, metrics = up(tmp_path, "--robots", "2", "--duration", "1")
    cmd = [a for a in cmd if a != "--no-viz"] + ["--viz-timeout", "0.01"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "the swarm goes on without it" in out.stdout and "swarm viz --connect tcp/127.0.0.1:" in out.stdout
    assert json.loads(metrics.read_text())["steps"] == 50


@pytest.mark.integration
def test_processes_say_what_they_do_and_log_level_quiets_them(tmp_path):
    """Each process says when it is connected and when a run begins and ends (with its counters);
    --log-level warning, handed to every process, leaves only warnings and errors."""
    cmd, _ = up(tmp_path / "a", "--robots", "2", "--duration", "1", "--quiet")
    (tmp_path / "a").mkdir()
    assert subprocess.run(cmd, capture_output=True, text=True, timeout=120).returncode == 0
    logs = tmp_path / "a" / "logs"
    robot, leader, world = ((logs / f"{name}.log").read_text() for name in ("robot-0", "leader", "world"))
    assert "robot 0: connected" in robot and re.search(r"robot 0: run \S+ \(lock-step, 2 robots; law (compiled|Python), "
                                                       r"message loops (compiled|Python)\)", robot)
    assert re.search(r"robot 0, run \S+: \d+ ticks, .* duplicated, 0 poses not as its states ahead said, loop CPU",
                     robot)
    assert "leader: connected" in leader and re.search(r"leader: run \S+ begins", leader)
    assert re.search(r"leader: run \S+ (ended|stopped): \d+ references sent", leader)
    assert "world: connected" in world and re.search(r"world: every robot and the leader alive; run \S+ begins", world)
    assert "world: done at t = 1.0 s" in world
    cmd, _ = up(tmp_path / "b", "--robots", "2", "--duration", "1", "--quiet", "--log-level", "warning")
    (tmp_path / "b").mkdir()
    assert subprocess.run(cmd, capture_output=True, text=True, timeout=120).returncode == 0
    for log in (tmp_path / "b" / "logs").glob("*.log"):
        assert " INFO: " not in log.read_text(), log.name


@pytest.mark.integration
def test_a_second_swarm_on_a_fleet_that_has_a_world_is_refused_and_the_first_run_goes_on(tmp_path):
    """`swarm up --connect` to a router where the fleet already has a world: exit 2 before anything starts,
    naming the fleet and --fleet; the first run is untouched (before, each took the other's robots and leader,
    and both failed)."""
    # 120 simulated s: 3 lock-step robots run 12 s in under a second, which can end before the second swarm has asked
    first, metrics = up(tmp_path / "a", "--robots", "3", "--duration", "120", "--quiet")
    (tmp_path / "a").mkdir()
    endpoint = first[first.index("--listen") + 1]
    proc = subprocess.Popen(first, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        wait_for_ticks(first, "t", 5, proc)
        (tmp_path / "b").mkdir()
        second = [sys.executable, "-m", "swarm.cli", "up", "--connect", endpoint, "--fleet", "t", "--robots", "2",
                  "--duration", "5", "--no-viz", "--log-dir", str(tmp_path / "b" / "logs")]
        out = subprocess.run(second, capture_output=True, text=True, timeout=120)
        assert out.returncode == 2, out.stderr
        assert "fleet 't'" in out.stderr and "already has a world running" in out.stderr and "--fleet" in out.stderr
        _, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            kill_all([proc])
    assert proc.returncode == 0, err
    assert json.loads(metrics.read_text())["failure"] is None
