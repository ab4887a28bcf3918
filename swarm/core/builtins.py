"""The built-in scenarios (docs/scenarios.md): `paper`, `paper-50hz` and `turtlebot3`, each as the dictionary its
TOML file would parse into (swarm.core.scenario_file parses and checks it like any file)."""

from __future__ import annotations

import math
from typing import Any

from swarm.core import generators
from swarm.core.errors import ScenarioError

BUILTINS = ("paper", "paper-50hz", "turtlebot3")
# What a scenario may hold of robots: beyond this a run cannot go (memory, time); swarm.core.scenario_file's limit
MAX_ROBOTS = 100_000


def builtin_document(name: str, robots: int | None = None) -> dict[str, Any]:
    """The built-in scenario `name` as the dictionary its TOML file would parse into.

    `paper` models the paper's Section 7 experiment: 37 robots, a 1.5 m hexagonal patch,
    a barrier of obstacles 2.6 m below the lowest slot, random starts below the barrier.
    `robots` scales it: the patch grows ring by ring, the start rectangle keeps 9 m^2 per
    robot (aspect 2.8:1, centred on x = 5 m, top edge 1.5 m below the barrier), and the
    barrier spans the rectangle plus 4.75 m on each side (centred on x = 4.7 m).
    `paper-50hz` is the same geometry at dt = 0.02 s with the safety governor on.
    `turtlebot3` is the same formation for TurtleBot3 Burger robots: every length halved (R = 0.6 m, 0.75 m
    spacing, obstacles' r = 0.15 m) but the robots' r = 0.22 m (two 0.105 m bodies touch at 0.21 m), the leader at 0.15 m/s (below 0.8 of the
    robot's v_max = 0.22 m/s, so followers catch up) along the same path's shape (the same turns at
    half the radius), the robots' limits v_max = 0.22 m/s and w_max = 2.84 rad/s, 20 Hz, governor on;
    7 robots unless `robots` says otherwise (with 37, the outer slots outrun v_max in the turns).
    """
    if name not in BUILTINS:
        raise ScenarioError(name, "", f"no such built-in scenario (built-ins: {', '.join(BUILTINS)}; "
                            "or give a path to a .toml file)")
    n = (7 if name == "turtlebot3" else 37) if robots is None else robots
    if not 1 <= n <= MAX_ROBOTS:
        raise ScenarioError("command line", "--robots", f"must be in 1..{MAX_ROBOTS}, got {n}")
    s = 0.5 if name == "turtlebot3" else 1.0  # lengths
    v = 0.15 if name == "turtlebot3" else 0.5  # the leader's speed [m/s]
    slow = (0.5 * s) / v  # durations stretch so the path keeps its lengths and turns
    width = math.sqrt(9.0 * n * 2.8) * s
    height = 9.0 * n * s * s / width
    lowest = float(generators.hex_patch(n, 1.5 * s)[:, 1].min())
    barrier_y = lowest - 2.6 * s
    intervals = max(1, round((width + 9.5 * s) / (1.6 * s)))
    top = barrier_y - 1.5 * s
    turn = math.pi / 32.0 / slow
    control = {"k1": 0.5, "k2": 0.5, "k3": 1.0, "tu": 1.0, "vt": 0.05, "threshold": "frozen",
               "governor": name != "paper"}
    if name == "turtlebot3":
        control.update(vt=0.02, v_max=0.22, w_max=2.84)
    return {
        "run": {"duration": 120.0 * slow, "dt": {"paper": 0.001, "paper-50hz": 0.02}.get(name, 0.05), "seed": 0},
        "control": control,
        # robots: r is the distance of two robots' centres at contact; a Burger's footprint radius is 0.105 m, so two
        # touch at 0.21 m: turtlebot3's r is 0.22 m (its obstacles keep the halved paper's 0.15 m)
        "bodies": {"r": 0.22 if name == "turtlebot3" else 0.3 * s, "R": 1.2 * s},
        "leader": {"start": [0.0, 0.0, 0.0], "segments": [
            {"duration": 10.0 * slow, "v": v, "w": 0.0},
            {"duration": 16.0 * slow, "v": v, "w": turn},
            {"duration": 8.0 * slow, "v": v, "w": 0.0},
            {"duration": 16.0 * slow, "v": v, "w": -turn},
            {"duration": 70.0 * slow, "v": v, "w": 0.0},
        ]},
        "formation": {"hex": {"count": n, "spacing": 1.5 * s}, "assignment": "random"},
        "robots": {"random": {"count": n, "region": [5.0 * s - width / 2, 5.0 * s + width / 2, top - height, top],
                              "min_separation": 0.8 * s, "obstacle_clearance": 1.2 * s}},
        "obstacles": [{"row": {"start": [4.7 * s - 0.8 * s * intervals, barrier_y],
                               "end": [4.7 * s + 0.8 * s * intervals, barrier_y], "pitch": 1.6 * s}, "r": 0.3 * s}],
    }
