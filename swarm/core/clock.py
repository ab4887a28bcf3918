"""Time as an argument: every process that keeps time takes a clock, so a test can hand it a fake one.

    clock.time()                 # unix time [s]: what real-time processes share (the world's epoch)
    clock.monotonic()            # [s] for deadlines and ages on this machine
    clock.wait(event, timeout_s) # block until event is set or timeout_s passes; True if it was set
    clock.anchor()               # at a run's start: re-read the system clock; returns the step since
    clock.step_s()               # how far the system clock has stepped away from time() [s]

WallClock is the real one. Its time() does not jump when the system clock is stepped: it is the
system clock read at the last anchor(), advanced by the monotonic clock since. NTP's slewing moves
both clocks alike and so passes through; a step does not (NTP stepping a clock that booted wrong, a
virtual machine resumed after a pause with its wall clock then set forward). Without this a step of
30 s in the middle of a real-time run moved the whole swarm's time 30 s ahead in one tick: every
robot's reference, pose and schedule was suddenly 30 s late. Each process anchors when a run
begins, so a long-lived robot takes up a step made between runs, and says at a run's end if the
system clock stepped during it.

FakeClock never blocks: wait() advances its time by the timeout (unless the event is already set),
so a loop driven by it runs as fast as the CPU allows and sees exactly the times a test decides.
Lock-step needs no clock for its logic (the world's tick is the time); only its timeouts do.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:
    import logging

STEP_WARN_S = 0.1  # a step of the system clock larger than this during a run is said in the process's log


class WallClock:
    """The machine's clocks; time() is step-free (see the module's docstring).

    system and mono: the sources (time.time and time.monotonic; a test passes its own)."""

    def __init__(self, system: Callable[[], float] = time.time, mono: Callable[[], float] = time.monotonic) -> None:
        self._system, self._mono = system, mono
        self.machine_monotonic = mono is time.monotonic  # monotonic() is CLOCK_MONOTONIC (a C timer may wait on it)
        self._anchor = (system(), mono())  # one tuple, replaced whole: a reader on another thread never sees half

    def time(self) -> float:
        wall0, mono0 = self._anchor
        return wall0 + (self._mono() - mono0)

    def monotonic(self) -> float:
        return self._mono()

    def wait(self, event: threading.Event, timeout_s: float | None) -> bool:
        return event.wait(timeout_s)

    def step_s(self) -> float:
        """How far the system clock is from time() [s]: 0 but for steps since the last anchor."""
        wall0, mono0 = self._anchor
        return self._system() - (wall0 + (self._mono() - mono0))

    def anchor(self) -> float:
        """Re-read the system clock (a run begins); returns the step taken up [s]."""
        step = self.step_s()
        self._anchor = (self._system(), self._mono())
        return step


class FakeClock:
    """A clock a test moves: time() = epoch + elapsed, monotonic() = elapsed."""

    def __init__(self, epoch: float = 1_000_000.0) -> None:
        self.epoch = epoch
        self.elapsed = 0.0
        self._lock = threading.Lock()

    def time(self) -> float:
        return self.epoch + self.elapsed

    def monotonic(self) -> float:
        return self.elapsed

    def advance(self, dt: float) -> None:
        with self._lock:
            self.elapsed += max(0.0, dt)

    def wait(self, event: threading.Event, timeout_s: float | None) -> bool:
        if event.is_set():
            return True
        if timeout_s is not None:
            self.advance(timeout_s)
        return event.is_set()

    def step_s(self) -> float:
        return 0.0  # a fake clock's system clock never steps

    def anchor(self) -> float:
        return 0.0


def said_step(clock: WallClock | FakeClock, log: logging.Logger, who: str, run: str) -> float:
    """At a run's end: log a warning if the system clock stepped during it (see the module's docstring);
    returns the step [s]."""
    step = clock.step_s()
    if abs(step) > STEP_WARN_S:
        log.warning("%s, run %s: the system clock stepped by %+.3f s during the run (an NTP step, or a virtual "
                    "machine paused and resumed); the run kept its time from the monotonic clock", who, run, step)
    return step


WALL = WallClock()
