"""A simulated fleet of ROS 2 robots for the real-fleet tests: robots that are not the swarm's.

    python -m tests.deploy.fleet_sim --listen tcp/127.0.0.1:P --inventory F --scenario S \
        [--stale I] [--silent I] [--rate HZ] [--speed X] [--truth out.json]

It is what a fleet of TurtleBot3s looks like on zenoh, and nothing more: world.ros2_fleet's Ros2Fleet
(cmd_vel in, odometry out in each robot's own odom frame, rmw_zenoh's liveliness tokens and
attachments, or the bridge's keys), unicycles moved along exact arcs on this process's own wall
clock, each holding its last command (a TurtleBot3 has no cmd_vel timeout) clamped to its limits as
a robot's firmware clamps it. It serves a zenoh router of its own (a robot's rmw_zenohd or bridge),
which the swarm's router connects to (the inventory's `connect`). It knows nothing of the swarm: no
clock, no configuration, no referee, no swarm key. The robots stand where the inventory says they do
(scenario + initial_pose). Faults for the pre-flight: --stale I publishes robot I's odometry at
0.4 Hz, --silent I never. --truth writes, at exit, the ground truth to hold the odometry-based
referee to: the smallest distance between two robots at any odometry instant, the final poses, and
the commands taken (how many were beyond the robot's limits, and the largest |v| and |w|). --speed runs the fleet's time that much faster than the wall clock (with
`--speed` given to the referee as well).
"""

from __future__ import annotations

import argparse
import heapq
import json
import math
import faulthandler
import os
import signal
import sys
import threading
import time

import numpy as np

from swarm.core import inventory, kinematics, scenario_file
from swarm.core.scenario_file import Overrides
from swarm.net.bus import ROUTER_RUNTIME, ZenohBus, zenoh_config
from world.ros2_fleet import Ros2Fleet

STALE_HZ = 0.4


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="fleet_sim")
    p.add_argument("--listen", required=True)
    p.add_argument("--inventory", required=True)
    p.add_argument("--scenario", required=True)
    p.add_argument("--robots", type=int)
    p.add_argument("--rate", type=float, default=20.0, help="odometry per robot per second of the fleet's time")
    p.add_argument("--speed", type=float, default=1.0)
    p.add_argument("--stale", type=int, action="append", default=[])
    p.add_argument("--silent", type=int, action="append", default=[])
    p.add_argument("--truth")
    a = p.parse_args(argv)
    fleet = inventory.apply(inventory.load(a.inventory),
                            scenario_file.load(a.scenario, Overrides(robots=a.robots), progress=scenario_file.silent))
    entries = [r.entry for r in fleet.robots]
    kinds = {(e.flavor, e.twist, e.domain) for e in entries}
    if len(kinds) != 1:
        print(f"fleet_sim: one flavor, twist and domain for every robot, got {sorted(kinds)}", file=sys.stderr)
        return 2
    flavor, twist, domain = kinds.pop()
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # a test that waited too long asks where each thread is
    os.environ.setdefault("ZENOH_RUNTIME", ROUTER_RUNTIME)  # as `swarm router`: a lingering link blocks no receiving
    bus = ZenohBus(zenoh_config("router", listen=[a.listen]))
    names = {e.id: e.namespace for e in entries}
    ros = Ros2Fleet(bus, [tuple(map(float, q)) for q in fleet.scenario.poses], flavor, twist, domain,
                    namespace=lambda i: names[i])
    ros.start()
    try:
        truth = run(ros, fleet, a, stop)
        if a.truth:  # before closing: a close can take zenoh's 10 s link linger (tests/deploy/test_fleet_processes.py)
            with open(a.truth, "w") as f:
                json.dump(truth, f)
            print(f"fleet_sim: the ground truth is in {a.truth}; closing", file=sys.stderr, flush=True)
    finally:
        ros.close()
        bus.close()
    return 0


def run(ros: Ros2Fleet, fleet: inventory.Fleet, a, stop: threading.Event) -> dict:
    n = fleet.scenario.n
    q = [list(map(float, row)) for row in fleet.scenario.poses]
    comp = [[0.0, 0.0, 0.0] for _ in range(n)]
    cmd = [(0.0, 0.0)] * n
    tq = [0.0] * n
    limits = [fleet.limits(i) for i in range(n)]
    period = 1.0 / a.rate
    rate = [STALE_HZ if i in a.stale else a.rate for i in range(n)]
    due = [(i * period / n, i) for i in range(n) if i not in a.silent]
    heapq.heapify(due)
    t0 = time.monotonic()
    min_d, moved, commands = math.inf, [0.0] * n, 0
    beyond, top_v, top_w = 0, 0.0, 0.0  # commands beyond the robot's limits (before the clamp), the largest |v|, |w|

    def now() -> float:
        return (time.monotonic() - t0) * a.speed

    def advance(i: int, t: float) -> None:
        if t > tq[i]:
            before = q[i][:2]
            kinematics.step_pose(q[i], comp[i], cmd[i][0], cmd[i][1], t - tq[i])
            moved[i] += math.hypot(q[i][0] - before[0], q[i][1] - before[1])
            tq[i] = t

    while not stop.is_set():
        t = now()
        for i, v, w in ros.take_commands():
            advance(i, t)
            v_max, w_max = limits[i]
            beyond += bool((v_max and abs(v) > v_max * (1 + 1e-9)) or (w_max and abs(w) > w_max * (1 + 1e-9)))
            top_v, top_w = max(top_v, abs(v)), max(top_w, abs(w))
            cmd[i] = (max(-v_max, min(v_max, v)) if v_max else v, max(-w_max, min(w_max, w)) if w_max else w)
            commands += 1
        while due and due[0][0] <= t:
            _, i = heapq.heappop(due)
            for j in range(n):
                advance(j, t)
            xy = np.array([row[:2] for row in q])
            d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
            d[np.diag_indices(n)] = math.inf
            min_d = min(min_d, float(d.min())) if n > 1 else min_d
            ros.publish_odom(i, t, *q[i], *cmd[i])
            heapq.heappush(due, (t + 1.0 / rate[i], i))
        wait = ((due[0][0] - now()) / a.speed) if due else 0.05
        stop.wait(min(0.005, max(0.0, wait)))
    for i in range(n):
        advance(i, now())
    return {"min_distance_m": None if math.isinf(min_d) else min_d, "poses": q, "moved_m": moved,
            "commands": commands, "beyond_limits": beyond, "max_abs_v": top_v, "max_abs_w": top_w, "t": now()}


if __name__ == "__main__":
    sys.exit(main())
