"""A process's presence on the bus: its liveliness token, and its proc queryable that says who it is.

    handle = presence.announce(bus, "lab", "robot", 3, run=lambda: agent.cfg.run)
    ...
    handle.close()  # both go

The token (`alive/<role>/<id>`) says that the process is there; the queryable (`proc/<role>/<id>`) answers
a `Proc` message: host, pid, start time, the run it is in and the swarm version (`swarm ps` asks them all).
"""

from __future__ import annotations

import functools
import os
import socket
import time
from typing import Callable

from swarm.proto import keys, protocol

STARTED = time.time()  # this process's start, near enough (the module loads at start)


@functools.lru_cache(maxsize=1)
def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("swarm")
    except metadata.PackageNotFoundError:
        return "unknown"


def describe(role: str, i: int = 0, run: str = "") -> protocol.Proc:
    """This process, as its proc queryable says it."""
    host = socket.gethostname()[:protocol.MAX_TEXT]
    return protocol.Proc(role=role, id=i, host=host, pid=os.getpid(), started=STARTED, run=run[:protocol.MAX_TEXT],
                         version=_version()[:protocol.MAX_TEXT])


class _Presence:
    def __init__(self, handles: list) -> None:
        self._handles = handles

    def close(self) -> None:
        while self._handles:
            self._handles.pop().close()


def serve(bus, fleet: str, role: str, i: int = 0, run: Callable[[], str] | None = None):
    """This process's proc queryable alone (a robot's process serves it from its start; its token comes with each
    run's agent): it answers the run the process is in now, `run()`, or "" without one."""

    def answer(_asked: str) -> bytes:
        return protocol.encode(describe(role, i, (run() if run is not None else "") or ""))

    return bus.serve(keys.proc(fleet, role, i), answer)


def announce(bus, fleet: str, role: str, i: int = 0, run: Callable[[], str] | None = None) -> _Presence:
    """Declare this process on the bus: its proc queryable (serve) and its liveliness token. Returns one handle
    that withdraws both."""
    return _Presence([serve(bus, fleet, role, i, run), bus.token(keys.alive(fleet, role, i))])
