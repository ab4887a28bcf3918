"""Windows, not "newest wins": how a receiver adopts a sender's time and sequence number.

    w = new(t_span=2.0, seq_span=101)      # compiled where it was built, else Window
    w.check(t, seq)      # -> OK, DUPLICATE, STALE or JUMP; only OK moves the window forward
    w.reset()            # the sender's liveliness token is new, or a new run started
    Window(t_span, seq_span, dt=0.02)   # lock-step: t must also be seq's tick time, seq x dt (else FORGED)

A message from a sender is adopted only if it moves forward from what the receiver has from that
sender, and not too far: seq in (last, last + seq_span] and t in [last_t, last_t + t_span]. One
message with seq 2^53 - 1 or t = 1e9 would otherwise win forever (every later, true message looks
old). The first message after a reset anchors the window. A refused jump is counted as bad, an
older message as stale, the same (t, seq) again as a duplicate; none of them is adopted, so a
lock-step barrier never advances on a refused message. The spans: t_span = max(2 s, 2 x the
watchdog), seq_span = the number of control periods in t_span (docs/protocol.md).

In lock-step a message's t is its tick's time, seq x dt: a window made with the tick dt refuses any other
(FORGED, counted as bad, never adopted, never a candidate to re-anchor the window). A forged state with the
next seq and t = 1e8 would otherwise be adopted, and every true state after it refused as older.
"""

from __future__ import annotations

import math
import os
from typing import Any, cast

OK = "ok"
DUPLICATE = "duplicate"
STALE = "stale"
JUMP = "jump"
FORGED = "forged"

TICK_EPS = 1e-6  # s: how far a lock-step message's t may be from seq x dt (roundings of k x dt)


def spans(dt: float, watchdog: float) -> tuple[float, int]:
    """(t_span [s], seq_span) for a control period dt [s] and a watchdog [s]."""
    t_span = max(2.0, 2.0 * watchdog)
    return t_span, int(math.ceil(t_span / dt)) + 1


CONFIRM = 3  # jumped messages in a row, each in the window of the one before, that re-anchor the window


class Window:
    """One sender's forward window (not thread-safe: the caller holds its lock)."""

    __slots__ = ("t_span", "seq_span", "dt", "t", "seq", "_cand", "_run")

    def __init__(self, t_span: float, seq_span: int, dt: float = 0.0) -> None:
        self.t_span, self.seq_span = t_span, seq_span
        self.dt = float(dt)  # lock-step: the tick; 0: t and seq are not tied
        self.t: float | None = None
        self.seq = -1
        self._cand: tuple[float, int] | None = None  # the last refused jump
        self._run = 0  # jumps in a row that agree with each other

    def reset(self) -> None:
        self.t, self.seq, self._cand, self._run = None, -1, None, 0

    def _verdict(self, t: float, seq: int, t0: float, seq0: int) -> str:
        if seq == seq0 and t == t0:
            return DUPLICATE
        if seq <= seq0 or t < t0:
            return STALE
        if seq > seq0 + self.seq_span or t > t0 + self.t_span:
            return JUMP
        return OK

    def peek(self, t: float, seq: int) -> str:
        """What check() would say about a message, without adopting it."""
        if self.dt and not abs(t - seq * self.dt) <= TICK_EPS:
            return FORGED
        return OK if self.t is None else self._verdict(t, seq, self.t, self.seq)

    def take(self, t: float, seq: int) -> bool:
        """check()'s common case alone: adopt (t, seq) and say True if it moves the anchored window forward within
        its spans (and is its tick's time in lock-step); else False, with nothing changed (check() decides). The
        compiled loops call it for a window of this class (swarm/proto/_wire_window.c, handed over by
        swarm.proto.protocol)."""
        t0 = self.t
        if t0 is not None and self.seq < seq <= self.seq + self.seq_span and t0 <= t <= t0 + self.t_span and \
                (not self.dt or abs(t - seq * self.dt) <= TICK_EPS):
            self.t, self.seq, self._cand, self._run = t, seq, None, 0  # _verdict's OK
            return True
        return False

    def check(self, t: float, seq: int) -> str:
        """Adopt (t, seq) if it is in the window (OK), else say why not."""
        if self.take(t, seq):  # the common case
            return OK
        v = self.peek(t, seq)
        if v in (JUMP, STALE):
            c = self._cand
            self._run = self._run + 1 if c is not None and self._verdict(t, seq, c[0], c[1]) == OK else 1
            self._cand = (t, seq)
            if self._run < CONFIRM:
                return v
            v = OK  # the sender did jump (or the window was anchored by a crafted message): follow it
        if v == OK:
            self.t, self.seq, self._cand, self._run = t, seq, None, 0
        return v


