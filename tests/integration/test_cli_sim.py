"""`swarm sim` through the real command line: the metrics contract, bad input, interruption."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.integration

CONTRACT_KEYS = {
    "robots": int, "obstacles": int, "duration_s": float, "dt": float, "seed": int,
    "converged_at_s": (float, type(None)), "final_position_error_max_m": float,
    "final_orientation_error_max_rad": float, "min_robot_distance_m": (float, type(None)),
    "min_obstacle_distance_m": (float, type(None)), "collisions": int, "last_freeze_end_s": (float, type(None)),
    "wall_s": float, "messages_dropped": int, "cmd_misses": int, "bad_messages": int, "interrupted": bool,
}


def swarm_cmd() -> list[str]:
    """The installed `swarm` console script next to this interpreter, else `python -m swarm.cli`."""
    exe = Path(sys.executable).with_name("swarm")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "swarm.cli"]


def run(args: list[str], timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(swarm_cmd() + args, capture_output=True, text=True, timeout=timeout)


@pytest.mark.timeout(180)
def test_paper_seed_through_cli_writes_contract_metrics(tmp_path):
    out = tmp_path / "m.json"
    plots = tmp_path / "fig2"
    p = run(["sim", "--scenario", "paper", "--seed", "4", "--metrics", str(out), "--plots", str(plots)])
    assert p.returncode == 0, p.stderr
    m = json.loads(out.read_text())
    for key, kind in CONTRACT_KEYS.items():
        assert key in m, key
        assert isinstance(m[key], kind) or (kind is float and isinstance(m[key], int)), (key, m[key])
    assert m["robots"] == 37 and m["obstacles"] == 26 and m["seed"] == 4
    assert m["dt"] == 0.001 and m["duration_s"] == pytest.approx(120.0)
    assert m["collisions"] == 0
    assert m["min_robot_distance_m"] > 0.4
    assert m["converged_at_s"] is not None and m["converged_at_s"] <= 60.0
    assert m["final_position_error_max_m"] < 1e-9 and m["final_orientation_error_max_rad"] < 1e-9
    assert m["interrupted"] is False
    assert m["messages_dropped"] == m["cmd_misses"] == m["bad_messages"] == 0
    assert (plots / "fig2.png").stat().st_size > 10_000
    assert "summary" in p.stdout and "converged at" in p.stdout


@pytest.mark.parametrize(
    "args, needle",
    [
        (["sim", "--robots", "0"], "--robots"),
        (["sim", "--dt", "nan"], "--dt"),
        (["sim", "--seed", "-1"], "--seed"),
        (["sim", "--scenario", "no-such-scenario"], "no such file"),
        (["sim", "--duration", "abc"], "--duration"),
        (["sim", "--scenario", "/tmp"], "is a directory"),
        (["sim", "--duration", "1", "--plots", "/etc/passwd/fig2"], "/etc/passwd is not a directory"),
        (["sim", "--duration", "1", "--plots", "/nonexistent/a/fig2"], "/nonexistent/a does not exist"),
        # /proc takes no new file, even from root: each refused before the run, naming the flag and the folder
        (["sim", "--duration", "1", "--plots", "/proc/fig2"], "--plots /proc/fig2: cannot write in /proc"),
        (["sim", "--duration", "1", "--metrics", "/proc/m.json"], "--metrics /proc/m.json: cannot write in /proc"),
        (["campaign", "--seeds", "0-1", "-o", "/proc/c"], "-o /proc/c: cannot write in /proc"),
        (["secure", "init", "/proc/fleet", "--robots", "2"], "/proc/fleet: cannot make or read the fleet directory"),
        (["up", "--robots", "2", "--no-viz", "--log-dir", "/proc/logs"], "--log-dir /proc/logs: cannot make it"),
        (["up", "--robots", "2", "--viz-port", "7447", "--dry-run"], "--viz-port 7447: the router listens on"),
        (["scenario", "scale", "paper-50hz", "--v-max", "0"], "--v-max"),
        (["scenario", "scale", "paper-50hz"], "--v-max"),
        (["up", "--robots", "2", "--listen", "tcp/0.0.0.0:7500", "--viz-port", "7500", "--dry-run"],
         "--viz-port 7500: the router listens on"),
        (["sim", "--duration", "1", "--drop", "0.1", "--threads", "2"], "--threads 2: a run with faults"),
    ],
)
def test_bad_command_line_exits_2_with_a_clear_message(args, needle):
    p = run(args)
    assert p.returncode == 2
    assert needle in p.stderr
    assert "Traceback" not in p.stderr


def test_broken_scenario_file_names_file_key_and_reason(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text('[run]\nduration = "long"\n[leader]\nstart=[0,0,0]\nsegments=[{duration=1,v=0,w=0}]\n'
                 '[formation]\noffsets=[[0,0]]\n[robots]\nposes=[[1,1,0]]\n')
    p = run(["sim", "--scenario", str(f)])
    assert p.returncode == 2
    assert str(f) in p.stderr and "run.duration" in p.stderr and "must be a number" in p.stderr
    assert "Traceback" not in p.stderr


def test_explicit_scenario_round_trips_through_show(tmp_path):
    """`swarm scenario show` writes a file that runs exactly like the built-in it came from."""
    f = tmp_path / "p7.toml"
    p = run(["scenario", "show", "paper-50hz", "--robots", "7", "--seed", "2"])
    assert p.returncode == 0, p.stderr
    f.write_text(p.stdout)
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    assert run(["sim", "--scenario", str(f), "--duration", "20", "--quiet", "--metrics", str(a)]).returncode == 0
    assert run(["sim", "--scenario", "paper-50hz", "--robots", "7", "--seed", "2", "--duration", "20", "--quiet",
                "--metrics", str(b)]).returncode == 0
    ma, mb = json.loads(a.read_text()), json.loads(b.read_text())
    for key in ("converged_at_s", "final_position_error_max_m", "min_robot_distance_m", "collisions"):
        assert ma[key] == mb[key], key


@pytest.mark.timeout(120)
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_interrupt_writes_metrics_and_exits_130(tmp_path, sig):
    out = tmp_path / "m.json"
    # SIGHUP as a terminal would send it: not ignored (a test run under nohup hands its children SIGHUP ignored,
    # and swarm then keeps it ignored, as nohup asks)
    hup_default = [sys.executable, "-c", "import os, signal, sys; signal.signal(signal.SIGHUP, signal.SIG_DFL); "
                   "os.execv(sys.argv[1], sys.argv[1:])"]
    proc = subprocess.Popen(hup_default + swarm_cmd() + ["sim", "--duration", "100000", "--metrics", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        line = ""
        while " t " not in line:  # the first progress line: the run is under way
            assert time.monotonic() < deadline, "no progress line within 60 s"
            line = proc.stderr.readline()
            assert line or proc.poll() is None, "swarm sim exited early"
        proc.send_signal(sig)
        rc = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert rc == 130
    m = json.loads(out.read_text())
    assert m["interrupted"] is True
    assert 0 < m["duration_s"] < 100000
    assert math.isfinite(m["wall_s"])


def test_help_lists_commands_and_exit_codes():
    p = run(["--help"])
    assert p.returncode == 0
    text = " ".join(p.stdout.split())  # argparse wraps the epilog at the terminal's width
    assert "sim" in text and "scenario" in text and "130 interrupted" in text and "4 swarm robot refused" in text
    p = run(["sim", "--help"])
    assert "--governor" in p.stdout and "--plots" in p.stdout


@pytest.mark.timeout(180)
def test_a_console_pipe_that_closes_leaves_the_run_whole(tmp_path):
    """`swarm sim ... | head -1`: the reader goes after one line; the run still ends, writes its metrics and exits
    as it would have (not 0 at the first line it could not print)."""
    out = tmp_path / "m.json"
    p = subprocess.Popen(swarm_cmd() + ["sim", "--robots", "7", "--duration", "2", "--seed", "3", "--metrics",
                                        str(out)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        assert p.stdout is not None and p.stdout.readline()
        p.stdout.close()  # the pipe's reader is gone: every later write of the command's breaks
        assert p.wait(timeout=150) == 0
    finally:
        p.kill()
    m = json.loads(out.read_text())
    assert m["duration_s"] == 2.0 and m["interrupted"] is False


@pytest.mark.skipif(shutil.which("swarm") is None and not Path(sys.executable).with_name("swarm").exists(),
                    reason="the console script is not installed (pip install -e .)")
def test_console_script_is_installed():
    assert run(["scenario", "check", "--help"]).returncode == 0


def test_wall_time_counts_from_the_process_start():
    """wall_s runs from the command's start (docs/metrics.md): a process that spent 0.3 s before
    calling main() reports an age of at least that (the clock ticks in 10 ms steps)."""
    code = ("import time; t = time.monotonic()\n"
            "while time.monotonic() - t < 0.3: pass\n"
            "from swarm.cli.main import _process_age_s; print(_process_age_s())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert 0.28 <= float(out.stdout) < 30.0


def test_a_start_just_outside_r_is_accepted_with_a_warning(write_scenario):
    doc = {"run": {"duration": 1.0, "dt": 0.01},
           "leader": {"start": [0.0, 0.0, 0.0], "segments": [{"duration": 1.0, "v": 0.0, "w": 0.0}]},
           "formation": {"offsets": [[0.0, 0.0], [2.0, 0.0]]}, "robots": {"poses": [[0.0, 0.0, 0.0], [0.305, 0.0, 0.0]]}}
    steep = write_scenario(doc, "steep.toml")
    doc["robots"]["poses"][1] = [0.5, 0.0, 0.0]
    fine = write_scenario(doc, "fine.toml")
    out = subprocess.run([sys.executable, "-m", "swarm.cli", "scenario", "check", steep, fine],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    warnings = [line for line in out.stdout.splitlines() if "warning" in line]
    assert len(warnings) == 1 and warnings[0].startswith(f"{steep}: warning: robots 0 and 1 start 0.305 m apart")
    doc["obstacles"] = [{"center": [0.5, 0.31]}]  # 0.31 m from robot 1, its r 0.3
    near_obstacle = write_scenario(doc, "obstacle.toml")
    out = subprocess.run([sys.executable, "-m", "swarm.cli", "sim", "--scenario", near_obstacle, "--duration", "0.1",
                          "--quiet"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "swarm sim: warning: robot 1 starts 0.31 m from obstacle 0, just outside its r = 0.3 m" in out.stderr


def test_scenario_scale_writes_a_scenario_that_fits_and_says_its_time_scale(tmp_path):
    p = run(["scenario", "scale", "paper-50hz", "--robots", "7", "--v-max", "0.22", "--w-max", "2.84"])
    assert p.returncode == 0, p.stderr
    assert "time scale k = 0.2719 (3.678 times slower: the same path in 441.315 s" in p.stderr
    # the file itself says so (it outlives the terminal)
    assert p.stdout.splitlines()[0].startswith("# scenario 'paper-50hz': 7 robots, 15 obstacles (written by swarm "
                                               "scenario scale from 'paper-50hz', time scale k = 0.2719 (3.678 times "
                                               "slower"), p.stdout.splitlines()[0]
    f = tmp_path / "burger.toml"
    f.write_text(p.stdout)
    check = run(["scenario", "check", str(f)])
    assert check.returncode == 0 and "warning" not in check.stdout, check.stdout


@pytest.mark.integration
@pytest.mark.timeout(300)
def test_swarm_sim_says_when_it_compiles_the_loop_it_is_about_to_run(tmp_path):
    """A first run says it compiles (here the parallel twin, from 256 robots), and its summary how much of its wall
    time that took; the same run again does neither. A run that needs another loop says so again: the fault
    kernel's, tests/unit/test_cli_args.py (each loop compiled here costs 15 s of the suite)."""
    env = {**os.environ, "SWARM_CACHE_DIR": str(tmp_path / "cache")}

    def said(*flags: str) -> bool:
        done = subprocess.run([*swarm_cmd(), "sim", "--duration", "0.2", *flags], env=env,
                              capture_output=True, text=True, timeout=240)
        assert done.returncode == 0, done.stderr
        compiling = "compiling the simulation kernel" in done.stderr
        wall = next(line for line in done.stdout.splitlines() if line.strip().startswith("wall time"))
        assert ("s of it compiling the loop, once" in wall) == compiling, wall
        return compiling

    assert said("--robots", "300") and not said("--robots", "300")
