"""The bodies a robot's law is given: the obstacles near (indexed by cell), the lock-step list (robots of
this tick by id, then obstacles, then dead robots: the simulator's order), and the static part both
modes share.
"""

from __future__ import annotations

import logging

from swarm.proto import keys, protocol
from swarm.core import law
from agents.state import GAP_PERIODS, RT_BODIES_TTL_S, block
from agents.links import Links

log = logging.getLogger("swarm.robot")


class Bodies(Links):
    """The law's bodies: lock-step's list and the static part (obstacles, dead or listed robots)."""

    def set_obstacles(self, obstacles: list[protocol.Obstacle]) -> None:
        """Keep the obstacles, indexed by cell so a tick looks only at the 3x3 cells around it."""
        self.obstacles = [(o.x, o.y, o.r, o.R) for o in obstacles]
        self.p[law.P_OBSTACLE_R] = max((o.r for o in obstacles), default=0.0)  # the governor's bound (swarm.core.law)
        self._ocells = {}
        self._onear = {}
        for m, (x, y, _r, _R) in enumerate(self.obstacles):
            self._ocells.setdefault(keys.cell_of(x, y, self.side), []).append(m)

    def _obstacles_near(self, cell: tuple[int, int]) -> list[tuple[float, float, float, float]]:
        """The obstacles in the 3x3 cells around `cell`, by index (the simulator's order); kept per cell."""
        near = self._onear.get(cell)
        if near is None:
            idx = sorted(m for c in block(*cell) for m in self._ocells.get(c, ()))
            near = self._onear[cell] = [self.obstacles[m] for m in idx]
        return near

    def bodies(self, x: float, y: float, seq: int):
        """Lock-step: the known bodies closer than the cell side, in summation order: live robots by id, the
        obstacles by index, dead robots by id (static bodies). A live robot counts with its state of this tick,
        or, when it was awaited and did not come, its last one (stale). Returns lists nx, ny, nr, nR, nk, na
        (ages, all 0) and the numbers of robots and stale robots used. Real time: _rt_bodies."""
        r2 = self.side * self.side
        wire = protocol._wire
        if wire is not None:  # the loop below over the table, compiled (swarm/proto/_wire_states.c)
            nx, ny, nr, nR, nk, na, robots, stale, oldest, dead_near = wire.lock_bodies(
                self.table, self.dead, self.waiting, seq, x, y, r2, law.KIND_ROBOT)
            if dead_near or self.obstacles:
                self._static_bodies(x, y, r2, nx, ny, nr, nR, nk, na, dead_near)
            return nx, ny, nr, nR, nk, na, robots, stale
        nx, ny, nr, nR, nk, na = [], [], [], [], [], []
        robots = stale = 0
        table, dead, waiting = self.table, self.dead, self.waiting
        dead_near = []
        for j in sorted(table):
            nb = table[j]
            if j in dead:
                dead_near.append(nb)
                continue
            if nb.seq != seq and j not in waiting:
                continue
            dx = x - nb.x
            dy = y - nb.y
            if dx * dx + dy * dy < r2:
                nx.append(nb.x)
                ny.append(nb.y)
                nr.append(nb.r)
                nR.append(nb.R)
                nk.append(law.KIND_ROBOT)
                na.append(0.0)
                robots += 1
                stale += nb.seq != seq
        self._static_bodies(x, y, r2, nx, ny, nr, nR, nk, na, dead_near)
        return nx, ny, nr, nR, nk, na, robots, stale

    def _listed_now(self) -> dict:
        """Real time: the robots the world lists as standing still (id -> (x, y, r, R)); a list older than
        RT_BODIES_TTL_S is dropped (the world sends one every period while it lists a robot)."""
        if self.rt_static:
            now = self.sim_time(self.clock.time())
            if now is not None and now - self.rt_static_t > RT_BODIES_TTL_S:
                self.rt_static = {}
        return self.rt_static

    def _info_delay(self) -> float:
        """Real time: how old this robot's news may be [s]: a high but typical lag of its poses or age of its
        neighbours' states when they come (the 75th percentile of the recent ones: a robot that comes near is heard
        at its first state that gets through, not its latest), plus GAP_PERIODS periods of losses."""
        return max(self._lag.value, self._news.value) + GAP_PERIODS * self.cfg.dt

    def _cut_off(self, j: int, t: float, span: float) -> bool:
        """Real time under faults: a partition of the run separates this robot from robot j at some time in
        [t - span, t] (their states do not cross: not hearing j says nothing of where it is)."""
        for p in self.partitions:
            if p.start <= t and p.end >= t - span and p.group(self.id) != p.group(j):
                return True
        return False

    def _static_bodies(self, x: float, y: float, r2: float, nx: list, ny: list, nr: list, nR: list, nk: list,
                       na: list, dead_near: list) -> None:
        """bodies(), its static part: the obstacles near, by index, then the dead robots near, by id, then (real time)
        the robots the world lists as standing still, appended (ages 0)."""
        for ox, oy, orr, oR in self._obstacles_near(keys.cell_of(x, y, self.side)):
            dx = x - ox
            dy = y - oy
            if dx * dx + dy * dy < r2:
                nx.append(ox)
                ny.append(oy)
                nr.append(orr)
                nR.append(oR)
                nk.append(law.KIND_OBSTACLE)
                na.append(0.0)
        for nb in dead_near:
            dx = x - nb.x
            dy = y - nb.y
            if dx * dx + dy * dy < r2:
                nx.append(nb.x)
                ny.append(nb.y)
                nr.append(nb.r)
                nR.append(nb.R)
                nk.append(law.KIND_DEAD)
                na.append(0.0)
        if self.rt_static and not self.cfg.lockstep:
            for sx, sy, sr, sR in self._listed_now().values():
                dx = x - sx
                dy = y - sy
                if dx * dx + dy * dy < r2:
                    nx.append(sx)
                    ny.append(sy)
                    nr.append(sr)
                    nR.append(sR)
                    nk.append(law.KIND_DEAD)
                    na.append(0.0)
