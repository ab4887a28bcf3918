"""Real time's command: what a robot knows of every neighbour (last state and its age, never forgotten
while it may be near), the law run as in lock-step, and the safety rule around it (swarm.core.safety;
docs/runtime.md, "The safety invariant").
"""

from __future__ import annotations

import logging
import math

from swarm.proto import keys
from swarm.core import law, safety
from agents.state import PROBE_S, RECENT_S, STALE_AFTER_S, STAND_BELOW
from agents.bodies import Bodies

log = logging.getLogger("swarm.robot")


class SafeCommand(Bodies):
    """The real-time command: the bodies as known now, the law, the safety rule."""

    def _rt_bodies(self, x: float, y: float, t: float, end: float):
        """Real time (under the lock): the law's bodies as in lock-step (robots by id closer than the cell side,
        with their last state however old, then the obstacles near, then the robots standing still: dead ones
        and those the world lists; ages 0: the law and its governor run as in lock-step), and the safety rule's
        bodies (x, y, contact distance, the most the body can be from (x, y) by `end`: swarm.core.safety).

        What a robot knows (docs/runtime.md, "The safety invariant"): every robot with its last state and that
        state's age (the age it had when it came plus the time since, on this robot's clock), never forgotten while
        it may be near: only a robot whose newest state puts it outside this robot's block of cells (the 3x3 it
        hears: everything within the cell side) is taken as away, until a newer state comes (a robot that leaves
        a cell keeps putting its states there a while: DEPART_S), and never one that a partition of the run's
        faults cuts off from this robot now. Not hearing a robot says nothing of where it is: its link may be
        stalled or down. A robot whose token is gone is a static body for the law; the safety rule keeps its
        motion bound (this robot's newest state of it need not be its last) until the world lists it: the robots
        the world lists stand still until the listing's t + BODIES_HOLD_S. Returns the law's lists nx, ny, nr,
        nR, nk, na, the numbers of robots and stale robots it uses, the safety rule's list, and the information
        delay [s] (_info_delay)."""
        side = self.side
        r2 = side * side
        mono = self.clock.monotonic()
        speed, V, eps = self.speed, self.V, safety.CLOCK_SKEW_S
        cx, cy = math.floor(x / side), math.floor(y / side)
        nx, ny, nr, nR, nk, na = [], [], [], [], [], []
        safe = []
        robots = stale = 0
        oldest = 0.0
        news, heard = 0.0, 0  # the ages recent states came with: their mean goes into the information delay
        table, dead, away, rx, beyond = self.table, self.dead, self.away, self.rx, self._beyond
        dead_near = []
        listed = self._listed_now()
        # what a neighbour heard in order may do: its announced stop, and V over the times a command of it this
        # robot has not heard of may have begun: since the newest pose came, and in the gaps of its poses since the
        # state came (each plus the longest reservation); only on links that keep order (no fault bus)
        pose = self.pose
        since_pose = end - t + (t - pose.t if pose is not None and t > pose.t else 0.0) + eps
        ordered = self._ordered and pose is not None
        reserve = safety.VALIDITY_MAX_S + safety.RAMP_S
        for j in sorted(table):
            nb = table[j]
            a0, m0 = rx.get(j, (0.0, mono))
            since = (mono - m0) * speed if mono > m0 else 0.0
            age = a0 + since
            if since < RECENT_S:
                news += a0
                heard += 1
            dx = x - nb.x
            dy = y - nb.y
            d2 = dx * dx + dy * dy
            contact = nb.r if nb.r > self._r else self._r
            gone = j in dead
            if gone and j in listed:  # the world has it where it stands: that, not its last state, is the body
                continue
            if (abs(math.floor(nb.x / side) - cx) > 1 or abs(math.floor(nb.y / side) - cy) > 1) and \
                    not self._cut_off(j, t, age):
                if j not in beyond:  # its newest state is beyond the cells this robot hears: it hears it come back
                    beyond.add(j)
                    self.forgotten += 1
                away.add(j)
                continue
            beyond.discard(j)
            if gone:
                dead_near.append(nb)
            elif since > PROBE_S and j not in self._probes:
                self._want_probe.add(j)  # kept, not heard: where is it? (_update_probes)
            m = V * (end - t + age + eps)  # safety.motion_bound, inline: the speed bound over the state's age,
            if nb.stop is not None and ordered:  # or what it announced, heard in order (above),
                missed = self._missed(m0)
                quiet = nb.stop + V * (since_pose + (missed + reserve if missed > 0.0 else 0.0))
                if quiet < m:
                    m = quiet
            if nb.still is not None and nb.stop is not None:  # or less while a promise to stand holds
                left = nb.still - nb.t
                ends = t - age + (left if left < safety.PROMISE_MAX_S else safety.PROMISE_MAX_S)
                promised = nb.stop + V * (end - ends + eps if end + eps > ends else 0.0)
                if promised < m:
                    m = promised
            safe.append((nb.x, nb.y, contact, m))
            if not gone and d2 < r2:
                nx.append(nb.x)
                ny.append(nb.y)
                nr.append(nb.r)
                nR.append(nb.R)
                nk.append(law.KIND_ROBOT)
                na.append(0.0)
                robots += 1
                stale += age > STALE_AFTER_S
                if age > oldest:
                    oldest = age
        self._static_bodies(x, y, r2, nx, ny, nr, nR, nk, na, dead_near)
        for ox, oy, orr, _oR in self._obstacles_near(keys.cell_of(x, y, self.side)):
            safe.append((ox, oy, orr, 0.0))
        if listed:  # the robots the world lists as standing still: where it has them
            now = self.sim_time(self.clock.time())
            age = 0.0 if now is None else max(0.0, now - self.rt_static_t)
            m = V * max(0.0, end - t + age - safety.BODIES_HOLD_S + eps)
            for sx, sy, sr, _sR in listed.values():
                safe.append((sx, sy, sr if sr > self._r else self._r, m))
        self.oldest_state_s = oldest
        # nobody heard lately: its own poses' lag says how late a robot coming near would be heard (an old figure
        # kept forever would slow a robot alone for good)
        self._news.add(news / heard if heard else self._lag.value)
        return nx, ny, nr, nR, nk, na, robots, stale, safe, self._info_delay()

    def command_realtime(self, t: float, x: float, y: float, th: float, ref: tuple, pose_t: float,
                         listen: bool = False) -> tuple[float, float]:
        """Real time (under the lock): the command at time t from the pose (x, y, th) of time pose_t, and what its
        state and command announce (_rt_until, _rt_stop, _rt_still). The law runs as in lock-step (its governor's
        horizon the period, every age 0); then, with the governor on, the safety rule (swarm.core.safety;
        docs/runtime.md, "The safety invariant"): the command is valid until t plus two periods and twice the
        recent lag of its poses; the speed stays within the bound V; it is slowed (v and w together: the same
        path) to the largest speed at which everything it can reach from its pose stays clear of everywhere every
        known body (and every robot it has not heard) can be until its motion surely ends, unless it moves away
        from that body; when no speed is allowed it stands (turning in place) and promises to stand a while
        (`still`), so its neighbours may take it as a static body and pass. listen: it holds still (its first
        periods), and says so."""
        dt = self.cfg.dt
        lag = t - pose_t if t > pose_t else 0.0
        self._lag.add(lag)
        until = t + safety.validity(dt, self._lag.value, self._act.value)
        self._sent_at.append((pose_t, t))
        # should this process die, a base with its own timeout acts on the command that long: its reach counts it
        reserve = until if self.base_timeout is None else max(until, t + self.base_timeout)
        eps, ramp = safety.CLOCK_SKEW_S, self.ramp
        vp = wp = 0.0
        ep = -math.inf
        pend = self._pending
        while pend and pend[0][2] + eps + ramp / 2.0 <= pose_t:
            pend.popleft()  # its motion is over by the pose's time
        for a, b, u in pend:
            if a > vp:
                vp = a
            if b > wp:
                wp = b
            if u > ep:
                ep = u
        ep = max(ep + eps + ramp / 2.0, pose_t)  # (-inf without one: the pose's time)
        plan = safety.Plan(pose_t, t, reserve, vp, ep, wp, ramp, self.switch, eps)
        nx, ny, nr, nR, nk, na, robots, stale, safe, delay = self._rt_bodies(x, y, t, plan.end)
        self.neighbours, self.stale = robots, stale
        self.stale_total += stale
        self.max_age = max(self.max_age, self.oldest_state_s)
        if listen:
            v = w = 0.0
        else:
            xl, yl, thl, vl, wl = ref
            self.p[law.P_DT] = dt
            v, w = self._law(x, y, th, self.cfg.dx, self.cfg.dy, self.cfg.r, t, xl, yl, thl, vl, wl,
                                         nx, ny, nr, nR, nk, na, len(nx), self.mem, self.p)
            self.commanded += 1
            if self.cfg.governor and v == v and w == w:  # a NaN goes on to be refused, never driven
                v, w = self._safe(t, x, y, th, v, w, plan, safe, delay)
        self._rt_until = until
        self._rt_stop = plan.reach(abs(v))
        self._rt_still = self._still_until if self._still_until > t else 0.0
        pend.append((abs(v), abs(w), reserve))
        return v, w

    def _safe(self, t: float, x: float, y: float, th: float, v: float, w: float, plan, safe, delay: float
              ) -> tuple[float, float]:
        """Real time: the law's (v, w) within the speed bound and the safety rule (command_realtime)."""
        V, held = self.V, False
        if abs(v) > V:
            f = V / abs(v)
            v, w = v * f, w * f
        if t < self._still_until:  # its promise: it stands (turning in place)
            v, held = 0.0, True
        else:
            sv = 1.0 if v >= 0.0 else -1.0
            unknown = safety.unheard_speed(self.side, self._r, delay, plan.end - t)
            limit, why = plan.limit(x, y, sv * math.cos(th), sv * math.sin(th), w, safe, V, unknown)
            if abs(v) > limit:
                held = True
                self.held_why[why] += 1
                if limit < STAND_BELOW:  # no motion it could make: stand, turn in place, and say it stands a while
                    if log.isEnabledFor(logging.DEBUG):
                        near = sorted((round(math.hypot(x - b[0], y - b[1]) - b[2] - b[3], 3), b[:2]) for b in safe)[:3]
                        log.debug("robot %d stands at t = %.2f s (its law asked v %.3f m/s): held by %s; the nearest "
                                  "bodies' room (m) and places: %s", self.id, t, v,
                                  ("a body", "only moving away from one", "robots it has not heard")[why - 1], near)
                    v = 0.0
                    self._promises += 1
                    jitter = 0.5 * ((math.sin(self.id * 12.9898 + self._promises * 78.233) * 43758.5453) % 1.0)
                    self._still_until = t + min(plan.end - t, safety.PROMISE_S) * (1.0 + jitter)
                else:
                    f = limit / abs(v)
                    v, w = v * f, w * f
        self.held += held
        return v, w
