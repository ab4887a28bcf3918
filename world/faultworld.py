"""The world's side of lock-step faults: membership, commands and static bodies by the shared schedule.

    wf = WorldFaults(scn, watchdog_s)          # scn.faults is not None
    wf.running(i, k)                           # robot i's process runs at tick k (poses go to it, its command is awaited)
    wf.returning(i, k)                         # "restart" / "resume" when robot i returns at k, else None
    bodies = wf.bodies(k, q)                   # the Bodies message of tick k (static bodies, returning robots)
    cmds = wf.apply(k, raw)                    # the command each robot moves with over tick k
    wf.take_stats(i, msg)                      # a robot's own fault counters (a FaultStats message)
    wf.metrics(alive, t_end)                   # the fault keys of the metrics contract

Mirrors step 6 of swarm.core.faultkernel (the simulator's fault loop) with the same decisions
(swarm.core.faulttable.Link): robot i's command of tick s arrives at s + delay unless lost; the newest
is applied; without a new one the last is held one period, then braked along a ramp of BRAKE_S; a
robot with no new command for longer than the watchdog is stopped (a static body); a dead robot
stops at once. The world counts the commands it lost or delayed; each robot's fault layer
(agents.faultview) counts what it lost of its poses, references and neighbours' states and sends it
(the faultstats message), and the world adds them up, so the totals equal the simulator's.
"""

from __future__ import annotations

from swarm.core import faultgen as fg
from swarm.core import faults as fl
from swarm.core.faultsim import BRAKE_S, CLASSES, TickSchedule, arrival
from swarm.proto.protocol import Bodies, Body
from swarm.core.faulttable import FaultTable

NONE = -2
LOST = -1


def brake_factor(since: int, dt: float, brake_s: float = BRAKE_S) -> float:
    """swarm.core.faultkernel.brake_factor: 1 for the tick a command came and the one after, then a ramp to 0."""
    if since <= 1:
        return 1.0
    return max(0.0, 1.0 - (since - 1) * dt / brake_s)


