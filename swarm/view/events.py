"""The events of a recording (/events, docs/recording.md): collisions, freezes and their ends, derived from a sequence of
snapshots and freeze flags the way the metrics count them. Pure: no I/O, no clock."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.core.geometry import DENSE_N, pairs_within
from swarm.core.scenario import Scenario


@dataclass(frozen=True)
class Event:
    """One entry of /events; robot/other are robot ids, obstacle an obstacle index."""

    t: float
    kind: str
    robot: int | None = None
    other: int | None = None
    obstacle: int | None = None
    distance: float | None = None
    detail: str = ""

    def to_dict(self) -> dict:
        """The /events message: robot, other, obstacle and distance only when they apply (not null)."""
        d: dict = {"t": self.t, "kind": self.kind}
        for name in ("robot", "other", "obstacle", "distance"):
            value = getattr(self, name)
            if value is not None:
                d[name] = value
        d["detail"] = self.detail
        return d


class EventDeriver:
    """Derives events from a sequence of snapshots and freeze flags (pure: no I/O, no clock).

    Collisions follow the metrics contract (docs/design.md): an unordered pair whose centre distance goes from >= r to
    < r between consecutive snapshots (r: the larger of two robots' r, the obstacle's r for a
    robot-obstacle pair); a pair already inside at the first snapshot counts once. A robot whose
    pose is not finite (missing from a snapshot) is in no pair.
    """

    def __init__(self, scn: Scenario):
        self.n = scn.n
        self.r = float(scn.r)
        self.obstacles = np.asarray(scn.obstacles, float).reshape(-1, 4)
        self._upper = np.triu_indices(self.n, 1) if 2 <= self.n <= DENSE_N else None
        self._inside: set[tuple[int, int]] = set()  # (i, j) robots, (i, n + m) robot i and obstacle m
        self._alive: np.ndarray | None = None
        self._stopped: np.ndarray | None = None
        self._was_stopped = np.zeros(self.n, bool)  # a robot_stopped event is open
        self._frozen: dict[int, bool] = {}
        self._seq: int | None = None

    def _contacts(self, x: np.ndarray, y: np.ndarray) -> dict[tuple[int, int], float]:
        """Pairs closer than their r now: {(i, j): distance} with j >= n meaning obstacle j - n."""
        ok = None
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            ok = np.isfinite(x) & np.isfinite(y)
            x, y = np.where(ok, x, 0.0), np.where(ok, y, 0.0)
        i, j, d = pairs_within(x, y, self.r, self._upper)
        if ok is not None and i.size:
            keep = ok[i] & ok[j]
            i, j, d = i[keep], j[keep], d[keep]
        out = dict(zip(zip(i.tolist(), j.tolist()), d.tolist())) if i.size else {}
        if len(self.obstacles) and self.n:
            ox, oy, orr = self.obstacles[:, 0], self.obstacles[:, 1], self.obstacles[:, 2]
            for a0 in range(0, self.n, 256):
                dx = x[a0:a0 + 256, None] - ox[None, :]
                dy = y[a0:a0 + 256, None] - oy[None, :]
                d2 = dx * dx + dy * dy
                a, m = np.nonzero(d2 < (orr * orr)[None, :])
                if a.size:
                    if ok is not None:
                        keep = ok[a0 + a]
                        a, m = a[keep], m[keep]
                    for aa, mm, dd in zip(a.tolist(), m.tolist(), np.sqrt(d2[a, m]).tolist()):
                        out[(a0 + aa, self.n + mm)] = dd
        return out

    def snapshot(self, t: float, seq: int | None, x: np.ndarray, y: np.ndarray, alive: np.ndarray,
                 stopped: np.ndarray) -> list[Event]:
        """Events of one snapshot: x, y (N,) [m], alive, stopped (N,) bool, rows indexed by robot id.
        seq: the snapshot's tick (a gap means snapshots were lost), None for samples of a run."""
        out: list[Event] = []
        if seq is not None:
            if self._seq is not None and seq > self._seq + 1:
                out.append(Event(t, "snapshots_missed", detail=f"{seq - self._seq - 1} snapshot(s) missing before "
                                                               f"seq {seq}; collisions between them may be missed"))
            self._seq = seq if self._seq is None else max(self._seq, seq)
        now = self._contacts(x, y)
        if now:
            for a, b in sorted(now.keys() - self._inside):
                d = now[(a, b)]
                if b < self.n:
                    out.append(Event(t, "collision", robot=a, other=b, distance=d,
                                     detail=f"robots {a} and {b} at {d:.4g} m < r = {self.r:g} m"))
                else:
                    m = b - self.n
                    out.append(Event(t, "collision", robot=a, obstacle=m, distance=d,
                                     detail=f"robot {a} and obstacle {m} at {d:.4g} m < r = "
                                            f"{self.obstacles[m, 2]:g} m"))
        self._inside = set(now)
        alive = np.asarray(alive, bool)
        stopped = np.asarray(stopped, bool)
        if self._alive is None:
            if not alive.all():
                for a in np.flatnonzero(~alive).tolist():
                    out.append(Event(t, "robot_dead", robot=a, detail=f"robot {a} is not alive at the first snapshot"))
        elif not np.array_equal(alive, self._alive):
            for a in np.flatnonzero(self._alive & ~alive).tolist():
                out.append(Event(t, "robot_dead", robot=a, detail=f"robot {a} is no longer alive"))
            for a in np.flatnonzero(~self._alive & alive).tolist():
                out.append(Event(t, "robot_alive", robot=a, detail=f"robot {a} is alive again"))
        if self._stopped is not None and not np.array_equal(stopped, self._stopped):
            for a in np.flatnonzero(~self._stopped & stopped).tolist():
                self._was_stopped[a] = True
                out.append(Event(t, "robot_stopped", robot=a,
                                 detail=f"the world stopped robot {a} (no fresh command: watchdog)"))
            for a in np.flatnonzero(self._stopped & ~stopped & self._was_stopped).tolist():
                self._was_stopped[a] = False
                out.append(Event(t, "robot_resumed", robot=a, detail=f"robot {a} moves again"))
        self._alive, self._stopped = alive.copy(), stopped.copy()
        return out

    def frozen(self, t: float, robot: int, flag: bool) -> Event | None:
        """A freeze_start / freeze_end event if robot's freeze flag changed (the first flag counts from False)."""
        flag = bool(flag)
        if self._frozen.get(robot, False) == flag:
            self._frozen[robot] = flag
            return None
        self._frozen[robot] = flag
        return Event(t, "freeze_start" if flag else "freeze_end", robot=robot,
                     detail=f"robot {robot} {'enters' if flag else 'leaves'} another robot's avoidance region")
