"""The world's count of a real-time run under faults (docs/faults.md, Lock-step and real time).

    rtf = RealtimeFaults(scn, fault_bus)       # the world's own FaultBus: the commands it lost or delayed
    rtf.take(i, faultstats, token_gen)         # robot i's report (with each of its statuses); False: refused
    rtf.away(i, t)                             # robot i's process is dead or hung at t by the schedule
    rtf.returned(i, t, within)                 # robot i's process came back by the schedule near t
    rtf.metrics(t_end, cmd_held, watchdog_stops)   # messages_dropped and the faults object of the metrics

Each robot's fault bus counts what it lost or delayed of its poses, references and neighbours' states
and reports the totals so far (a `faultstats` message, seq counting that process's reports from 0); the
world keeps the newest report of each process and adds the last one of a process that was replaced
(a restarted robot counts from 0 again). So the totals are what every process decided, up to the last
report each sent: a robot's losses after its last status, or those of a process killed between two
statuses, are not in them. Kills, restarts and hangs are counted from the schedule, up to the simulated
time the run reached.
"""

from __future__ import annotations

from swarm.core import faults as fl
from swarm.core.faultsim import CLASSES


class RealtimeFaults:
    def __init__(self, scn, fbus) -> None:
        self.faults, self.n, self.fbus = scn.faults, scn.n, fbus
        self.seq = [-1] * self.n  # the newest report's seq of each robot's current process
        self.gen = [-1] * self.n  # the robot's token count at that report
        self.now: list[tuple | None] = [None] * self.n  # its counters: dropped state, pose, ref; delayed state, pose, ref
        self.before = [[0] * 6 for _ in range(self.n)]  # the last reports of its earlier processes, added up
        self.max_age = 0.0

    def take(self, i: int, m, token_gen: int) -> bool:
        """Robot i's report m (a FaultStats); token_gen: how many tokens robot i has declared so far. A seq
        that does not move forward is a new process's (its first reports) when the robot's token is new
        since the last report, and refused otherwise (False: a stale or repeated one)."""
        if m.seq <= self.seq[i]:
            if token_gen == self.gen[i]:
                return False
            last = self.now[i]
            if last is not None:
                self.before[i] = [a + b for a, b in zip(self.before[i], last)]
        self.seq[i], self.gen[i] = m.seq, token_gen
        self.now[i] = (m.dropped_state, m.dropped_pose, m.dropped_ref, m.delayed_state, m.delayed_pose, m.delayed_ref)
        self.max_age = max(self.max_age, float(m.max_age))
        return True

    def away(self, i: int, t: float) -> bool:
        """Robot i's process is dead or hung at simulated time t by the schedule (its token may go then)."""
        return fl.process_state(self.faults, i, t) != "alive"

    def returned(self, i: int, t: float, within: float) -> bool:
        """Robot i's process came back (a restart, or the end of a hang) by the schedule at most `within`
        seconds before t [s] (or a little after: the schedule's clock and a robot's differ by a period or so)."""
        ends = [k.end for k in self.faults.kills if k.robot == i and k.restart is not None]
        ends += [h.end for h in self.faults.hangs if h.robot == i]
        return any(t - within <= end <= t + within for end in ends)

    def totals(self) -> tuple[list[int], list[int]]:
        """(dropped, delayed) by class (faultgen.CLS_* order): the world's commands and every robot's reports."""
        dropped, delayed = list(self.fbus.dropped), list(self.fbus.delayed)
        for i in range(self.n):
            now = self.now[i]
            rows = [self.before[i]] + ([list(now)] if now is not None else [])
            for row in rows:
                for c, a, b in ((0, 0, 3), (1, 1, 4), (3, 2, 5)):  # state, pose, ref
                    dropped[c] += int(row[a])
                    delayed[c] += int(row[b])
        return dropped, delayed

    def metrics(self, t_end: float, cmd_held: int, watchdog_stops: int) -> dict:
        """messages_dropped and the faults object (docs/metrics.md); process faults up to t_end [s]."""
        f = self.faults
        dropped, delayed = self.totals()
        eps = 1e-9
        return {
            "messages_dropped": sum(dropped),
            "faults": {
                "dropped": dict(zip(CLASSES, dropped)),
                "delayed": dict(zip(CLASSES, delayed)),
                "killed": sum(1 for k in f.kills if k.at <= t_end + eps),
                "restarted": sum(1 for k in f.kills if k.restart is not None and k.end <= t_end + eps),
                "hung": sum(1 for h in f.hangs if h.at <= t_end + eps),
                "partitions": fl.partitions_begun(f, t_end),
                "cmd_held": cmd_held,
                "watchdog_stops": watchdog_stops,
                "max_state_age_s": round(self.max_age, 9),
            },
        }
