"""Scheduled process faults, done for real by `swarm up`'s supervisor: SIGKILL, a new process, SIGSTOP, SIGCONT.

    pf = ProcessFaults(faults, dt, lockstep=True)
    for robot, action in pf.due(tick=progress.seq):          # lock-step: by the world's tick
        ...                                                    # real time: pf.due(t=simulated time now)

Actions, in order: "kill" (SIGKILL the robot's process group), "start" (a new process takes the robot
over: the kill rule's restart), "stop" (SIGSTOP), "cont" (SIGCONT). Each happens once.

Lock-step: a kill or hang at tick K happens once the world is at K or later (the process has answered
tick K - 1 and is not sent anything more until it returns); a restarted process is started right after
the kill, and the world waits for its liveliness token before the restart tick; SIGCONT comes once the
world is at the tick before the resume and the process has been stopped MIN_STOP_S, longer than zenoh's
lease, so its session surely closed: the world waits for its token to lapse, come back, and for the
robot to say it is back (its subscriptions in place) before that tick. Either
way the run equals `swarm sim` with the same faults: every process follows the same schedule.

Real time: each action at its scheduled simulated time (the world's clock: epoch + t / speed), the
restart included: a robot is dead from its kill to its restart, and the others learn it from its
liveliness token (a 1 s lease) as they would on real hardware.
"""

from __future__ import annotations

import math
import time
from typing import cast

from swarm.core import faults as fl
from swarm.core.faulttable import first_tick

MIN_STOP_S = 2.5  # lock-step: wall seconds a hung process stays stopped at least (more than zenoh's 1 s lease)


class ProcessFaults:
    def __init__(self, faults: fl.Faults | None, dt: float, lockstep: bool, min_stop_s: float = MIN_STOP_S) -> None:
        self.lockstep, self.min_stop_s = lockstep, min_stop_s
        self.stopped_at: dict[int, float] = {}  # robot -> monotonic time of its SIGSTOP
        todo: list[tuple[float, int, int, str]] = []  # (when: tick or simulated s, order, robot, action)
        # at one time, a restart or a resume before a kill or a hang (docs/faults.md): a robot hung at the time of
        # its restart is its new process, stopped (it was the old one's pid, already gone); lock-step starts the
        # new process right after the kill, at the kill's tick
        first, then = (0, 1) if not lockstep else (0, 0)
        # lock-step: a hang between two ticks stops the robot at none (its SIGCONT would come before its SIGSTOP
        # and leave it stopped): neither signal is sent
        skip = {(h.robot, t, kind) for h in (faults.hangs if faults and lockstep else ())
                if first_tick(h.at, dt) == first_tick(h.end, dt) for t, kind in ((h.at, "hang"), (h.end, "resume"))}
        for t, robot, kind in (fl.events(faults) if faults else []):
            if (robot, t, kind) in skip:
                continue
            k = first_tick(t, dt)
            if kind == "kill":
                todo.append((k if lockstep else t, then, robot, "kill"))
            elif kind == "restart":
                # lock-step: at once after the kill (the world waits for it); real time: at its time
                todo.append((self._kill_tick(cast(fl.Faults, faults), robot, t, dt) if lockstep else t,
                             1 if lockstep else first, robot, "start"))
            elif kind == "hang":
                todo.append((k if lockstep else t, then, robot, "stop"))
            else:
                todo.append((max(0, k - 1) if lockstep else t, 2 if lockstep else first, robot, "cont"))
        self.todo = sorted(todo)

    @staticmethod
    def _kill_tick(faults: fl.Faults, robot: int, restart_t: float, dt: float) -> int:
        for k in faults.kills:
            if k.robot == robot and k.restart is not None and abs(k.end - restart_t) < 1e-9:
                return first_tick(k.at, dt)
        return first_tick(restart_t, dt)

    def __bool__(self) -> bool:
        return bool(self.todo)

    def due(self, tick: int | None = None, t: float | None = None) -> list[tuple[int, str]]:
        """The actions due now (world at `tick` in lock-step, at simulated time `t` in real time), in order;
        each is returned once."""
        now = tick if self.lockstep else t
        if now is None:
            return []
        out = []
        while self.todo and self.todo[0][0] <= now + (0 if self.lockstep else 1e-9):
            _, _, robot, action = self.todo[0]
            if action == "cont" and self.lockstep and \
                    time.monotonic() < self.stopped_at.get(robot, -math.inf) + self.min_stop_s:
                break  # lock-step: stopped past the lease (the world waits for its token to lapse and come back)
            self.todo.pop(0)
            if action == "stop":
                self.stopped_at[robot] = time.monotonic()
            out.append((robot, action))
        return out

    def next_time(self) -> float | None:
        """When the next action is due (a tick or simulated seconds); None when none is left."""
        return self.todo[0][0] if self.todo else None
