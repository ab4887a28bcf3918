"""Real time's safety rule: a robot never commands a motion that could meet another body, whatever the latency.

The invariant (docs/runtime.md, "The safety invariant", states it with its assumptions and the argument): when
robot i commands (v, w) from its pose p (of time s) at time t, every position it can reach from then on if it
sends no further command stays farther than the contact distance from everywhere every known body can be until
that motion surely ends, or it moves away from that body. What i can reach is bounded because a drive executes a
command only until the command's `until` and then brakes along a known ramp; where another robot j can be is
bounded by the speed bound V over the age of its last state, or by what j announced (a standing robot's promise,
a dead robot's final motion). Late information only makes these bounds larger: robots slow down and stop, and
never drive into each other. Lock-step keeps the paper's law and its governor exactly (the world never misses a
command the schedule does not remove); this rule is real time's.

Scalar style (floats and lists, no numpy): it runs in the robot process on every command. All times are on the
swarm's clock [simulated s], distances in m, speeds in m/s.

    until = t + validity(dt, lag)                          # how long the drive may execute the new command
    plan = Plan(s, t, until, pending, ramp, switch, eps)   # what the robot itself may still do
    limit, why = plan.limit(x, y, heading, w, bodies, V, unknown)  # the largest |v| the rule allows
    stop = plan.reach(min(|v|, limit))                     # the `stop` its state announces
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

RAMP_S = 0.1  # s: the simulated drive brakes from a command's `until` to a stop along this (docs/runtime.md)
CLOCK_SKEW_S = 0.01  # s: how far two processes' swarm clocks may differ (NTP on a LAN: a few ms)
PROMISE_MAX_S = 1.0  # s: a receiver takes a standing robot's promise at most this far past its state's time
PROMISE_S = 0.15  # s: a robot promises to stand at most this long at a time (and its reservation at least)
VALIDITY_MAX_S = 0.25  # s: the longest a command may be executed without a newer one (longer ones would make every
# reservation so long that robots in formation could not keep up with the leader near each other)
BODIES_HOLD_S = 0.25  # s: a robot the world lists as standing does not move before the listing's t + this
DEFAULT_SPEED_BOUND = 1.0  # m/s: real time's speed bound when the scenario sets no control.v_max (at least)
MARGIN = 1e-3  # m: kept between a reservation and the contact distance (roundings)
TURN_MAX = math.pi / 4  # rad: the most a robot may turn over its reservation and still count as moving away

# why limit() held a robot back (the strictest body's kind)
FREE, BODY, AWAY_ONLY, UNKNOWN, PENDING = 0, 1, 2, 3, 4


def speed_bound(v_max: float, leader_speed: float) -> float:
    """Real time's speed bound V [m/s]: the scenario's control.v_max when it sets one, else twice the leader's
    largest speed, at least DEFAULT_SPEED_BOUND. Every robot keeps to it and assumes it of every other."""
    if v_max > 0.0:
        return v_max
    return max(DEFAULT_SPEED_BOUND, 2.0 * abs(leader_speed))


def validity(dt: float, lag: float, act: float = 0.0) -> float:
    """How long after its computation a command may be executed [s]: long enough for the next command to land
    (and one period more if that one is late): three control periods plus twice the lag of the robot's poses (the
    way back to the drive takes about as long), or, when the drive says which command it executes (a pose's
    `cmd`), two periods plus the time from computing a command to seeing it act (act); at most VALIDITY_MAX_S. The
    caller gives a typical lag and act (the 75th percentile of the recent ones: Recent), not the largest:
    a longer validity makes every reservation longer (everything near slows down), while a command that comes
    after its validity only brakes its robot, until the next one, a period later, lands."""
    return min(VALIDITY_MAX_S, max(3.0 * dt + 2.0 * max(0.0, lag), 2.0 * dt + max(0.0, act)))


class Recent:
    """The q-quantile of the last `size` samples (0 before any), recomputed every `every` samples: a typical lag,
    deaf to the odd outlier (a lost packet sent again) and quick to follow a machine that slows."""

    def __init__(self, size: int = 64, q: float = 0.75, every: int = 16) -> None:
        self._ring = [0.0] * size
        self._n = 0
        self._q, self._every = q, every
        self.value = 0.0

    def add(self, x: float) -> None:
        size = len(self._ring)
        self._ring[self._n % size] = x
        self._n += 1
        if self._n % self._every == 0 or self._n <= self._every:
            got = sorted(self._ring[:min(self._n, size)])
            self.value = got[min(len(got) - 1, int(self._q * len(got)))]


def motion_bound(tau: float, age: float, t: float, V: float, stop: float | None = None,
                 still_left: float | None = None, eps: float = CLOCK_SKEW_S) -> float:
    """How far a body known from a state `age` seconds old at time t can be from that state's position at time
    tau >= t: V over the time since the state, or, when the state carried them, what it announced: at most `stop`
    until its promise ends (`still_left` seconds after the state's time), V after."""
    free = V * (tau - t + age + eps)
    if stop is None or still_left is None:
        return free
    ends = t - age + min(still_left, PROMISE_MAX_S)  # the promise's end on this robot's time line
    return min(free, stop + V * max(0.0, tau - ends + eps))


class Plan:
    """What robot i may still do from its pose p (of time s) at time t, if the command it is about to send
    (valid until `until`) is its last: its pending commands, those sent before that may still act, are a
    speed vp and the time ep until which they may act at full speed (their until + eps + ramp / 2: the ramp is
    no faster than a linear one to a stop); the new one arrives at some a in [t, until + eps] (later, it has
    expired and the drive refuses it) and replaces them within `switch` seconds."""

    def __init__(self, s: float, t: float, until: float, vp: float, ep: float, wp: float = 0.0,
                 ramp: float = RAMP_S, switch: float = 0.0, eps: float = CLOCK_SKEW_S) -> None:
        self.s, self.t, self.until, self.vp, self.ep, self.wp = s, t, until, vp, max(ep, s), wp
        self.ramp, self.switch, self.eps = ramp, switch, eps
        self.end = max(ep + ramp / 2.0, until + eps + ramp)  # every motion of this robot is over by then
        arrive = until + eps
        # the arrival times where the bound's pieces meet (it is concave in a: the largest is at one of these)
        self._at = sorted({t, arrive, min(arrive, max(t, self.ep - switch))})

    def _pieces(self) -> list[tuple[float, float]]:
        """(P, Q) per arrival time a: the reach is P + |v| Q (the pending motion until the new command takes
        over, then the new one's to its end)."""
        s, vp, ep = self.s, self.vp, self.ep
        q_end = self.until + self.eps + self.ramp / 2.0
        return [(vp * min(ep - s, a - s + self.switch), q_end - a) for a in self._at]

    def reach(self, u: float) -> float:
        """The most the robot moves from p [m] if the new command (speed |v| = u) is its last."""
        out = self.vp * (self.ep - self.s)  # the new one never arrives: the pending ones run to their end
        for p, q in self._pieces():
            out = max(out, p + u * q)
        return out

    def limit(self, x: float, y: float, hx: float, hy: float, w: float,
              bodies: Iterable[tuple[float, float, float, float]], V: float,
              unknown: float = math.inf) -> tuple[float, int]:
        """The largest |v| [m/s] the invariant allows (0: stand), and why (FREE, or the kind of what held it).

        (hx, hy): the unit direction the robot would move in (its heading, reversed for v < 0); w: the command's
        turn rate [rad/s]; bodies: (bx, by, contact, m) each, m the most the body can be from (bx, by) until
        self.end (motion_bound; 0 for an obstacle); unknown: the speed [m/s] the robots it has not heard allow
        (unheard_speed), inf for no bound.
        A body the robot moves away from (every point where the body can be, grown by the robot's own pending
        motion, lies behind it, with room for every turn it can make meanwhile) sets no limit: its distance to every
        point where that body can be only grows."""
        pieces = self._pieces()
        settled = self.vp * (self.ep - self.s)
        start = self.vp * (self.until + self.eps + self.switch - self.s)  # how far the pending motion may carry it
        turn = abs(w) * (self.end - self.s) + abs(self.wp) * (self.until + self.eps - self.s)
        far = self.reach(V) + MARGIN  # a body with more room than this cannot hold the robot back
        best, why = math.inf, FREE
        for bx, by, contact, m in bodies:
            dx, dy = x - bx, y - by
            d2 = dx * dx + dy * dy
            near = far + contact + m
            if d2 >= near * near:
                continue
            l = math.sqrt(d2)
            room = l - contact - m - MARGIN  # what the robot's own motion may take
            if room >= settled:
                cap = _cap(pieces, room)
                if cap >= best:
                    continue
            else:
                cap = 0.0
            # it may move away from the body instead, whatever its speed: from every point where the body can be
            # and every point its pending motion can take it to (no contact distance: moving away closes on nothing)
            rho = m + start + MARGIN
            if l > rho and turn < TURN_MAX and hx * dx + hy * dy > l * math.cos(math.acos(rho / l) - turn):
                continue
            best = cap
            why = BODY if cap > 0.0 else AWAY_ONLY
        if unknown < best:
            best, why = unknown, UNKNOWN
        return max(0.0, best), why


def unheard_speed(hear: float, contact: float, delay: float, reservation: float) -> float:
    """The speed [m/s] that keeps a robot clear of one it has not heard: a robot within `hear` of it is heard
    within `delay` (the information delay), and each robot may go on for its `reservation` (its command's
    validity and ramp) before it reacts; two robots that each keep to this speed can close at most
    hear - contact before one knows of the other (and that one's rule then keeps it clear). Never 0: a lone robot
    with old news is slowed, not frozen."""
    return max(0.0, hear - contact) / (2.0 * max(1e-6, delay + reservation))


def _cap(pieces: list[tuple[float, float]], room: float) -> float:
    """The largest u with P + u Q <= room for every piece (the pending motion alone fits: checked by the caller)."""
    cap = math.inf
    for p, q in pieces:
        if q > 0.0:
            cap = min(cap, (room - p) / q)
        elif p > room:
            return 0.0
    return max(0.0, cap)
