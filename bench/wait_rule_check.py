"""The lock-step world's wait-rule check: its cost a tick, with and without its shortcut.

    python bench/wait_rule_check.py [--robots 37] [--duration 120]

Replays `swarm sim`'s trajectory of the built-in paper-50hz scenario through World._check_wait_rule, as
the world runs it once a tick, twice: looking at every pair every step, and with the shortcut that looks
only after a step in which some robot moved more than L (docs/runtime.md, "Lock-step: why a distributed
run equals `swarm sim`"). Prints the thread's CPU a tick for each, the pairs each counted (they must be
equal), and how many steps had a robot moving more than L.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarm.core import scenario_file  # noqa: E402
from swarm.core.scenario_file import Overrides  # noqa: E402
from swarm.core.sim import Simulation  # noqa: E402
from swarm.net.bus import MemoryBus, MemoryNet  # noqa: E402
from swarm.proto import keys  # noqa: E402
from world.world import World  # noqa: E402


def replay(scn, q: np.ndarray, shortcut: bool) -> tuple[float, int]:
    """(CPU [s] a tick, pairs counted) of the check over the poses q[k]."""
    world = World(MemoryBus(MemoryNet()), scn, "bench", lockstep=True)
    world.alive[:] = True
    rows = [[list(r) for r in q[k]] for k in range(len(q))]
    t0 = time.thread_time()
    for k in range(1, len(q)):
        world.q = rows[k]
        if not shortcut:
            world._short_step = False
        world._check_wait_rule(k * scn.dt, q[k - 1][:, :2].copy())
    return (time.thread_time() - t0) / (len(q) - 1), world.overruns


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--duration", type=float, default=120.0, help="simulated seconds (default: the whole paper run)")
    a = ap.parse_args()
    if a.robots < 2 or a.duration <= 0:
        ap.error("--robots must be at least 2 and --duration positive")
    logging.disable(logging.WARNING)  # a long step is logged by the world; counted below anyway
    scn = scenario_file.load("paper-50hz", Overrides(robots=a.robots, duration=a.duration), progress=scenario_file.silent)
    q = Simulation(scn, record_period=scn.dt).run().recording.q
    L = keys.lockstep_step_bound(scn.reach, scn.cell_side)
    steps = np.sqrt(((q[1:, :, :2] - q[:-1, :, :2]) ** 2).sum(axis=2)).max(axis=1)
    long = np.flatnonzero(steps > L)
    print(f"N = {scn.n}, {len(q) - 1} steps of {scn.dt:g} s: {long.size} with a robot moving more than L = {L:.3f} m"
          + (f" (the last at t = {(long.max() + 1) * scn.dt:g} s)" if long.size else ""))
    for shortcut in (False, True):
        cpu, pairs = replay(scn, q, shortcut)
        print(f"  {'with the shortcut' if shortcut else 'every step      '}: {1e6 * cpu:.0f} us a tick, {pairs} pairs counted")


if __name__ == "__main__":
    main()
