"""Dead is an obstacle, always, and real time never drives a robot into another (docs/runtime.md, "The safety
invariant"): robot processes killed outside any fault schedule (SIGKILL: a crash, an OOM kill, a dead battery)
in both modes, and a real-time swarm sharing the machine with CPU hogs. Bounded: every wait has a deadline, every
process is killed by its group."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from tests.integration.helpers import child_of, up, wait_for_ticks

pytestmark = pytest.mark.integration

KILLED = (1, 3, 5)


def _start(cmd: list[str]) -> subprocess.Popen:
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)


def _finish(proc: subprocess.Popen, timeout_s: float) -> tuple[int, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        raise AssertionError(f"swarm up did not end in {timeout_s:g} s:\n{out[-3000:]}\n{err[-3000:]}") from None
    return proc.returncode, out + err


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_robots_killed_outside_the_schedule_are_bodies_named_and_the_survivors_converge(tmp_path, mode):
    """3 of 7 robots' processes get SIGKILL at t = 20 s, with no fault table and no restart: the world stops each
    at once and lists it, every robot takes it as a static body (a live robot drove into a dead one in every run
    before), the run ends with exit 3 naming the 3 lost robots, and the 4 survivors converge."""
    extra = ("--speed", "2") if mode == "realtime" else ()
    cmd, metrics = up(tmp_path, "--robots", "7", "--restarts", "0", "--mode", mode, "--duration", "80", *extra)
    proc = _start(cmd)
    try:
        wait_for_ticks(cmd, "t", 1000, proc, timeout_s=120)  # t = 20 s (dt 0.02)
        for i in KILLED:
            child_of(proc, "robot", i).kill()
        rc, text = _finish(proc, 180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    m = json.loads(metrics.read_text())
    assert rc == 3, text[-3000:]
    assert m["collisions"] == 0, text[-3000:]
    assert m["lost_robots"] == list(KILLED) and m["robots_alive_at_end"] == 4
    assert "3 robots lost (1, 3, 5)" in text
    assert m["converged_at_s"] is not None and m["stranded"] == [], (m["final_position_error_max_m"], text[-3000:])
    if mode == "realtime":  # the survivors' laws and rules held them back now and then, and said so
        assert m["held_back"] is not None and "real time" in text


def test_a_real_time_swarm_beside_two_cpu_hogs_never_collides(tmp_path):
    """19 robots at twice real time with two busy processes on the machine (each a core's worth of demand): the
    control round trip stretches and commands come late, and the robots' safety rule holds them back instead
    of letting a late command carry one into another."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True) for _ in range(2)]
    cmd, metrics = up(tmp_path, "--robots", "19", "--mode", "realtime", "--speed", "2", "--duration", "60",
                      "--allow-violations")
    proc = _start(cmd)
    try:
        rc, text = _finish(proc, 240)
    finally:
        for h in hogs:
            os.killpg(h.pid, signal.SIGKILL)
            h.wait(10)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    m = json.loads(metrics.read_text())
    assert rc == 0 and m["failure"] is None, text[-3000:]
    assert m["collisions"] == 0, text[-3000:]
    assert m["round_trip_ms_p99"] > 0 and m["held_back"] is not None
