"""What one lock-step robot knows under faults: the receiving side's fault layer of an agent.

A lock-step agent under faults still receives every message the network carries (its synchronisation,
the wait rule of docs/runtime.md, needs them: nobody waits out a timeout for a message the schedule
removed), and this layer decides, with the fault model every process shares (swarm.core.faults), which
of them its law is given: the same rules, in the same order, as the simulator's fault kernel
(swarm.core.faultkernel), so a faulty lock-step run equals `swarm sim` step for step.

    view = FaultView(robot_id, robots, dt, reach, side, faults)
    view.active(k)                        # this robot's process runs at tick k (the schedule)
    b = view.belief(k, pose_of_tick)      # its pose as it knows it at k (delivered poses + its commands)
    view.offer(k, j, state) / view.forget(k, j)   # a neighbour's raw state of tick k
    ref, bodies = view.inputs(k, refs, static, obstacles)   # what the law is given
    view.commanded(k, v, w)               # its command of tick k (for its own dead reckoning)

Raw messages are kept for the last H ticks (H = the largest delay + 2): a late delivery takes the
message of its send tick.
"""

from __future__ import annotations

from swarm.core import faultgen as fg
from swarm.core import faults as fl
from swarm.core import kinematics
from swarm.core.faultsim import TickSchedule, arrival
from swarm.core.faulttable import FaultTable, Link


