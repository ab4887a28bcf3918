"""Dead is an obstacle, always, and real time never drives a robot into another (docs/runtime.md, "The safety
invariant"): robot processes killed outside any fault schedule (SIGKILL: a crash, an OOM kill, a dead battery)
in both modes, and a real-time swarm sharing the machine with CPU hogs. Bounded: every wait has a deadline, every
process is killed by its group."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import time

import pytest

from tests.integration.helpers import child_of, cpu_hogs, up, wait_for_ticks

pytestmark = pytest.mark.integration

KILLED = (1, 3, 5)
LOST = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3}) swarm\.robot WARNING: @@LOST (\d+) \(its liveliness "
                  r"token is gone\)$", re.M)


def _unix(stamp: str, ms: str) -> float:
    """Unix time of a log line's asctime (local time, ms)."""
    return time.mktime(time.strptime(stamp, "%Y-%m-%d %H:%M:%S")) + int(ms) / 1000.0


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


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_robots_killed_outside_the_schedule_are_bodies_named_and_the_survivors_converge(tmp_path, mode):
    """3 of 7 robots' processes get SIGKILL at t = 12 s, with no fault table and no restart: the world stops each
    at once and lists it, every robot takes it as a static body (a live robot drove into a dead one in every run
    before), the run ends with exit 3 naming the 3 lost robots, and the 4 survivors converge. In real time every
    receiver also loses 30 % of its messages (--drop 0.3), and every survivor hears each kill within 1 s."""
    extra = ("--speed", "2", "--drop", "0.3") if mode == "realtime" else ()
    duration = "72" if mode == "realtime" else "56"  # (30 % loss slows the last approach)
    cmd, metrics = up(tmp_path, "--robots", "7", "--restarts", "0", "--mode", mode, "--duration", duration, *extra)
    proc = _start(cmd)
    try:
        wait_for_ticks(cmd, "t", 600, proc, timeout_s=120)  # t = 12 s (dt 0.02)
        for i in KILLED:
            child_of(proc, "robot", i).kill()
        killed_at = time.time()
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
        assert m["messages_dropped"] > 0
    for i in set(range(7)) - set(KILLED):  # every survivor heard of each kill, within 1 s
        lines = (tmp_path / "logs" / f"robot-{i}.log").read_text()
        for j in KILLED:
            stamps = LOST.findall(lines.replace(f"robot {i}: robot {j} lost", f"@@LOST {j}"))
            assert any(j == int(k) and abs(_unix(s, ms) - killed_at) <= 1.0 for s, ms, k in stamps), (i, j)


def test_a_real_time_swarm_beside_two_cpu_hogs_never_collides(tmp_path):
    """19 robots at twice real time with two busy processes on the machine (each a core's worth of demand): the
    control round trip stretches and commands come late, and the robots' safety rule holds them back instead
    of letting a late command carry one into another."""
    cmd, metrics = up(tmp_path, "--robots", "19", "--mode", "realtime", "--speed", "2", "--duration", "30",
                      "--allow-violations")
    with cpu_hogs(2):
        proc = _start(cmd)
        try:
            rc, text = _finish(proc, 240)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
    m = json.loads(metrics.read_text())
    assert rc == 0 and m["failure"] is None, text[-3000:]
    assert m["collisions"] == 0, text[-3000:]
    assert m["round_trip_ms_p99"] > 0 and m["held_back"] is not None
