"""The start of a run: a world (or a referee) waits until the leader and every robot are alive.

    wait_ready(missing, wake, monotonic, timeout_s, stop)   # NotReady names who never came

The wait ends timeout_s after the last process came alive, not after it began: `swarm up` starts a big swarm's
robots in waves (swarm.launch.capacity.Waves), and a swarm that keeps coming up is not stuck.
"""

from __future__ import annotations

import threading
from typing import Callable
from swarm.core.errors import SwarmError


class NotReady(SwarmError, RuntimeError):
    """Some processes did not come up in time; `missing` names them."""

    def __init__(self, missing: list[str], timeout_s: float):
        self.missing = missing
        shown = ", ".join(missing[:12]) + (f" and {len(missing) - 12} more" if len(missing) > 12 else "")
        super().__init__(f"not alive after {timeout_s:g} s: {shown}")


def wait_ready(missing: Callable[[], list[str]], wake: Callable[[float], object], monotonic: Callable[[], float],
               timeout_s: float, stop: threading.Event | None = None) -> None:
    """Return once missing() is empty. wake(s) blocks up to s seconds or until something came; InterruptedError
    when stop is set; NotReady when timeout_s passed with no process newly alive."""
    end, left_count = monotonic() + timeout_s, -1
    while True:
        gone = missing()
        if not gone:
            return
        if stop is not None and stop.is_set():
            raise InterruptedError
        if left_count < 0 or len(gone) < left_count:  # progress: the wait starts again
            left_count, end = len(gone), monotonic() + timeout_s
        left = end - monotonic()
        if left <= 0:
            raise NotReady(gone, timeout_s)
        wake(min(left, 0.2))