class FaultView:
    def __init__(self, robot_id: int, robots: int, dt: float, reach: float, side: float, faults: fl.Faults) -> None:
        self.id, self.n, self.dt = robot_id, robots, dt
        self.table = FaultTable.of(faults, robots, dt)
        self.schedule = TickSchedule(self.table, robots)
        self.dmax = int(max([d.ticks + d.jitter for d in faults.delays], default=0))
        self.h = self.dmax + 2
        self.offer_r = reach + (side - reach) / 3.0  # reach + L: what this robot surely receives
        self.side = side
        self.pose_link = self.table.link(fg.CLS_POSE, fg.WORLD, robot_id)
        self.ref_link = self.table.link(fg.CLS_REF, fg.LEADER, robot_id)
        self.state_links: dict[int, Link] = {}
        # its belief: kb its tick (-1: none yet), bel (x, y, theta); kp the newest pose's send tick, pbase that pose
        self.kb, self.bel, self.kp, self.pbase = -1, [0.0, 0.0, 0.0], -1, (0.0, 0.0, 0.0)
        self.belh: dict[int, tuple[float, float, float]] = {}  # its belief at recent ticks it was active
        self.cmdh: dict[int, tuple[float, float]] = {}  # its command at recent ticks
        self.lastc = (0.0, 0.0)
        self.kr = -1  # the newest delivered reference's send tick
        self.poses: dict[int, tuple[float, float, float]] = {}  # raw poses by tick
        self.refs: dict[int, tuple] = {}  # raw references by tick: (x, y, theta, v, w)
        self.ring_pose: dict[int, int] = {}  # send tick -> delay (or LOST)
        self.ring_ref: dict[int, int] = {}
        self.ring_state: dict[int, dict[int, int]] = {}  # j -> send tick -> delay
        self.raw_state: dict[int, dict[int, tuple[float, float]]] = {}  # j -> send tick -> (x, y)
        self.tk: dict[int, int] = {}  # j -> newest delivered send tick (>= 0), or -(s + 2) forgotten at s
        self.tpos: dict[int, tuple[float, float]] = {}
        self.listen = False
        self.event: str | None = None  # "restart" or "resume" when the tick begun last is a return tick
        self.born = 0  # the tick this robot's process (re)started
        self.max_age = 0.0  # the oldest neighbour state its law used [s]
        self.dropped = [0, 0, 0, 0]  # by class (faultgen.CLS_*), counted as the simulator counts them
        self.delayed = [0, 0, 0, 0]

    # ------------------------------------------------------------------ the schedule

    def active(self, k: int) -> bool:
        return self.schedule.active(self.id, k)

    def returns(self) -> bool:
        """This robot is restarted or resumed at some tick."""
        return self.schedule.next_return(self.id, -1) is not None

    def last_return(self) -> int | None:
        """The tick of this robot's last restart or resume (None: it has none)."""
        ticks = [tick for tick, kind in self.schedule.events[self.id] if kind in (1, 3)]
        return max(ticks) if ticks else None

    def returns_next(self, k: int) -> bool:
        """The next tick after k at which this robot runs is one it returns at (restarted or resumed)."""
        if self.active(k + 1):
            return self.schedule.fresh(self.id, k + 1) is not None
        return self.schedule.next_return(self.id, k) is not None  # only a return makes it run again

    def other_active(self, j: int, k: int) -> bool:
        return self.schedule.active(j, k)

    def _alive_at(self, s: int) -> bool:
        """This robot's process (this one, not one before a restart) was running at tick s."""
        return s >= self.born and self.schedule.active(self.id, s)

    def _note(self, cls: int, lost: bool, late: int) -> int:
        if lost:
            self.dropped[cls] += 1
            return -1
        if late > 0:
            self.delayed[cls] += 1
        return late

    def _prune(self, k: int) -> None:
        old = k - self.h
        for d in (self.belh, self.cmdh, self.poses, self.refs, self.ring_pose, self.ring_ref):
            for s in [s for s in d if s <= old]:
                del d[s]
        for d in list(self.ring_state.values()) + list(self.raw_state.values()):
            for s in [s for s in d if s <= old]:
                del d[s]

    # ------------------------------------------------------------------ tick k

    def start(self, k: int, pose: tuple[float, float, float], rejoin: bool = False) -> tuple[float, float, float] | None:
        """Tick k begins (its raw pose came): the process events, then its belief at k; None while its
        process is dead or hung (it does nothing at k). rejoin: its session dropped outside the schedule and
        came back, and it rejoins the run at k (agents.intake): as a resume ("rejoin"), it listens at k."""
        self.event = event = self.schedule.fresh(self.id, k)
        if rejoin and event is None:
            self.event = event = "rejoin"
        if event == "restart":  # a fresh process knows nothing, nor takes what was sent to the old one
            self.kb, self.kp, self.kr, self.born = -1, -1, -1, k
            self.tk.clear()
            self.tpos.clear()
            self.dropped, self.delayed, self.max_age = [0, 0, 0, 0], [0, 0, 0, 0], 0.0  # its counters too
        if event is not None:
            self.listen = True
            self.kb = -1  # its first pose always arrives
        self._prune(k)
        if not self.active(k):
            self.cmdh[k] = self.lastc
            return None
        t = k * self.dt
        self.poses[k] = pose
        if self.kb < 0:
            self.ring_pose[k] = 0  # the first pose always arrives
        else:
            lost, late = self.pose_link.decide(k, t)
            self.ring_pose[k] = self._note(fg.CLS_POSE, lost, late)
        s = arrival(self.ring_pose, k, self.dmax, self.kp)
        if s >= 0 and self._alive_at(s):
            self.kp = s
            self.pbase = self.poses[s]
            q = list(self.pbase)
            c = [0.0, 0.0, 0.0]
            for u in range(s, k):  # its own commands since that pose (exact arcs)
                v, w = self.cmdh.get(u, self.lastc)
                kinematics.step_pose(q, c, v, w, self.dt)
            self.bel = q
            self.kb = k
        elif self.kb >= 0:  # no pose: the last belief advanced by the last command
            dx, dy, dth = kinematics.arc_displacement(self.bel[2], self.lastc[0], self.lastc[1], (k - self.kb) * self.dt)
            self.bel = [self.bel[0] + dx, self.bel[1] + dy, self.bel[2] + dth]
            self.kb = k
        b = (self.bel[0], self.bel[1], self.bel[2])
        self.belh[k] = b
        return b

    def previous(self, k: int) -> tuple[float, float, float]:
        """Its belief at k - 1 if it was active then, else at k (what neighbours' offers are measured from)."""
        return self.belh.get(k - 1) or self.belh[k]

    def reference(self, k: int, ref: tuple | None) -> None:
        """Its raw reference of tick k, (x, y, theta, v, w) (None: it did not come)."""
        if ref is not None:
            self.refs[k] = ref
            lost, late = self.ref_link.decide(k, k * self.dt)
            self.ring_ref[k] = self._note(fg.CLS_REF, lost, late)
        s = arrival(self.ring_ref, k, self.dmax, self.kr)
        if s >= 0 and self._alive_at(s):
            self.kr = s
            self.ref_kr = self.refs[s]

    def neighbour(self, k: int, j: int, xy: tuple[float, float] | None) -> None:
        """Robot j's raw state of tick k (its position), or None when none came at k (it is out of range)."""
        ring = self.ring_state.setdefault(j, {})
        raw = self.raw_state.setdefault(j, {})
        if xy is not None and self.schedule.active(j, k):
            px, py, _ = self.previous(k)
            dx, dy = xy[0] - px, xy[1] - py
            if dx * dx + dy * dy < self.offer_r * self.offer_r:
                raw[k] = xy
                if k == 0:
                    ring[k] = 0  # the start barrier: every robot's first state arrives
                else:
                    link = self.state_links.get(j)
                    if link is None:
                        link = self.state_links[j] = self.table.link(fg.CLS_STATE, j, self.id)
                    lost, late = link.decide(k, k * self.dt)
                    ring[k] = self._note(fg.CLS_STATE, lost, late)
            else:
                self.tk[j] = -(k + 2)  # out of range: forgotten, its older states too
        elif xy is None and self.schedule.active(j, k):
            self.tk[j] = -(k + 2)
        tkj = self.tk.get(j, -1)
        s = arrival(ring, k, self.dmax, tkj if tkj >= 0 else -tkj - 2)
        if s >= 0 and self._alive_at(s):
            self.tk[j] = s
            self.tpos[j] = raw[s]

    def law_inputs(self, k: int) -> tuple[bool, tuple | None]:
        """(listening, reference): a robot that just (re)started or resumed listens this tick (it commands
        zero); otherwise its newest delivered reference (x, y, theta, v, w) advanced along the leader's
        arc to t, or None when none came yet (it commands zero)."""
        if self.listen:
            self.listen = False
            return True, None
        if self.kr < 0:
            return False, None
        t = k * self.dt
        x, y, th, v, w = self.ref_kr
        if self.kr < k:  # the newest reference, advanced along the leader's arc to t
            dx, dy, dth = kinematics.arc_displacement(th, v, w, t - self.kr * self.dt)
            x, y, th = x + dx, y + dy, th + dth
        return False, (x, y, th, v, w)

    def bodies(self, k: int, static: dict[int, tuple[float, float, float, float]], obstacles, robot_r: float,
               robot_R: float, kind_robot: int, kind_obstacle: int, kind_dead: int):
        """The bodies its law is given at k, in summation order: known neighbours by id (not static), the
        obstacles (x, y, r, R, by index) within the cell side, the static bodies {id: (x, y, r, R)} (dead or
        stopped robots) by id. Lists nx, ny, nr, nR, nk, na; na: the age [s] of what it knows of each,
        plus its own pose's age (its own position is that uncertain)."""
        x, y = self.bel[0], self.bel[1]
        own = (k - self.kp) * self.dt
        side2 = self.side * self.side
        nx, ny, nr, nR, nk, na = [], [], [], [], [], []
        for j in sorted(self.tk):
            s = self.tk[j]
            if s < 0 or j in static or not self._shown(j, k):
                continue
            bx, by = self.tpos[j]
            if (x - bx) ** 2 + (y - by) ** 2 < side2:
                age = (k - s) * self.dt
                self.max_age = max(self.max_age, age)
                nx.append(bx)
                ny.append(by)
                nr.append(robot_r)
                nR.append(robot_R)
                nk.append(kind_robot)
                na.append(age + own)
        for ox, oy, orr, oR in obstacles:
            if (x - ox) ** 2 + (y - oy) ** 2 < side2:
                nx.append(ox)
                ny.append(oy)
                nr.append(orr)
                nR.append(oR)
                nk.append(kind_obstacle)
                na.append(own)
        for j in sorted(static):
            sx, sy, sr, sR = static[j]
            if j != self.id and (x - sx) ** 2 + (y - sy) ** 2 < side2:
                nx.append(sx)
                ny.append(sy)
                nr.append(sr)
                nR.append(sR)
                nk.append(kind_dead)
                na.append(own)
        return nx, ny, nr, nR, nk, na

    def _shown(self, j: int, k: int) -> bool:
        """A known neighbour is a body unless it is dead now (then it is a static body)."""
        return self.schedule.state(j, k) != fg.PROC_DEAD

    def commanded(self, k: int, v: float, w: float) -> None:
        self.cmdh[k] = (v, w)
        self.lastc = (v, w)

    def counters(self) -> tuple[int, int, int, int, int, int, float]:
        """(dropped state, pose, ref; delayed state, pose, ref; the oldest state used [s]): a FaultStats."""
        d, y = self.dropped, self.delayed
        return (d[fg.CLS_STATE], d[fg.CLS_POSE], d[fg.CLS_REF], y[fg.CLS_STATE], y[fg.CLS_POSE], y[fg.CLS_REF],
                self.max_age)

    def stats(self) -> dict:
        names = ("state", "pose", "cmd", "ref")
        return {"dropped": dict(zip(names, self.dropped)), "delayed": dict(zip(names, self.delayed)),
                "max_state_age_s": round(self.max_age, 9)}

