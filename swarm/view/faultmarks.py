"""What the fault events say about each robot now: killed (dead), hung, cut off by a partition.

    marks = FaultMarks(n)                        # live: fed with world/events as they come
    marks.apply(t, "kill", (3,))                 # True: it was new and named robots of the run
    marks.killed, marks.hung, marks.cut          # (n,) bool, rows by robot id

    marks = FaultMarks(n, faults.timeline(scn.faults, n))   # `swarm sim --viz`, a late viewer, old recordings
    marks.advance(t)                             # every event of the schedule at or before t [s]

The events are the protocol's `event` kind (docs/protocol.md): kill and restart, hang and resume of
the robots named, partition and partition_end (robots: those cut off from the world's group), and
signal (what `swarm up`'s supervisor did: the scheduled event already says it, so a signal changes
nothing here). The same event told twice (by the bus and by the schedule a late viewer starts from)
counts once. An event naming a robot outside 0..n-1 changes nothing and is counted in `ignored`
(the caller drops it as a bad message). Pure: no I/O, no clock; the viewer, `swarm sim --viz` and
replay all colour their robots from it.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from swarm.core.faultgen import TIME_EPS

# event -> (which flag, value it sets)
_EFFECTS = {"kill": ("killed", True), "restart": ("killed", False), "hang": ("hung", True),
            "resume": ("hung", False), "partition": ("cut", True), "partition_end": ("cut", False)}
STATE_EVENTS = tuple(_EFFECTS)  # the events that change a robot's marks (signal does not)


class FaultMarks:
    """Per-robot fault flags from fault events (see the module docstring). Not thread-safe."""

    def __init__(self, n: int, timeline: Sequence[tuple[float, str, tuple[int, ...], str]] = ()):
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        self.n = n
        self.timeline = list(timeline)  # (t [s], event, robots, detail), in time order
        self.ignored = 0  # events naming a robot outside 0..n-1
        self.reset()

    def reset(self) -> None:
        """Forget every event (a new run); the timeline starts over."""
        self.killed = np.zeros(self.n, bool)
        self.hung = np.zeros(self.n, bool)
        self.cut = np.zeros(self.n, bool)
        self._seen: set[tuple[float, str, tuple[int, ...]]] = set()
        self._next = 0  # timeline entries applied
        self._at = -np.inf  # the latest time advance() reached

    @property
    def any(self) -> bool:
        """Some robot is dead, hung or cut off now."""
        return bool(self.killed.any() or self.hung.any() or self.cut.any())

    def apply(self, t: float, event: str, robots: Iterable[int]) -> bool:
        """Apply one event at t [s]; True if it changed what is known (new, and about robots of the run)."""
        robots = tuple(int(i) for i in robots)
        if any(i < 0 or i >= self.n for i in robots):
            self.ignored += 1
            return False
        effect = _EFFECTS.get(event)
        if effect is None:  # a signal: the scheduled event that goes with it says what it did
            return False
        key = (round(float(t), 9), event, robots)
        if key in self._seen:
            return False
        self._seen.add(key)
        flag, value = effect
        getattr(self, flag)[list(robots)] = value
        return True

    def advance(self, t: float) -> None:
        """Apply the timeline's events at or before t [s] (an event at te happens at the first tick at or
        after te: a sample at t shows it when te <= t). A t before the last one starts over."""
        if t < self._at - TIME_EPS:
            self.reset()
        self._at = t
        while self._next < len(self.timeline) and self.timeline[self._next][0] <= t + TIME_EPS:
            te, event, robots, _detail = self.timeline[self._next]
            self.apply(te, event, robots)
            self._next += 1


def robot_list(ids: Iterable[int]) -> str:
    """Robot ids as short text: runs of consecutive ids as ranges, "0-4, 7, 9-11"; "–" for none."""
    ids = sorted(set(int(i) for i in ids))
    if not ids:
        return "–"
    out, start, prev = [], ids[0], ids[0]
    for i in ids[1:] + [None]:
        if i is not None and i == prev + 1:
            prev = i
            continue
        out.append(str(start) if start == prev else f"{start}-{prev}" if prev > start + 1 else f"{start}, {prev}")
        if i is not None:
            start = prev = i
    return ", ".join(out)
