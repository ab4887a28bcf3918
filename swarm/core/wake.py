"""Wake: threading.Event's set / is_set / clear / wait, on one raw lock.

    wake = Wake()
    wake.set()             # any thread (a bus callback): the loop's next wait() returns at once
    wake.wait(timeout_s)   # the loop: block until set (or timeout_s); True if it is set
    wake.clear()           # the loop, after a wait: take what is new under its own lock, then wait again

A bus callback sets it to wake a process's run loop (a robot's, the world's). threading.Event does the
same with a Condition written in Python: a set() runs five Python frames and a wait() allocates a lock
for each call. With about two of each a robot's lock-step tick on zenoh's threads, that was about a
twentieth of its CPU (docs/performance.md, "Callbacks on zenoh's threads, and the world's commands"). Here a set() is one attribute store and a lock release.

The lock is a token: released (available) when a set() may not have been seen yet. wait() returns as
soon as the flag is set, or when it can take the token (it puts it back: a set stays set until clear()).
A set() racing with clear() can leave a token without the flag: the next wait() then returns False at
once, and its clear() takes the token. Callers re-check their state after every wait (as with an Event),
so an early return costs one look; a set() is never lost.
"""

from __future__ import annotations

import _thread
from time import thread_time
from typing import Callable


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


class Runner:
    """Work run on the thread that made it due, instead of waking a loop thread for it.

        runner = Runner(work, wake)  # wake: the loop's Wake (it learns of an error there)
        runner.set()                 # any thread: work() runs now, here, unless another thread runs it
        runner.stop(timeout_s)       # no work() from now on (waits for one under way)

    A lock-step robot's tick (agents.robot): the message that makes the tick due (its pose, the last state
    it waited for) comes on zenoh's thread; handing it to a loop thread costs a thread wake-up, its cold
    caches and a GIL hand-over twice a tick in each of 37 processes on 2 cores (docs/performance.md, "A tick on the thread its message came on").

    work() never runs on two threads at once, and no set() is lost: a set() that finds work() under way on
    another thread leaves a mark (`_again`), and that thread runs work() once more after it, before it
    leaves. An exception in work() is kept in `error` (the first) and sets `wake`: the loop raises it.
    `cpu_s` sums the thread CPU time spent in work()."""

    __slots__ = ("wake", "_busy", "_again", "_work", "error", "cpu_s")

    def __init__(self, work: Callable[[], object], wake: Wake) -> None:
        self.wake = wake
        self._busy = _thread.allocate_lock()
        self._again = False
        self._work = work
        self.error: BaseException | None = None
        self.cpu_s = 0.0

    def set(self) -> None:
        self._again = True
        busy = self._busy
        # the mark is read after the release: a set() that failed to take the lock while work() ran is seen
        while self._again and busy.acquire(False):
            try:
                self._again = False
                c0 = thread_time()
                try:
                    self._work()
                except BaseException as e:  # on a thread that is not the loop's: the loop raises it
                    if self.error is None:
                        self.error = e
                    self.wake.set()
                self.cpu_s += thread_time() - c0
            finally:
                busy.release()

    def stop(self, timeout_s: float) -> bool:
        """No work() from now on: take the lock for good (after one under way, waiting up to timeout_s).
        False if work() was still under way then (it is the last: any later set() runs nothing)."""
        self._work = _nothing
        return self._busy.acquire(True, timeout_s)


def _nothing() -> None:
    pass
