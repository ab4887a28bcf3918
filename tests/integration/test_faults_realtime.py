"""Faults for real in `swarm up --mode realtime` (docs/faults.md, Lock-step and real time under faults): 30 % of
every message lost by each receiver's fault bus, and robot 2's process really killed (SIGKILL) at 5 s by the
schedule: every surviving robot hears that robot 2's liveliness token is gone within 1 s of the kill the
supervisor logged, and the world counts it as the schedule's, not a lost robot. (That the survivors of
kills, scheduled or not, converge under 30 % loss: tests/integration/test_safe_realtime.py.) Bounded: `swarm
up` runs under a timeout and stops every process it started."""

from __future__ import annotations

import json
import re
import subprocess
import time

import pytest

from tests.integration.helpers import up

pytestmark = pytest.mark.integration

N = 7
DURATION = 12  # simulated s: 6 wall s at speed 2
KILLED = 2
LOST = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3}) swarm\.robot WARNING: robot (\d+): robot (\d+) lost "
                  r"\(its liveliness token is gone\)$", re.M)
KILL = re.compile(r"^(\d+\.\d+) t = ([\d.]+) s: robot (\d+) killed \(SIGKILL, pid (\d+)\)$", re.M)


def log_time(stamp: str, ms: str) -> float:
    """Unix time of a log line's asctime (local time, ms)."""
    return time.mktime(time.strptime(stamp, "%Y-%m-%d %H:%M:%S")) + int(ms) / 1000.0


def test_realtime_drop_and_a_scheduled_kill_the_survivors_see_within_a_second(tmp_path):
    cmd, metrics = up(tmp_path, "--mode", "realtime", "--robots", str(N), "--duration", str(DURATION), "--speed", "2",
                      "--drop", "0.3", "--kill", f"{KILLED}@5", "--quiet")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    logs = tmp_path / "logs"
    m = json.loads(metrics.read_text())
    assert out.returncode == 0, (out.stderr, {k: m.get(k) for k in ("collisions", "converged_at_s", "failure")})

    # the supervisor really killed robot 2's process at 5 s ...
    kills = KILL.findall((logs / "faults.log").read_text())
    assert len(kills) == 1 and int(kills[0][2]) == KILLED and 5.0 <= float(kills[0][1]) < 5.1
    killed_at = float(kills[0][0])
    robot2 = (logs / f"robot-{KILLED}.log").read_text()
    assert "loop CPU" not in robot2  # a clean exit logs its counters: a SIGKILLed process cannot
    assert f"robot {KILLED}'s token is gone at t = 5." in (logs / "world.log").read_text()

    # ... and every survivor logged robot 2 lost within 1 s of it
    for i in range(N):
        if i == KILLED:
            continue
        seen = [log_time(s, ms) for s, ms, me, other in LOST.findall((logs / f"robot-{i}.log").read_text())
                if int(me) == i and int(other) == KILLED]
        assert seen, f"robot {i} never logged robot {KILLED} lost"
        assert abs(seen[0] - killed_at) <= 1.0, (i, seen[0] - killed_at)

    # no collision, and the faults were really there
    assert m["mode"] == "realtime" and m["collisions"] == 0
    assert m["robots_alive_at_end"] == N - 1 and m["robots_lost"] == 0  # a scheduled kill is no loss
    f = m["faults"]
    assert f["killed"] == 1 and f["restarted"] == 0 and m["robot_restarts"] == 0
    for cls in ("state", "pose", "cmd", "ref"):
        assert f["dropped"][cls] > 0, cls
    assert m["messages_dropped"] == sum(f["dropped"].values())


def test_realtime_robots_that_lose_every_pose_still_report_what_they_lost(tmp_path):
    """--drop 1 in real time: no robot ever makes a step (every pose is lost), so no status carries its
    fault counters; the waker reports them anyway, and the metrics count the poses lost (they said 0)."""
    duration = 4
    cmd, metrics = up(tmp_path, "--mode", "realtime", "--robots", "3", "--duration", str(duration), "--drop", "1",
                      "--quiet")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    m = json.loads(metrics.read_text())
    assert out.returncode == 0, (out.stderr, m.get("failure"))
    dropped = m["faults"]["dropped"]
    # every robot loses the world's 50 poses a second: most of 3 x 4 x 50, less the last reports' lag
    assert dropped["pose"] >= 0.5 * 3 * duration * 50, dropped
    assert m["messages_dropped"] == sum(dropped.values()) > 0
    for i in range(3):  # nothing moved: not one step, so not one command
        assert re.search(rf"robot {i}, run \S+: 0 ticks", (tmp_path / "logs" / f"robot-{i}.log").read_text())


def test_a_robot_back_from_a_scheduled_hang_is_no_bad_message(tmp_path):
    """A hang longer than the world's window on a robot's commands (2 s): the resumed robot's first commands
    can reach the world before its new liveliness token does, and jumped the window: counted as bad
    messages (2 in every such run). The schedule explains the gap, so the window starts again there.
    (--allow-violations: what is checked here is the count of bad messages, not the run's safety.)"""
    faults = tmp_path / "hang.toml"
    faults.write_text("[faults]\n[[faults.hang]]\nrobot = 3\nat = 2.0\nduration = 3.0\n")
    cmd, metrics = up(tmp_path, "--mode", "realtime", "--robots", "7", "--duration", "8", "--speed", "2",
                      "--faults", str(faults), "--quiet", "--allow-violations")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=150)
    m = json.loads(metrics.read_text())
    assert out.returncode == 0, (out.stderr, m.get("failure"))
    assert m["faults"]["hung"] == 1 and m["robots_lost"] == 0
    world = (tmp_path / "logs" / "world.log").read_text()
    assert "robot 3's token is gone at t = " in world  # the hang outlasted the lease: its session went
    assert m["bad_messages"] == 0, [line for line in world.splitlines() if "bad message" in line]
