"""What every process `swarm up` starts does first: die with the launcher, however it dies."""

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


def stop_group(proc, term_s: float = 10.0, descendants: bool = False) -> None:
    """Stop a child that leads its own process group (started with process_group=0): SIGTERM to the group,
    and if the child has not ended within term_s, SIGKILL to it (with descendants, first to the group of
    every process it started: swarm up's children lead groups of their own), then reap it."""
    import subprocess

    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
    try:
        proc.wait(term_s)
        return
    except subprocess.TimeoutExpired:
        pass
    if descendants:
        import psutil

        try:
            left = psutil.Process(proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            left = []
        for p in left:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        proc.wait(5.0)
    except subprocess.TimeoutExpired:
        pass