def by_seq_alone(w: Window, t: float, seq: int) -> bool:
    """Whether the window refuses (t, seq) for its seq alone, its t within the window's span forward: a jump or a
    step back that a sender's counter never makes while its clock runs on (a sender that stalls or whose clock
    steps jumps in t; one that restarts has a new token, which resets the window). Such a message never counts
    toward re-anchoring: a forger's run of them, seq 10^12 at the time of now, would pin the window by seq."""
    t0 = w.t
    return t0 is not None and t0 <= t <= t0 + w.t_span and w.peek(t, seq) in (JUMP, STALE)


def epoch_offset(clock: Any, wall: float) -> float:
    """How far [s] a real-time clock message's epoch puts its time from this machine's unix time `wall`:
    epoch + t / speed - wall. The run's epoch is taken once, from the first clock: one far off (a forged epoch)
    would put every true message of the run outside the receiver's window, and the swarm would stand still."""
    return float(clock.epoch + clock.t / max(float(clock.speed), 1e-9) - wall)


def epoch_refusal(off: float) -> str:
    return (f"a clock whose epoch puts its time {off:+.4g} s from this machine's clock, more than the window's span "
            "(a forged epoch, or machines' clocks out of sync: keep them on NTP)")


def outside(w: Window, t: float, seq: int, ahead: bool) -> str:
    """The verdict on a message that the receiver's own clock puts outside what its sender can have sent by now:
    ahead of it (a jump), or behind anything still of use (stale in an empty window; else the window's own
    verdict, adopted only when that is OK). Either way it never counts toward re-anchoring the window: a run of such messages is a forger's, not a
    sender that jumped, and three of them would otherwise pin the window where the forger wants it
    (docs/protocol.md, "Windows")."""
    if ahead:
        return JUMP
    if w.t is None:  # nothing to be behind of but the receiver's clock: it anchors no window
        return STALE
    v = w.peek(t, seq)
    return w.check(t, seq) if v == OK else v


ESTOP_SPAN_S = 30.0  # s: how far ahead of a receiver's clock an operator's may be (StopOrder), and so how long one
# forged engage far ahead may hold the stop against the operator's release; far wider than t_span, since an
# operator's laptop is not a robot: a release refused for a clock 3 s off would leave the swarm stopped


class StopOrder:
    """The emergency stop's order as one receiver takes it (the robots and the world; docs/protocol.md, "Windows").
    Messages are ordered by (t, seq), t the operator's unix time. An engage is always obeyed; a release only when
    it comes after every engage taken. Judged on the receiver's own unix clock first: a t more than `span` ahead
    of it is no operator's (operators keep their clocks on NTP): it is counted bad, a release of it is refused,
    and an engage of it is obeyed but marks the order only up to now + span. So no engage, however far ahead
    its t or seq, holds the stop against the operator's release longer than span seconds after it came."""

    __slots__ = ("span", "mark")

    def __init__(self, span: float = ESTOP_SPAN_S) -> None:
        self.span = span
        self.mark: tuple[float, int] = (-math.inf, -1)  # the latest engage taken: (t, seq)

    def take(self, engaged: bool, t: float, seq: int, now: float) -> tuple[bool, str]:
        """(act, verdict): act says to apply the message (an engage: always); verdict is OK, or JUMP (t ahead of
        the receiver's clock: bad) or STALE (a release no later than an engage taken)."""
        limit = now + self.span
        if engaged:
            self.mark = max(self.mark, (t, seq) if t <= limit else (limit, 2**62))
            return True, OK if t <= limit else JUMP
        if t > limit:
            return False, JUMP
        if (t, seq) <= self.mark:
            return False, STALE
        return True, OK


try:  # the compiled loops, this window among them (swarm/proto/_wire_window.c), where they were built: new() makes
    # one of those; swarm.proto.protocol takes the module from here (one place decides it)
    from swarm.proto import _wire as _compiled
except ImportError:
    _compiled = None
if os.environ.get("SWARM_PURE_PYTHON"):
    _compiled = None

COMPILED = _compiled is not None
LOOPS: Any = _compiled  # the module of the compiled loops (swarm.proto._wire), or None: swarm.proto.protocol's _wire


def new(t_span: float, seq_span: int, dt: float = 0.0) -> Window:
    """A sender's window: the compiled one where it was built (the robots' loops take a state's window from it
    without a Python call), else this module's Window; the same rules either way (tests/protocol/test_window.py)."""
    if _compiled is not None:
        return cast(Window, _compiled.Window(t_span, seq_span, dt))
    return Window(t_span, seq_span, dt)