class WorldFaults:
    def __init__(self, scn, watchdog_s: float) -> None:
        f = scn.faults
        n, dt = scn.n, scn.dt
        self.n, self.dt, self.faults = n, dt, f
        self.table = FaultTable.of(f, n, dt)
        self.schedule = TickSchedule(self.table, n)
        self.dmax = int(max([d.ticks + d.jitter for d in f.delays], default=0))
        self.h = self.dmax + 2
        self.links = [self.table.link(fg.CLS_CMD, i, fg.WORLD) for i in range(n)]
        self.ring: list[dict[int, int]] = [{} for _ in range(n)]  # send tick -> delay, LOST
        self.cmdh: list[dict[int, tuple[float, float]]] = [{} for _ in range(n)]  # send tick -> (v, w)
        self.wnew = [(0.0, 0.0)] * n
        self.wsrc = [-1] * n
        self.wlast = [-1] * n
        self.stopped = [False] * n
        self.watchdog_ticks = float(watchdog_s / dt)
        end = scn.steps * dt
        self.alive_end = [fl.process_state(f, i, end) == "alive" for i in range(n)]
        self.r, self.R = float(scn.r), float(scn.R)
        self.dropped = [0, 0, 0, 0]  # commands only here (faultgen.CLS_CMD); the rest from the robots
        self.delayed = [0, 0, 0, 0]
        self.killed = self.restarted = self.hung = self.cmd_held = self.watchdog_stops = 0
        # each robot's own counters: the newest report of its current process, and the sum of its earlier ones
        self.stats_now: list[tuple | None] = [None] * n
        self.stats_before = [[0] * 7 for _ in range(n)]  # dropped state, pose, ref; delayed state, pose, ref; 0
        self.max_age = 0.0
        self.born = [0] * n  # the tick each robot's current process began
        self.law_frozen = [False] * n  # each robot's law froze it at its newest report (a hung one's stays)

    # ------------------------------------------------------------------ the schedule

    def running(self, i: int, k: int) -> bool:
        return self.schedule.active(i, k)

    def dead(self, i: int, k: int) -> bool:
        return self.schedule.state(i, k) == fg.PROC_DEAD

    def returning(self, i: int, k: int) -> str | None:
        return self.schedule.fresh(i, k)

    def begin(self, k: int) -> list[tuple[int, str]]:
        """Tick k begins: the process events at k, [(robot, kind)], counted."""
        out = []
        for tick, robot, kind in self.table.event_ticks.tolist():
            if tick == k:
                name = fl.KINDS[kind]
                out.append((robot, name))
                if name == "kill":
                    self.killed += 1
                elif name == "restart":
                    self.restarted += 1
                    self._retire(robot)
                    self.born[robot] = k
                    self.law_frozen[robot] = False  # a fresh controller
                elif name == "hang":
                    self.hung += 1
        return out

    def _retire(self, i: int) -> None:
        """Robot i's process was replaced: its last report counts, the new process counts from 0."""
        last = self.stats_now[i]
        if last is not None:
            self.stats_before[i] = [a + b for a, b in zip(self.stats_before[i], last)]
        self.stats_now[i] = None

    def bodies(self, k: int, q) -> Bodies:
        """The Bodies message of tick k (before its poses): dead or watchdog-stopped robots where they stand,
        and the robots returning at k with their first pose."""
        static = tuple(Body(i, float(q[i][0]), float(q[i][1]), self.r, self.R) for i in range(self.n)
                       if self.stopped[i] or self.dead(i, k))
        back = tuple(Body(i, float(q[i][0]), float(q[i][1]), self.r, self.R) for i in range(self.n)
                     if self.returning(i, k) is not None)
        return Bodies(t=k * self.dt, seq=k, bodies=static, returning=back)

    # ------------------------------------------------------------------ commands

    def apply(self, k: int, raw: dict[int, tuple[float, float]]) -> list[tuple[float, float]]:
        """The commands robots move with over tick k: raw holds the command of tick k each running robot
        sent (a running robot that sent none, say after a timeout: its decision is taken all the same and
        its command is taken as zero)."""
        t, h, out = k * self.dt, self.h, []
        for i in range(self.n):
            ring, cmdh = self.ring[i], self.cmdh[i]
            for s in [s for s in ring if s <= k - h]:
                del ring[s]
                cmdh.pop(s, None)
            if self.running(i, k):
                lost, late = self.links[i].decide(k, t)
                ring[k] = LOST if lost else late
                cmdh[k] = raw.get(i, (0.0, 0.0))
                if lost:
                    self.dropped[fg.CLS_CMD] += 1
                elif late > 0:
                    self.delayed[fg.CLS_CMD] += 1
            if self.dead(i, k):
                self.stopped[i] = False  # a dead robot is a static body as dead, not as stopped
                out.append((0.0, 0.0))
                continue
            s = arrival(ring, k, self.dmax, self.wsrc[i])
            if s >= 0:
                self.wsrc[i], self.wlast[i] = s, k
                self.wnew[i] = cmdh[s]
                cmd = self.wnew[i]
            else:
                if k - self.wlast[i] == 1:
                    self.cmd_held += 1
                f = brake_factor(k - self.wlast[i], self.dt)
                cmd = (self.wnew[i][0] * f, self.wnew[i][1] * f)
            was = self.stopped[i]
            self.stopped[i] = (k - self.wlast[i]) * self.dt > self.watchdog_ticks * self.dt + 1e-9
            if self.stopped[i] and not was:
                self.watchdog_stops += 1
            out.append(cmd)
        return out

    def frozen(self, k: int) -> list[bool]:
        """The robots frozen at k for the metrics: by their laws (swarm sim's definition under faults), the
        dead ones never."""
        return [self.law_frozen[i] and not self.dead(i, k) for i in range(self.n)]

    # ------------------------------------------------------------------ counters

    def take_stats(self, i: int, m) -> None:
        """Robot i's report (a FaultStats message); one of a process before its restart is ignored."""
        if m.seq < self.born[i]:
            return
        self.stats_now[i] = (m.dropped_state, m.dropped_pose, m.dropped_ref, m.delayed_state, m.delayed_pose,
                             m.delayed_ref, m.max_age)
        self.law_frozen[i] = m.frozen
        self.max_age = max(self.max_age, float(m.max_age))

    def totals(self) -> tuple[list[int], list[int]]:
        """(dropped, delayed) by class (faultgen.CLS_* order) over the world and every robot's reports."""
        dropped, delayed = list(self.dropped), list(self.delayed)
        for i in range(self.n):
            now = self.stats_now[i]
            rows = [self.stats_before[i]] + ([list(now)] if now is not None else [])
            for row in rows:
                for c, a, b in ((fg.CLS_STATE, 0, 3), (fg.CLS_POSE, 1, 4), (fg.CLS_REF, 2, 5)):
                    dropped[c] += int(row[a])
                    delayed[c] += int(row[b])
        return dropped, delayed

    def metrics(self, alive_at_end: int, t_end: float) -> dict:
        dropped, delayed = self.totals()
        return {
            "messages_dropped": sum(dropped),
            "robots_alive_at_end": alive_at_end,
            "faults": {
                "dropped": dict(zip(CLASSES, dropped)),
                "delayed": dict(zip(CLASSES, delayed)),
                "killed": self.killed,
                "restarted": self.restarted,
                "hung": self.hung,
                "partitions": fl.partitions_begun(self.faults, t_end),
                "cmd_held": self.cmd_held,
                "watchdog_stops": self.watchdog_stops,
                "max_state_age_s": round(self.max_age, 9),
            },
        }
