"""Time as an argument: every process that keeps time takes a clock, so a test can hand it a fake one.

    clock.time()                 # unix time [s]: what real-time processes share (the world's epoch)
    clock.monotonic()            # [s] for deadlines and ages on this machine
    clock.wait(event, timeout_s) # block until event is set or timeout_s passes; True if it was set

WallClock is the real one. FakeClock never blocks: wait() advances its time by the timeout
(unless the event is already set), so a loop driven by it runs as fast as the CPU allows and
sees exactly the times a test decides. Lock-step needs no clock for its logic (the world's tick
is the time); only its timeouts do.
"""

from __future__ import annotations

import threading
import time


class WallClock:
    """The machine's clocks."""

    def time(self) -> float:
        return time.time()

    def monotonic(self) -> float:
        return time.monotonic()

    def wait(self, event: threading.Event, timeout_s: float | None) -> bool:
        return event.wait(timeout_s)


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


WALL = WallClock()
