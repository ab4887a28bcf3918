"""Robots on the ROS 2 drive against the simulated ROS 2 fleet, as real processes over a zenoh router:
the swarm converges through cmd_vel and odometry; the robot-side watchdog and the emergency stop put
zero velocity on cmd_vel, measured by a listener of the robots' cmd_vel topics."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time

import psutil
import pytest

from swarm.net.bus import ZenohBus, zenoh_config
from swarm.proto import keys, ros2
from tests.integration.helpers import child_of, descendants, up, wait_for_ticks, wait_until

pytestmark = pytest.mark.integration
CLI = [sys.executable, "-m", "swarm.cli"]


class CmdVel:
    """Listens to robot i's cmd_vel (bridge keys) and remembers (wall time, v, w) of every command."""

    def __init__(self, endpoint: str, robots: int, twist: str = "plain") -> None:
        self.bus = _bus(endpoint)
        self.lock = threading.Lock()
        self.cmds: dict[int, list[tuple[float, float, float]]] = {i: [] for i in range(robots)}
        decode = ros2.decode_twist if twist == "plain" else ros2.decode_twist_stamped
        self.estops: list[float] = []  # wall times the emergency stop was heard here
        self.bus.subscribe(keys.estop("t"), lambda k, b: self.estops.append(time.monotonic()))
        for i in range(robots):
            self.bus.subscribe(ros2.bridge_key(f"robot{i}", ros2.CMD_VEL),
                               lambda k, b, i=i: self._on(i, decode(b)))

    def _on(self, i: int, vw: tuple[float, float]) -> None:
        with self.lock:
            self.cmds[i].append((time.monotonic(), *vw))

    def moving(self, i: int) -> int:
        with self.lock:
            return sum(1 for _, v, w in self.cmds[i] if v or w)

    def first_zero_after(self, i: int, t0: float) -> float | None:
        with self.lock:
            return next((t for t, v, w in self.cmds[i] if t >= t0 and v == 0.0 and w == 0.0), None)

    def last(self, i: int):
        with self.lock:
            return self.cmds[i][-1] if self.cmds[i] else None

    def close(self) -> None:
        self.bus.close()


def _bus(endpoint: str) -> ZenohBus:
    def connect():
        try:
            return ZenohBus(zenoh_config(connect=[endpoint]))
        except Exception:  # the router is not up yet
            return None

    return wait_until(connect, 30, f"a router at {endpoint}", every_s=0.1)


@pytest.mark.slow
def test_five_ros2_robots_converge_on_rmw_zenoh(tmp_path):
    # speed 2, not 3: less load. 90 s: alone it converges at 38 s, but beside the unit tests its robots' safety
    # rule held them back long enough (late messages) that one run in CI had not converged at 60 s, exit 0 (no
    # robot stranded, no collision): slower under load, as it should be, not wrong
    cmd, metrics = up(tmp_path, "--robots", "5", "--mode", "realtime", "--drive", "ros2", "--duration", "90",
                      "--speed", "2", "--quiet")
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr + "".join(p.read_text()[-2000:] for p in (tmp_path / "logs").glob("*.log"))
    m = json.loads(metrics.read_text())
    said = {k: m.get(k) for k in ("converged_at_s", "collisions", "bad_messages", "final_position_error_max_m",
                                  "final_orientation_error_max_rad", "stranded", "last_freeze_end_s", "samples_missed",
                                  "cmd_held", "watchdog_stops", "robots_alive_at_end", "host_steal_pct")}
    assert m["converged_at_s"] is not None and m["collisions"] == 0 and m["bad_messages"] == 0, \
        f"{said}\n{out.stdout[-1500:]}"


@pytest.mark.parametrize("flavor, twist, release", [("bridge", "plain", "v2"), ("bridge", "stamped", "v2"),
                                                    ("rmw_zenoh", "stamped", "v2"), ("rmw_zenoh", "plain", "v1")])
