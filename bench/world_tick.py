"""The world's own work a lock-step tick, part by part (no bus traffic timed but its puts on a memory bus).

    python bench/world_tick.py [--robots 37] [--repeat 300]

Builds the world of the built-in paper-50hz scenario with N robots, every robot alive and in its slot
around the leader at t = 10 s, and times (warm, the mean of --repeat calls) what `World._run_lockstep`
does each tick besides waiting: taking the N commands (on zenoh's threads, each with its check that
every awaited command is in, each robot's next pose stepped and encoded as its command comes), the same with
the last command ending the tick on its thread (the poses copied in, the clock and every pose published),
moving every robot one exact arc and publishing the clock and every pose as the run loop does when it ends
a tick, the wait-rule check, and the metrics sample (its pairs compiled, and in numpy). Memory-bus puts.
Which of them stand between the last command of tick k and the first pose of tick k + 1 (the path every
robot waits on) is in docs/performance.md ("The world's part of a lock-step tick").
"""

from __future__ import annotations

import argparse
import sys
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from swarm.core import kinematics  # noqa: E402
from swarm.core.scenario_file import Overrides, load  # noqa: E402
from swarm.proto import keys, protocol  # noqa: E402
from swarm.net.bus import MemoryBus, MemoryNet  # noqa: E402
from world import referee as referee_mod  # noqa: E402
from world.world import World  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--repeat", type=int, default=300, help="calls timed per part (default 300)")
    a = ap.parse_args()
    if a.robots < 2 or a.repeat < 1:
        ap.error("--robots must be at least 2 and --repeat at least 1")
    scn = load("paper-50hz", Overrides(robots=a.robots))
    world = World(MemoryBus(MemoryNet()), scn, "bench", lockstep=True)
    world.alive[:] = True
    world.leader_alive = True
    x, y, th, _, _ = scn.leader.state(10.0)
    for i in range(scn.n):
        world.q[i][:] = [x + float(scn.offsets[i][0]), y + float(scn.offsets[i][1]), th]
    before = np.array(world.q)[:, :2] - 0.01  # every robot moved 1.4 cm this tick
    world.k, world._await = 500, 500

    def steps() -> None:
        for i in range(scn.n):
            kinematics.step_pose(world.q[i], world.comp[i], 0.5, 0.1, scn.dt)

    cmd_keys = [keys.robot_cmd("bench", i) for i in range(scn.n)]
    cmds = [protocol.encode(protocol.Cmd(t=10.0, seq=500, v=0.5, w=0.1)) for _ in range(scn.n)]

    def take_commands(take_over: bool = False) -> None:  # what zenoh's threads run for a tick's commands
        world.k, world.t, world._await = 500, 10.0, 500
        world._inline_from = 500 if take_over else -1  # the run loop waits at tick 500: the last command may end it
        world.cmd_seq = [-1] * scn.n
        world._awaited = set(range(scn.n))
        world._pending = {}
        for key, payload in zip(cmd_keys, cmds):
            world._on_cmd(key, payload)
        world.wake.clear()
        if take_over and world.k != 501:
            sys.exit("the last command did not end the tick (World._take_over)")

    def numpy_sample() -> None:
        compiled, referee_mod._referee = referee_mod._referee, None
        try:
            world._sample(10.0)
        finally:
            referee_mod._referee = compiled

    parts = [
        (f"{scn.n} commands taken, each robot's next pose stepped and encoded (World._on_cmd)", take_commands, 1),
        ("the same, the last one ending the tick: the poses in, clock and poses out (_take_over)",
         lambda: take_commands(True), 1),
        (f"{scn.n} exact arcs (the run loop, when it ends a tick)", steps, 1),
        ("wait-rule check", lambda: world._check_wait_rule(10.0, before), 1),
        ("metrics sample" + (" (pairs compiled: world/_referee.c)" if referee_mod._referee is not None else ""),
         lambda: world._sample(10.0), 1),
        ("metrics sample, pairs in numpy", numpy_sample, 1),
        (f"clock and {scn.n} poses published (the run loop)", lambda: world._publish_tick(10.0, 500), 1),
    ]
    print(f"the world's work a lock-step tick at N = {scn.n} (warm, mean of {a.repeat} calls):")
    for name, fn, times in parts:
        q, comp = [list(p) for p in world.q], [list(c) for c in world.comp]
        us = 1e6 * timeit.timeit(fn, number=a.repeat) / a.repeat * times
        world.q, world.comp = q, comp  # every part sees the same poses
        print(f"  {name:<86} {us:6.0f} us")


if __name__ == "__main__":
    main()
