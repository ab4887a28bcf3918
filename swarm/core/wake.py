"""Wake: threading.Event's set / is_set / clear / wait, on one raw lock.

    wake = Wake()
    wake.set()             # any thread (a bus callback): the loop's next wait() returns at once
    wake.wait(timeout_s)   # the loop: block until set (or timeout_s); True if it is set
    wake.clear()           # the loop, after a wait: take what is new under its own lock, then wait again

A bus callback sets it to wake a process's run loop (a robot's, the world's). threading.Event does the
same with a Condition written in Python: a set() runs five Python frames and a wait() allocates a lock
for each call. With about two of each a robot's lock-step tick on zenoh's threads, that was about a
twentieth of its CPU (docs/runtime.md). Here a set() is one attribute store and a lock release.

The lock is a token: released (available) when a set() may not have been seen yet. wait() returns as
soon as the flag is set, or when it can take the token (it puts it back: a set stays set until clear()).
A set() racing with clear() can leave a token without the flag: the next wait() then returns False at
once, and its clear() takes the token. Callers re-check their state after every wait (as with an Event),
so an early return costs one look; a set() is never lost.
"""

from __future__ import annotations

import _thread


class Wake:
    __slots__ = ("_flag", "_token")

    def __init__(self) -> None:
        self._flag = False
        self._token = _thread.allocate_lock()
        self._token.acquire()  # taken: nothing to see yet

    def set(self) -> None:
        self._flag = True
        try:
            self._token.release()
        except RuntimeError:  # already released: a set() not yet seen is there
            pass

    def is_set(self) -> bool:
        return self._flag

    def clear(self) -> None:
        self._flag = False
        self._token.acquire(False)

    def wait(self, timeout: float | None = None) -> bool:
        if self._flag:
            return True
        if self._token.acquire(True, -1 if timeout is None else max(0.0, timeout)):
            try:
                self._token.release()  # a set stays set until clear()
            except RuntimeError:  # a set() released it meanwhile
                pass
        return self._flag
