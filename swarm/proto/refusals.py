"""Counting refused messages: a process's own (BadMessages, which also logs them) and the counts the robots
claim in their statuses (Claims, each bounded by what that robot can have seen)."""

from __future__ import annotations

import logging
import math
import time
from typing import TYPE_CHECKING

from swarm.proto.messages import ProtocolError

if TYPE_CHECKING:
    from collections.abc import ValuesView


REFUSALS_PER_S_MAX = 1_000_000  # messages a process can refuse in a second of wall time (each costs it a
# microsecond or more of decoding): the most a robot's own `bad` counter can have grown by in that time


class Claims:
    """What the robots say they refused (their statuses' `bad`), each bounded by what that robot can have
    seen: its counter grows at most REFUSALS_PER_S_MAX a second of the receiver's wall time since the robot's
    previous status (plus one second), so one status claiming 2^53 does not reach the metrics. A lower count
    is taken as is (a restarted process counts from zero again). `total` is what the run reports."""

    def __init__(self) -> None:
        self.by_robot: dict[int, int] = {}
        self._mono: dict[int, float] = {}
        self.capped = 0  # statuses whose claim was cut to the bound

    def take(self, i: int, bad: int, mono: float) -> None:
        prev, last = self.by_robot.get(i, 0), self._mono.get(i)
        bound = prev + int(REFUSALS_PER_S_MAX * ((0.0 if last is None else max(0.0, mono - last)) + 1.0))
        if bad > bound:
            self.capped += 1
            bad = bound
        self.by_robot[i], self._mono[i] = bad, mono

    def values(self) -> ValuesView[int]:
        return self.by_robot.values()

    @property
    def total(self) -> int:
        return sum(self.by_robot.values())


class BadMessages:
    """Counts refused messages and logs them, at most one line per `every` seconds. A message is counted once
    by each process that refuses it (a state refused by the 6 robots that hear it counts 6 in a run's
    `bad_messages`, which adds the robots' own counts to the world's).

    count: bad messages (malformed, out of bounds, a jump beyond a sender's window, a key that names
    no robot of the scenario); stale: older than what the receiver has from that sender (not
    adopted); duplicates: the same (t, seq) again. Only `count` is what a run reports as bad."""

    def __init__(self, log: logging.Logger, every: float = 5.0):
        self.log = log
        self.every = every
        self.count = 0
        self.stale = 0
        self.duplicates = 0
        self._last = -math.inf
        self._quiet = 0

    def reject(self, key: str, err: Exception) -> None:
        self.count += 1
        now = time.monotonic()
        if now - self._last >= self.every:
            more = f" ({self._quiet} more since the last report)" if self._quiet else ""
            self.log.warning("dropped a bad message on %s: %s%s", key, err, more)
            self._last = now
            self._quiet = 0
        else:
            self._quiet += 1

    def verdict(self, key: str, verdict: str, what: str = "") -> bool:
        """Account for a window's verdict (swarm.proto.window); True if the message is to be adopted."""
        if verdict == "ok":
            return True
        if verdict == "stale":
            self.stale += 1
        elif verdict == "duplicate":
            self.duplicates += 1
        elif verdict == "forged":
            self.reject(key, ProtocolError(f"{what or 'seq or t'}: lock-step, and t is not seq x dt (its tick's time)"))
        else:
            self.reject(key, ProtocolError(f"{what or 'seq or t'} jumps beyond the sender's window"))
        return False
