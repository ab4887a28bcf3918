"""The referee: the metrics of docs/metrics.md from ground truth, one sample at a time.

The world calls sample() at every control step (every tick in lock-step) with the true poses,
which robots are alive and the live leader reference. The definitions are those of the
in-process simulator (swarm.core.kernel), so a lock-step run and `swarm sim` report the same
numbers: errors against the live reference, a robot is frozen while it is inside R_j of another
(live) robot, a collision is a pair going from >= r to < r between consecutive samples.
"""

from __future__ import annotations

import logging
import math
import os
from types import ModuleType

import numpy as np

from swarm.core import law, metrics
from swarm.core.metrics import CONVERGED_ANGLE_RAD, CONVERGED_POSITION_M, step_time
from swarm.core.scenario import Scenario

_referee: ModuleType | None
try:  # pair_scan below, compiled (setup.py, where a C compiler is found)
    from world import _referee
except ImportError:
    _referee = None
if os.environ.get("SWARM_PURE_PYTHON"):
    _referee = None

FREEZE_MERGE_S = 0.1
COLLISIONS_LOGGED = 20  # a run logs its first collisions one by one, then says that it stops
_BLOCK = 256  # rows of the pairwise distance matrix computed at once


def pair_scan(q: np.ndarray, r: np.ndarray, R: np.ndarray, live: np.ndarray, obstacles: np.ndarray,
              freezes: bool) -> tuple[float, float, list[tuple[int, int]], bytes]:
    """Every pair of a sample at once: (the smallest centre distance of two robots, the smallest centre distance of a
    robot to an obstacle's centre (inf where there is none), the pairs (i, j) of robots closer than max(r_i, r_j)
    with i < j and (i, n + m) of a robot inside obstacle m, which robots are frozen: n bytes). q: n x 3 poses;
    obstacles: m x 4. A distance that is not a number (from a pose that is not: the world ends such a run first)
    counts for nothing. Compiled in world/_referee.c (the same floats: tests/unit/test_referee_compiled.py)."""
    n = len(r)
    x, y = q[:, 0], q[:, 1]
    inside: list[tuple[int, int]] = []
    frozen = np.zeros(n, bool)
    min_rr = min_ro = math.inf
    for a in range(0, n, _BLOCK):
        b = min(n, a + _BLOCK)
        dx = x[a:b, None] - x[None, :]
        dy = y[a:b, None] - y[None, :]
        d = np.sqrt(dx * dx + dy * dy)
        rows = np.arange(a, b)
        d[rows - a, rows] = np.inf
        upper = np.where(np.arange(n)[None, :] > rows[:, None], d, np.inf)
        if n >= 2:  # fmin: a distance that is not a number (a pose that is not) is passed over, not the block
            min_rr = min(min_rr, float(np.fmin.reduce(upper, axis=None)))
        rmax = np.where(r[a:b, None] > r[None, :], r[a:b, None], r[None, :])
        inside += [(int(a + i), int(j)) for i, j in zip(*np.nonzero(upper < rmax))]
        # frozen: inside R_j of another live robot j (the law's freeze rule)
        near = (dx * dx + dy * dy < (R * R)[None, :]) & live[None, :]
        near[rows - a, rows] = False
        frozen[a:b] = near.any(axis=1) & live[a:b] & freezes
    if len(obstacles) and n:
        ox, oy, orr = obstacles[:, 0], obstacles[:, 1], obstacles[:, 2]
        for a in range(0, n, _BLOCK):
            b = min(n, a + _BLOCK)
            d = np.sqrt((x[a:b, None] - ox[None, :]) ** 2 + (y[a:b, None] - oy[None, :]) ** 2)
            min_ro = min(min_ro, float(np.fmin.reduce(d, axis=None)))
            inside += [(int(a + i), n + int(m)) for i, m in zip(*np.nonzero(d < orr[None, :]))]
    return min_rr, min_ro, inside, frozen.tobytes()