def test_commands_reach_the_robots_and_odometry_is_used(tmp_path, flavor, twist, release):
    """Each family: bridge, current rmw_zenoh (Jazzy, stamped), an older rmw_zenoh release (the named-field
    attachment, Humble's plain Twist and keys without type hashes) that drops a command of the other form. The
    robots run with a field robot's defaults (`swarm up` gives them only the flavour and the domain): they find the
    twist type from the robot's token or its bridge's route and the attachment form from its odometry, and every
    command is taken (a dropped one would count as a bad message)."""
    cmd, metrics = up(tmp_path, "--robots", "3", "--mode", "realtime", "--drive", "ros2", "--ros-flavor", flavor,
                      "--twist", twist, "--duration", "10", "--speed", "2", "--quiet",
                      *(["--rmw-zenoh-attachment", release] if flavor == "rmw_zenoh" else []),
                      *(["--distro", "humble"] if twist == "plain" else []))
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr + "".join(p.read_text()[-2000:] for p in (tmp_path / "logs").glob("*.log"))
    m = json.loads(metrics.read_text())
    # the robots moved (commands delivered) toward their slots (their odometry closed the loop)
    assert m["collisions"] == 0 and m["bad_messages"] == 0 and m["robots_alive_at_end"] == 3
    assert m["final_position_error_max_m"] < 10.0 and m["steps"] >= 400
    said = (tmp_path / "logs" / "robot-0.log").read_text()
    # the robots ran with a field robot's defaults: the twist type from the robot's token or its bridge's route
    how = "its rmw_zenoh token" if flavor == "rmw_zenoh" else "the bridge's route"
    assert f"subscribes /robot0/cmd_vel as {ros2.twist_type(twist)} ({how})" in said, said[-3000:]
    if flavor == "rmw_zenoh":
        assert f"the robot's attachments are {release}" in said and "did not move" not in said, said[-3000:]


def test_watchdog_estop_and_ctrl_c_put_zero_velocity_on_cmd_vel(tmp_path):
    """Stop the pose stream: zero within 0.5 s; swarm stop: every robot zero within a period (of its
    receipt) and held until release; the leader lost: zero at once; Ctrl-C on a robot: zero before it exits."""
    cmd, _ = up(tmp_path, "--robots", "3", "--mode", "realtime", "--drive", "ros2", "--ros-flavor", "bridge",
                "--duration", "300", "--restarts", "0", "--lost-timeout", "60", "--quiet")
    endpoint = cmd[cmd.index("--listen") + 1]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    listener = None
    try:
        wait_for_ticks(cmd, "t", 150, proc)  # 3 s of motion
        listener = CmdVel(endpoint, 3)
        wait_until(lambda: all(listener.moving(i) > 10 for i in range(3)), 20, "robots moving")

        # the emergency stop: every robot zero, held until the release
        t0 = time.monotonic()
        stop = subprocess.run(CLI + ["stop", "--fleet", "t", "--connect", endpoint, "--reason", "test"],
                              capture_output=True, text=True, timeout=60)
        assert stop.returncode == 0, stop.stderr
        heard = listener.estops[0]
        for i in range(3):  # within a control period (0.02 s) of the stop reaching the robots: 0.1 s on a loaded CI
            t = listener.first_zero_after(i, heard)
            assert t is not None and t - heard < 0.1, f"robot {i} stopped {t and t - heard} s after the stop"
        time.sleep(0.5)  # what is measured: nothing but zero for this long while the stop holds
        for i in range(3):
            assert listener.last(i)[1:] == (0.0, 0.0)
        n_before = [listener.moving(i) for i in range(3)]
        time.sleep(0.3)
        assert [listener.moving(i) for i in range(3)] == n_before
        subprocess.run(CLI + ["stop", "--release", "--fleet", "t", "--connect", endpoint], check=True, timeout=60,
                       capture_output=True)
        wait_until(lambda: all(listener.moving(i) > n_before[i] for i in range(3)), 10, "moving again after release")

        # the pose stream stops (the world hangs): each robot's guard halts it within 0.5 s
        world = child_of(proc, "world")
        world.send_signal(signal.SIGSTOP)
        t0 = time.monotonic()
        try:
            wait_until(lambda: all(listener.first_zero_after(i, t0) is not None for i in range(3)), 5, "zero after hang")
            for i in range(3):
                assert listener.first_zero_after(i, t0) - t0 < 0.5 + 0.2, f"robot {i} took too long"
        finally:
            world.send_signal(signal.SIGCONT)
        wait_until(lambda: all(listener.moving(i) > n_before[i] + 5 for i in range(3)), 10, "moving again after resume")

        # Ctrl-C on a robot: zero velocity before it exits
        victim = child_of(proc, "robot", 1)
        t0 = time.monotonic()
        victim.send_signal(signal.SIGINT)
        victim.wait(10)
        assert listener.first_zero_after(1, t0) is not None

        # the leader lost: the others stop at once
        t0 = time.monotonic()
        child_of(proc, "leader").kill()
        wait_until(lambda: all(listener.first_zero_after(i, t0) is not None for i in (0, 2)), 5, "zero after leader lost")
        for i in (0, 2):
            assert listener.first_zero_after(i, t0) - t0 < 0.5
    finally:
        if listener is not None:
            listener.close()
        for p in descendants(proc.pid):
            try:
                p.send_signal(signal.SIGCONT)
            except psutil.NoSuchProcess:
                pass
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
