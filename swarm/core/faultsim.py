"""The state the simulator keeps under faults, and the fault metrics (docs/faults.md, docs/metrics.md).

    state = FaultState(scn, dt)        # the arrays of swarm.core.faultkernel.run_fault_steps
    state.arguments()                   # its fault-specific arguments, in order
    state.metrics(t_end)                # messages_dropped, faults {...}, robots_alive_at_end

swarm.core.sim.Simulation holds one when its scenario has faults and calls the fault kernel with it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from swarm.core import faultgen as fg
from swarm.core import faults as fl
from swarm.core import law
from swarm.core.faulttable import FaultTable

if TYPE_CHECKING:
    from swarm.core.scenario import Scenario

WATCHDOG_S = 0.5  # the world's watchdog: no new command for longer than this stops a robot
BRAKE_S = law.BRAKE_S  # after the one-period hold, a robot without a new command brakes to a stop over this long
CLASSES = ("state", "pose", "cmd", "ref")  # faultgen.CLS_* order


def commands_may_miss(faults: fl.Faults) -> bool:
    """Whether a robot's command may not reach the world at some tick: a drop or delay rule of class
    cmd (or all), or a hang (a hung robot sends nothing)."""
    return bool(faults) and (any(r.cls in ("cmd", "all") for r in faults.drops + faults.delays)
                             or bool(faults.hangs))


def horizon(faults: fl.Faults, dt: float, brake_s: float = BRAKE_S) -> float:
    """The safety governor's horizon [s]: how long one command may act. dt without faults on commands;
    when a command may be missing, the world holds the last one a period and then brakes along a ramp,
    so the last command acts for dt times (1 + the hold + the ramp's steps): the governor keeps every
    body safe over that (docs/faults.md, Safe under faults)."""
    if not commands_may_miss(faults):
        return dt
    return law.hold_horizon(dt, brake_s)


class FaultState:
    def __init__(self, scn: Scenario, watchdog_s: float = WATCHDOG_S, fk: Any = None) -> None:
        if fk is None:  # the paper's law (a user's law comes with its own: swarm.core.userlaw.Law.kernels)
            from swarm.core import faultkernel as fk

        self.fk = fk
        f = cast(fl.Faults, scn.faults)  # a FaultState is made for a scenario with faults only
        n, m = scn.n, len(scn.obstacles)
        self.faults = f
        self.table = FaultTable.of(f, n, scn.dt)
        tab = self.table
        # a message later than the run is never delivered: the rings need not reach past its last tick (a delay
        # rule of 10^6 ticks made them robots x robots x 10^6 whatever the run: 11.7 GB at 37 robots)
        self.dmax = min(int(max([d.ticks + d.jitter for d in f.delays], default=0)), scn.steps + 1)
        h = self.dmax + 2
        rules = tab.drop.shape[0]

        def chains(*shape: int) -> np.ndarray:
            c = np.zeros((*shape, rules, fg.C_SIZE), np.int64)
            c[..., fg.C_K] = -1
            return c

        self.ch_state, self.ch_pose, self.ch_ref, self.ch_cmd = chains(n, n), chains(n), chains(n), chains(n)
        self.ring_state = np.full((n, n, h), fk.NONE, np.int64)
        self.ring_pose, self.ring_ref, self.ring_cmd = (np.full((n, 1, h), fk.NONE, np.int64) for _ in range(3))
        self.proc = np.zeros(n, np.int64)
        self.proch = np.zeros((h, n), np.int64)
        self.listen = np.zeros(n, np.int64)
        self.qh = np.zeros((h, n, 3))
        self.bel = np.zeros((n, 3))
        self.belh = np.zeros((h, n, 3))
        self.belv = np.zeros((h, n), np.bool_)
        self.kb = np.full(n, -1, np.int64)
        self.kp = np.full(n, -1, np.int64)
        self.pbase = np.zeros((n, 3))
        self.cmdh = np.zeros((h, n, 2))
        self.lastc = np.zeros((n, 2))
        self.kr = np.full(n, -1, np.int64)
        self.tk = np.full((n, n), -1, np.int64)
        self.tx = np.zeros((n, n))
        self.ty = np.zeros((n, n))
        self.wcmd = np.zeros((n, 2))
        self.wnew = np.zeros((n, 2))
        self.wsrc = np.full(n, -1, np.int64)
        self.wlast = np.full(n, -1, np.int64)
        self.stopped = np.zeros(n, np.bool_)
        end = scn.steps * scn.dt
        self.alive_end = np.array([fl.process_state(f, i, end) == "alive" for i in range(n)], np.bool_)
        self.facc = np.zeros(fk.F_SIZE, np.int64)
        self.fmax = np.zeros(1)
        self.inside = np.zeros((n + m, n + m), np.bool_)
        self.watchdog_ticks = float(watchdog_s / scn.dt)

    def arguments(self) -> tuple[Any, ...]:
        """The fault kernel's arguments after the shared ones (q ... p), up to the accumulators."""
        t = self.table
        return (self.watchdog_ticks, np.int64(t.seed), t.drop, t.drop_from, t.drop_to, t.delay, t.delay_from,
                t.delay_to, t.part_win, t.part_group, t.event_ticks, self.dmax,
                self.ch_state, self.ch_pose, self.ch_ref, self.ch_cmd,
                self.ring_state, self.ring_pose, self.ring_ref, self.ring_cmd,
                self.proc, self.proch, self.listen, self.qh, self.bel, self.belh, self.belv, self.kb, self.kp,
                self.pbase, self.cmdh, self.lastc, self.kr, self.tk, self.tx, self.ty, self.wcmd, self.wnew,
                self.wsrc, self.wlast, self.stopped, self.alive_end, BRAKE_S)

    def metrics(self, t_end: float) -> dict[str, Any]:
        """The fault keys of the metrics contract; t_end [s]: the time of the run's last step."""
        fk, a = self.fk, self.facc
        dropped = {c: int(a[fk.F_DROPPED + i]) for i, c in enumerate(CLASSES)}
        return {
            "messages_dropped": sum(dropped.values()),
            "robots_alive_at_end": int(np.count_nonzero(self.proc != fg.PROC_DEAD)),
            "faults": {
                "dropped": dropped,
                "delayed": {c: int(a[fk.F_DELAYED + i]) for i, c in enumerate(CLASSES)},
                "killed": int(a[fk.F_KILLED]),
                "restarted": int(a[fk.F_RESTARTED]),
                "hung": int(a[fk.F_HUNG]),
                "partitions": fl.partitions_begun(self.faults, t_end),
                "cmd_held": int(a[fk.F_CMD_HELD]),
                "watchdog_stops": int(a[fk.F_WATCHDOG]),
                "max_state_age_s": round(float(self.fmax[0]), 9),
            },
        }



def arrival(ring: dict[int, int], k: int, dmax: int, newest: int) -> int:
    """Lock-step under faults: the send tick of the newest message of `ring` (send tick -> its delay in
    ticks, -1 lost) that arrives at tick k, newer than `newest`; -1: none (agents.faultview, world.faultworld)."""
    for d in range(dmax + 1):
        s = k - d
        if s < 0 or s <= newest:
            break
        if ring.get(s) == d:
            return s
    return -1


class TickSchedule:
    """The process faults in ticks, as the fault kernel applies them: robot i's process state at tick k
    (faultgen.PROC_*), and whether a restart or a resume happens exactly at k (a listening tick).
    Every lock-step process reads it, so membership follows the schedule."""

    def __init__(self, table: FaultTable, robots: int) -> None:
        self.events: dict[int, list[tuple[int, int]]] = {i: [] for i in range(robots)}  # robot -> [(tick, kind)]
        for tick, robot, kind in table.event_ticks.tolist():
            self.events[robot].append((tick, kind))

    def state(self, robot: int, k: int) -> int:
        s = fg.PROC_ALIVE
        for tick, kind in self.events[robot]:
            if tick > k:
                break
            s = (fg.PROC_DEAD, fg.PROC_ALIVE, fg.PROC_HUNG, fg.PROC_ALIVE)[kind]
        return s

    def active(self, robot: int, k: int) -> bool:
        return self.state(robot, k) == fg.PROC_ALIVE

    def fresh(self, robot: int, k: int) -> str | None:
        """"restart" or "resume" when that event of robot happens at tick k (it listens), else None."""
        out = None
        for tick, kind in self.events[robot]:
            if tick == k and kind in (1, 3):
                out = fl.KINDS[kind]
        return out

    def next_return(self, robot: int, k: int) -> int | None:
        """The tick of robot's next restart or resume after tick k (None: none)."""
        for tick, kind in self.events[robot]:
            if tick > k and kind in (1, 3):
                return tick
        return None
