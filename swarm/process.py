"""What a swarm process does to itself, whoever started it: die with the launcher that started it, name its threads
for the operating system, settle its heap before its run loop. Below agents/ and world/, which use it, and below
swarm.launch, which starts the processes (swarm.launch.child stops them)."""

from __future__ import annotations

import ctypes
import os
import signal

PARENT_ENV = "SWARM_PARENT_PID"  # set by the supervisor in every child's environment


def die_with_parent() -> None:
    """In a child started by the launcher: get SIGTERM when the launcher dies, however it dies.

    Linux's PR_SET_PDEATHSIG; the check after it closes the race where the parent died first."""
    parent = os.environ.get(PARENT_ENV)
    if not parent:
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):  # not Linux: the launcher's own cleanup has to do
        return
    if os.getppid() != int(parent):
        os.kill(os.getpid(), signal.SIGTERM)


def name_thread(name: str) -> None:
    """This thread's name for the operating system (`top -H`, perf, /proc/PID/task/TID/comm), at most 15
    bytes: Python's own threads are otherwise all named after the process. Linux's PR_SET_NAME; a no-op
    elsewhere."""
    try:
        ctypes.CDLL(None).prctl(15, name.encode()[:15], 0, 0, 0)  # PR_SET_NAME = 15
    except (OSError, AttributeError):
        pass


def settle_heap() -> None:
    """Before a process's run loop: collect once, then move everything alive (imports, sessions,
    configuration) out of the garbage collector's sight (gc.freeze). A full collection of a robot
    process costs about 3 ms (13 000 objects after its imports); frozen, the ones that still come
    now and then cost microseconds, so they do not show up in the control round trip."""
    import gc

    gc.collect()
    gc.freeze()
