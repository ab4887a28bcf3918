"""Faults as numbers: the numeric table of a run's fault schedule (swarm.core.faults), the arrays swarm.core.faultgen
decides on, compiled in the simulator and plain in the processes, and one link's view of them.

    table = FaultTable.of(faults, robots, dt)        # ids as columns: the LEADER, the WORLD, then robot i
    table.link("state", sender=3, receiver=5).decide(k, t)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from swarm.core import faultgen as fg
from swarm.core.faults import CLASSES, KINDS, DelayRule, DropRule, Faults, events


def first_tick(t: float, dt: float) -> int:
    """The first tick k >= 0 whose time k dt is at or after t [s] (within faultgen.TIME_EPS)."""
    k = max(0, math.ceil((t - fg.TIME_EPS) / dt))
    while k > 0 and (k - 1) * dt >= t - fg.TIME_EPS:
        k -= 1
    while k * dt < t - fg.TIME_EPS:
        k += 1
    return k


@dataclass(frozen=True, eq=False)
class FaultTable:
    """Faults as numpy arrays for swarm.core.faultgen (compiled in the simulator, plain in processes).

    Ids are columns through faultgen.ID_OFFSET: column 0 the LEADER, 1 the WORLD, 2 + i robot i.
    Window bounds are stored lowered by faultgen.TIME_EPS (so a test is `lo <= t < hi`; inf: open).

    drop        (D, D_SIZE) float64, row r = drop rule r: D_CLS class code (faultgen.CLS_*), D_P, D_BURST,
                D_START, D_END [s], D_STAY and D_ENTER (the burst chain's transitions, 0 when burst == 1)
    drop_from   (D, N + 2) bool, drop_from[r, id + ID_OFFSET]: rule r matches sender id (all True: any
                sender; a `from` list: its robots only, never the world or the leader); drop_to likewise
    delay       (Y, Y_SIZE) float64: Y_CLS, Y_TICKS, Y_JITTER, Y_START, Y_END; delay_from, delay_to as above
    part_win    (P, 2) float64: W_START, W_END of each partition (windows do not overlap)
    part_group  (P, N) int64: part_group[w, i] the group of robot i in partition w (0: the world's)
    proc        (F, F_SIZE) float64, one row per kill or hang: F_ROBOT, F_KIND (PROC_DEAD / PROC_HUNG),
                F_START, F_END (inf: a kill without restart)
    event_ticks (E, 3) int64: the process events of events(faults) as (tick, robot, kind index in
                KINDS), the tick being first_tick(t, dt): the lock-step tick at which each happens
    """

    seed: int
    robots: int
    dt: float
    drop: np.ndarray = field(repr=False)
    drop_from: np.ndarray = field(repr=False)
    drop_to: np.ndarray = field(repr=False)
    delay: np.ndarray = field(repr=False)
    delay_from: np.ndarray = field(repr=False)
    delay_to: np.ndarray = field(repr=False)
    part_win: np.ndarray = field(repr=False)
    part_group: np.ndarray = field(repr=False)
    proc: np.ndarray = field(repr=False)
    event_ticks: np.ndarray = field(repr=False)

    @classmethod
    def of(cls, faults: Faults, robots: int, dt: float) -> FaultTable:
        """The table of `faults` for a scenario of `robots` robots and control period dt [s]."""
        if isinstance(robots, bool) or not isinstance(robots, (int, np.integer)) or robots < 1:
            raise ValueError(f"robots must be an integer >= 1, got {robots!r}")
        robots = int(robots)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
        cols = robots + fg.ID_OFFSET

        def mask(ids: tuple[int, ...] | None, what: str) -> np.ndarray:
            m = np.zeros(cols, bool)
            if ids is None:
                m[:] = True
                return m
            bad = [i for i in ids if i >= robots]
            if bad:
                raise ValueError(f"{what} names robot {bad[0]}, not in a scenario of {robots} robots")
            m[np.asarray(ids) + fg.ID_OFFSET] = True
            return m

        def low(t: float) -> float:
            return t - fg.TIME_EPS

        D, Y = len(faults.drops), len(faults.delays)
        drop = np.zeros((D, fg.D_SIZE))
        drop_from, drop_to = np.zeros((D, cols), bool), np.zeros((D, cols), bool)
        d: DropRule | DelayRule
        for r, d in enumerate(faults.drops):
            drop[r, fg.D_CLS], drop[r, fg.D_P], drop[r, fg.D_BURST] = CLASSES[d.cls], d.p, d.burst
            drop[r, fg.D_START], drop[r, fg.D_END] = low(d.start), low(d.end)
            if d.burst > 1.0 and 0.0 < d.p < 1.0:
                drop[r, fg.D_STAY], drop[r, fg.D_ENTER] = fg.burst_params(d.p, d.burst)
            drop_from[r], drop_to[r] = mask(d.senders, f"drop[{r}].from"), mask(d.receivers, f"drop[{r}].to")
        delay = np.zeros((Y, fg.Y_SIZE))
        delay_from, delay_to = np.zeros((Y, cols), bool), np.zeros((Y, cols), bool)
        for r, d in enumerate(faults.delays):
            delay[r, fg.Y_CLS], delay[r, fg.Y_TICKS], delay[r, fg.Y_JITTER] = CLASSES[d.cls], d.ticks, d.jitter
            delay[r, fg.Y_START], delay[r, fg.Y_END] = low(d.start), low(d.end)
            delay_from[r], delay_to[r] = mask(d.senders, f"delay[{r}].from"), mask(d.receivers, f"delay[{r}].to")
        P = len(faults.partitions)
        part_win = np.zeros((P, 2))
        part_group = np.zeros((P, robots), np.int64)
        for w, part in enumerate(faults.partitions):
            part_win[w] = low(part.start), low(part.end)
            part_group[w, :] = len(part.groups)
            for g, group in enumerate(part.groups):
                bad = [i for i in group if i >= robots]
                if bad:
                    raise ValueError(f"partition[{w}] names robot {bad[0]}, not in a scenario of {robots} robots")
                part_group[w, list(group)] = g
        rows = [(k.robot, fg.PROC_DEAD, k.at, k.end) for k in faults.kills] + \
            [(h.robot, fg.PROC_HUNG, h.at, h.end) for h in faults.hangs]
        for robot, *_ in rows:
            if robot >= robots:
                raise ValueError(f"a process fault names robot {robot}, not in a scenario of {robots} robots")
        proc = np.array([(r, kind, low(a), low(b)) for r, kind, a, b in rows], float).reshape(-1, fg.F_SIZE)
        ev = np.array([(first_tick(t, dt), robot, KINDS.index(kind)) for t, robot, kind in events(faults)],
                      np.int64).reshape(-1, 3)
        return cls(faults.seed, robots, float(dt), drop, drop_from, drop_to, delay, delay_from, delay_to,
                   part_win, part_group, proc, ev)

    def arrays(self) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                              np.ndarray]:
        """(seed, drop, drop_from, drop_to, delay, delay_from, delay_to, part_win, part_group): the leading
        arguments of faultgen.decide, in order."""
        return (self.seed, self.drop, self.drop_from, self.drop_to, self.delay, self.delay_from, self.delay_to,
                self.part_win, self.part_group)

    def new_chains(self) -> np.ndarray:
        """An empty burst chain cache for one link and class: (D, C_SIZE) int64 rows (-1, 0)."""
        chains = np.zeros((self.drop.shape[0], fg.C_SIZE), np.int64)
        chains[:, fg.C_K] = -1
        return chains

    def decide(self, cls: int, sender: int, receiver: int, k: int, t: float, chains: np.ndarray) -> tuple[bool, int]:
        """faultgen.decide (plain Python) for message k of class cls (faultgen.CLS_*) on (sender, receiver),
        sent at t [s]: (lost, delay in ticks)."""
        lost, late = fg.decide(*self.arrays(), cls, sender, receiver, k, t, chains)
        return bool(lost), int(late)

    def link(self, cls: int, sender: int, receiver: int) -> Link:
        """The decisions of one link and class, prepared once (what a process keeps per link)."""
        return Link(self, cls, sender, receiver)


class Link:
    """faultgen.decide for one (class, sender, receiver), prepared for plain Python: the rules that can
    match the link, their stream keys and a burst chain cache are worked out once, so a message costs a
    few microseconds (decide over the whole table: ~40 us with four rules). Same answers as decide
    (tests/unit/test_faults_decisions.py); keep one Link per link and class in a process."""

    def __init__(self, table: FaultTable, cls: int, sender: int, receiver: int):
        if cls not in range(fg.N_CLASSES):
            raise ValueError(f"cls must be a message class 0..{fg.N_CLASSES - 1} (faultgen.CLS_*), got {cls!r}")
        for name, i in (("sender", sender), ("receiver", receiver)):
            if not -fg.ID_OFFSET <= i < table.robots:
                raise ValueError(f"{name} must be a robot id 0..{table.robots - 1}, WORLD or LEADER, got {i!r}")
        self.cls, self.sender, self.receiver = cls, sender, receiver
        cs, cr = sender + fg.ID_OFFSET, receiver + fg.ID_OFFSET

        def matches(row: np.ndarray, senders: np.ndarray, receivers: np.ndarray, col: int) -> bool:
            return int(row[col]) in (cls, fg.CLS_ALL) and bool(senders[cs]) and bool(receivers[cr])

        # drop rules: (row in the chain cache, key, p, burst, stay, enter, lo, hi); p = 0 rules never lose
        self.drops: list[tuple[int, int, float, float, float, float, float, float]] = []
        for r in range(table.drop.shape[0]):
            d = table.drop[r]
            if matches(d, table.drop_from[r], table.drop_to[r], fg.D_CLS) and d[fg.D_P] > 0.0:
                self.drops.append((len(self.drops), fg.stream(table.seed, r, cls, sender, receiver), float(d[fg.D_P]),
                                   float(d[fg.D_BURST]), float(d[fg.D_STAY]), float(d[fg.D_ENTER]),
                                   float(d[fg.D_START]), float(d[fg.D_END])))
        self.delays: list[tuple[int, int, int, float, float]] = []
        for r in range(table.delay.shape[0]):
            d = table.delay[r]
            if matches(d, table.delay_from[r], table.delay_to[r], fg.Y_CLS):
                self.delays.append((fg.stream(table.seed, fg.DELAY_RULE + r, cls, sender, receiver),
                                    int(d[fg.Y_TICKS]), int(d[fg.Y_JITTER]), float(d[fg.Y_START]), float(d[fg.Y_END])))
        # partition windows: (lo, hi, whether the link is cut during it)
        self.windows = [(float(lo), float(hi), bool(fg.is_cut(table.part_win[w:w + 1], table.part_group[w:w + 1],
                                                                  sender, receiver, float(lo))))
                        for w, (lo, hi) in enumerate(table.part_win)]
        self.chains = np.zeros((len(self.drops), fg.C_SIZE), np.int64)
        self.chains[:, fg.C_K] = -1

    def decide(self, k: int, t: float) -> tuple[bool, int]:
        """(lost, delay in ticks) of message k sent at t [s]: faultgen.decide for this link."""
        for lo, hi, separated in self.windows:
            if lo <= t < hi:
                if separated:
                    return True, 0
                break
        for row, key, p, burst, stay, enter, lo, hi in self.drops:
            if lo <= t < hi and fg.lost_at(key, k, p, burst, stay, enter, self.chains, row):
                return True, 0
        late = 0
        for key, ticks, jitter, lo, hi in self.delays:
            if lo <= t < hi:
                late = max(late, fg.jittered(key, k, ticks, jitter))
        return False, late