class Referee:
    def __init__(self, scn: Scenario):
        self.scn = scn
        self.n = scn.n
        self.offsets = np.asarray(scn.offsets, float)
        self.r = np.full(self.n, float(scn.r))
        self.R = np.full(self.n, float(scn.R))
        self.obstacles = np.asarray(scn.obstacles, float).reshape(-1, 4)
        self.samples = 0
        self.last_t: float | None = None
        self.last_xy = np.zeros((0, 2))  # the live robots' positions at the last sample
        self.good_since: float | None = None  # first sample of the current run with every live robot converged
        self.last_frozen_t: float | None = None
        self.freeze_intervals = 0
        self._frozen_until = np.full(self.n, -math.inf)  # last sample time each robot was frozen
        self.min_rr = math.inf
        self.min_ro = math.inf
        self.collisions = 0
        self._inside: set[tuple[int, int]] = set()
        self.new_collisions: list[tuple[int, int, float]] = []  # the last sample's: (i, j or n + obstacle, distance)
        self.pmax = 0.0
        self.emax = 0.0
        self.converged_now = 0
        self.frozen_now = 0
        self.alive_now = 0
        self.frozen = np.zeros(self.n, bool)
        self.strands = metrics.Strands(self.n)  # robots stranded far from their slots (docs/metrics.md)

    def sample(self, t: float, q: np.ndarray, alive: np.ndarray, leader: tuple[float, float, float],
               frozen_by_law: np.ndarray | list[bool] | None = None) -> None:
        """Account for the state at time t: q (N, 3) true poses, alive (N,) bool, leader (x, y, theta);
        frozen_by_law (N,) bool: which robots their laws froze (under faults, where a law's view is not the
        truth; None: frozen is inside R_j of another live robot, which is what the law sees otherwise)."""
        xl, yl, thl = leader
        x, y, th = q[:, 0], q[:, 1], q[:, 2]
        px = xl + self.offsets[:, 0] - x
        py = yl + self.offsets[:, 1] - y
        pe = np.sqrt(px * px + py * py)
        ee = np.array([abs(law.wrap_angle(thl - a)) for a in th.tolist()])
        live = alive.astype(bool)
        ok = (pe < CONVERGED_POSITION_M) & (ee < CONVERGED_ANGLE_RAD)
        self.converged_now = int(np.count_nonzero(ok & live))
        self.alive_now = int(np.count_nonzero(live))
        if self.converged_now < self.alive_now or self.alive_now == 0:  # no live robot is never "converged"
            self.good_since = None
        elif self.good_since is None:
            self.good_since = t
        self.strands.sample(t, pe, live, self.converged_now)
        self.pmax = float(pe[live].max()) if self.alive_now else 0.0
        self.emax = float(ee[live].max()) if self.alive_now else 0.0
        self.last_t = t
        self.last_xy = q[live, :2].copy()
        self.samples += 1
        freezes = self.scn.control.law is None  # a user's law never freezes (docs/control.md)
        scan = _referee.pair_scan if _referee is not None else pair_scan
        min_rr, min_ro, pairs, frozen_bytes = scan(np.ascontiguousarray(q, float), self.r, self.R, live, self.obstacles,
                                                   freezes)
        inside = set(pairs)
        frozen = np.frombuffer(frozen_bytes, bool).copy()
        if self.n >= 2:
            self.min_rr = min(self.min_rr, min_rr)
        if len(self.obstacles) and self.n:
            self.min_ro = min(self.min_ro, min_ro)
        new = sorted(inside - self._inside)
        self.collisions += len(new)
        self.new_collisions = [(i, j, self._distance(x, y, i, j)) for i, j in new]
        self._inside = inside
        if frozen_by_law is not None:
            frozen = np.asarray(frozen_by_law, bool)
        self.frozen = frozen
        self.frozen_now = int(np.count_nonzero(frozen))
        if self.frozen_now:
            self.last_frozen_t = t
            starts = frozen & (t - self._frozen_until > FREEZE_MERGE_S + 0.5 * self.scn.dt)
            self.freeze_intervals += int(np.count_nonzero(starts))
            self._frozen_until[frozen] = t

    @property
    def stranded_now(self) -> int:
        return self.strands.now

    def _distance(self, x: np.ndarray, y: np.ndarray, i: int, j: int) -> float:
        """Centre distance of robot i to robot j, or to obstacle j - n's boundary (negative inside)."""
        if j < self.n:
            return math.hypot(float(x[i] - x[j]), float(y[i] - y[j]))
        ox, oy, orr = self.obstacles[j - self.n, :3]
        return math.hypot(float(x[i] - ox), float(y[i] - oy)) - float(orr)

    def describe(self, t: float) -> list[str]:
        """One line per collision that began at the last sample (t), for a log: who, when, how close."""
        return [f"collision at t = {t:.3f} s: robots {i} and {j} are {d:.3f} m apart "
                f"(r = {max(self.r[i], self.r[j]):g} m)" if j < self.n else
                f"collision at t = {t:.3f} s: robot {i} is inside obstacle {j - self.n} ({-d:.3f} m past its edge)"
                for i, j, d in self.new_collisions]

    def converged_at(self) -> float | None:
        """The first sample time from which every later sample had every live robot converged."""
        return None if self.good_since is None else step_time(self.good_since)

    def metrics(self, wall_s: float, interrupted: bool, mode: str, **extra) -> dict:
        return metrics.record(
            self.scn, duration_s=self.last_t or 0.0, converged_at_s=self.converged_at(),
            position_error_max=self.pmax if self.samples and self.alive_now else None,
            orientation_error_max=self.emax if self.samples and self.alive_now else None, min_robot_distance=self.min_rr, min_obstacle_distance=self.min_ro,
            collisions=self.collisions, last_freeze_end_s=self.last_frozen_t, wall_s=wall_s,
            interrupted=interrupted, mode=mode, freeze_intervals=self.freeze_intervals, samples=self.samples,
            **self.strands.keys(), final_spread_m=metrics.spread(self.last_xy), **extra)


def log_collisions(ref: Referee, t: float, log: logging.Logger = logging.getLogger("swarm.world")) -> None:
    """Log the collisions that began at the last sample, up to the first COLLISIONS_LOGGED of the run, so a
    run that collided says who and when, not only how many (the count in the metrics is always whole)."""
    first = ref.collisions - len(ref.new_collisions)  # collisions before this sample
    for n, line in enumerate(ref.describe(t), start=first + 1):
        if n > COLLISIONS_LOGGED:
            if first <= COLLISIONS_LOGGED:
                log.warning("more than %d collisions: the rest are counted in the metrics, not logged",
                            COLLISIONS_LOGGED)
            return
        log.warning("%s", line)
