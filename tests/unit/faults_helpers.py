"""Shared by the fault-model tests (tests/unit/test_faults_contract.py, test_faults_decisions.py): the size
of the scenario the faults are checked against, the example of the faults contract (docs/faults.md) and the
rules it parses to, `parse` ([faults] text to Faults), `_rule` (the text of a [faults] table of one rule) and
`_random_faults` (a random valid Faults, for round trips and for comparing the schedule and decision code)."""

from __future__ import annotations

import math
import tomllib

import numpy as np

from swarm.core import faults as F
from swarm.core.faults import (
    DelayRule,
    DropRule,
    Faults,
    Hang,
    Kill,
    Partition,
)

N = 7  # robots of the scenario the faults are checked against
DURATION = 60.0  # s


# The example of the faults contract (docs/faults.md).
CONTRACT = """
[faults]
seed = 7                  # optional, default run.seed

[[faults.drop]]           # lose messages, each message on each link on its own
class = "state"           # "state" | "pose" | "cmd" | "ref" | "all"
p = 0.3                   # probability, 0 <= p <= 1
burst = 1.0               # optional mean burst length in messages (>= 1; 1 = independent losses)
from = [0, 3]             # optional sender robot ids (default: all)
to = [1, 2]               # optional receiver robot ids (default: all)
start = 10.0              # optional window [start, end) in simulated seconds (default: the whole run)
end = 30.0

[[faults.delay]]          # deliver late (same optional keys as drop)
class = "state"
ticks = 2                 # control periods late (lock-step: ticks; real time: ticks x dt)
jitter = 1                # optional: plus a uniform whole number 0..jitter (messages then reorder)

[[faults.partition]]      # nothing crosses between the groups during the window
groups = [[0, 1, 2], [3, 4]]   # robot ids; robots in no group form one more group
start = 20.0
end = 22.0

[[faults.kill]]           # the robot's process is killed (SIGKILL)
robot = 5
at = 15.0
restart = 2.0             # optional: seconds later a new process takes the robot over

[[faults.hang]]           # the robot's process is stopped (SIGSTOP), then resumed (SIGCONT)
robot = 3
at = 10.0
duration = 3.0
"""


CONTRACT_FAULTS = Faults(
    seed=7,
    drops=(DropRule("state", 0.3, 1.0, (0, 3), (1, 2), 10.0, 30.0),),
    delays=(DelayRule("state", 2, 1),),
    partitions=(Partition(((0, 1, 2), (3, 4)), 20.0, 22.0),),
    kills=(Kill(5, 15.0, 2.0),),
    hangs=(Hang(3, 10.0, 3.0),),
)


def parse(text: str, robots: int = N, duration: float = DURATION, seed: int = 0) -> Faults:
    return F.parse_faults(tomllib.loads(text)["faults"], "f.toml", robots, duration, seed)


def _rule(kind: str, body: str) -> str:
    return f"[faults]\n[[faults.{kind}]]\n{body}\n"


DROP = 'class = "state"\np = 0.3\n'


def _random_faults(rng: np.random.Generator) -> Faults:
    def ids():
        return None if rng.random() < 0.5 else tuple(int(i) for i in rng.choice(N, rng.integers(1, N + 1), False))

    def window():
        start = float(rng.uniform(0, 50)) if rng.random() < 0.7 else 0.0
        return start, (start + float(rng.uniform(1e-6, 20)) if rng.random() < 0.7 else math.inf)

    def cls(robot_ends=True):
        return str(rng.choice(["state", "all"] if robot_ends else list(F.CLASSES)))

    drops = tuple(DropRule(cls(), float(rng.uniform(0, 0.5)), float(rng.choice([1.0, rng.uniform(1, 20)])),
                           ids(), ids(), *window()) for _ in range(rng.integers(0, 4)))
    delays = tuple(DelayRule(cls(), int(rng.integers(0, 5)), int(rng.integers(0, 3)), ids(), ids(), *window())
                   for _ in range(rng.integers(0, 3)))
    parts, t = [], 0.0
    for _ in range(rng.integers(0, 3)):
        start = t + float(rng.uniform(0, 5))
        t = start + float(rng.uniform(0.1, 5))
        split = int(rng.integers(1, N))
        perm = [int(i) for i in rng.permutation(N)]
        parts.append(Partition((tuple(perm[:split]),), start, t))
    kills, hangs, t = [], [], 0.0
    for robot in rng.choice(N, 3, False):
        at = float(rng.uniform(0, 50))
        if rng.random() < 0.5:
            kills.append(Kill(int(robot), at, float(rng.uniform(0.1, 5)) if rng.random() < 0.5 else None))
        else:
            hangs.append(Hang(int(robot), at, float(rng.uniform(0.1, 5))))
    return Faults(int(rng.integers(0, 2**63 - 1)), drops, delays, tuple(parts), tuple(kills), tuple(hangs))
