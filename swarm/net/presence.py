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
import queue
import socket
import time
from typing import Any, Callable

from swarm.proto import keys, protocol
from swarm.proto.protocol import ProtocolError

ROLE_ORDER = ("router", "launcher", "world", "leader", "robot", "viz", "recorder")
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


QUIET_S = 0.3  # tokens stop coming this long: the listing is whole (bounded by --wait)


def _expr(fleet: str | None, what: str) -> str:
    """The key expression of every `what` (alive, proc) key of one fleet, or of every fleet."""
    if fleet is None:
        return f"{keys.PREFIX}/*/{what}/*/*"
    return keys.alive_any(fleet) if what == "alive" else keys.proc_any(fleet)


def collect(bus, fleet: str | None, wait_s: float, stop=None) -> list[dict[str, Any]]:
    """Every live process of `fleet` (None: of every fleet) on bus: its liveliness token (`alive`: a robot's
    process waiting for a run has none yet), with what its proc queryable says (host, pid, started, run, version;
    None where it did not answer: a process without one). Sorted by fleet, role, id."""
    tokens: queue.Queue = queue.Queue()
    handle = bus.watch_alive(_expr(fleet, "alive"), lambda key, up: tokens.put((key, up)))
    found: dict[tuple[str, str, int], bool] = {}
    end = time.monotonic() + wait_s
    try:
        while True:
            left = end - time.monotonic()
            if left <= 0 or (stop is not None and stop.is_set()):
                break
            try:
                key, up = tokens.get(timeout=min(left, QUIET_S))
            except queue.Empty:
                if found:
                    break  # nothing new for a while: every token there was has come
                continue
            parsed = keys.parse(key)
            if parsed is not None and parsed.kind == "alive" and parsed.role is not None and parsed.id is not None:
                found[(parsed.fleet, parsed.role, parsed.id)] = up
    finally:
        handle.close()
    procs: dict[tuple[str, str, int], protocol.Proc] = {}
    p: protocol.Proc | None
    for key, payload in bus.query(_expr(fleet, "proc"), timeout_s=max(0.5, wait_s)):
        parsed = keys.parse(key)
        try:
            p = protocol.decode(payload, "proc")
        except ProtocolError:
            continue  # a reply that does not decode says nothing
        if parsed is not None and parsed.kind == "proc" and (p.role, p.id) == (parsed.role, parsed.id):
            procs[(parsed.fleet, p.role, p.id)] = p
    rows: list[dict[str, Any]] = []
    for who in {k for k, up in found.items() if up} | set(procs):
        f, role, i = who
        p = procs.get(who)
        rows.append({"fleet": f, "role": role, "id": i, "alive": found.get(who, False),
                     "host": p.host if p else None, "pid": p.pid if p else None,
                     "started": p.started if p else None, "run": (p.run or None) if p else None,
                     "version": p.version if p else None})
    rank = {r: n for n, r in enumerate(ROLE_ORDER)}
    rows.sort(key=lambda r: (r["fleet"], rank.get(r["role"], len(rank)), r["id"]))
    return rows


def why_no_world(bus, fleet: str, me: tuple[str, int] | None = None, wait_s: float = 1.0) -> str:
    """What is on the router when fleet `fleet` has no world answering: "no process of fleet 'lab' is on this
    router; fleets there: default (world, leader, 7 robots)", or what of `fleet` is there besides `me` (role, id).
    For the line a process waiting for a run says after a few seconds (routers serve every fleet and are left out;
    fleets a --secure identity may not see are not named)."""
    rows = [r for r in collect(bus, None, wait_s) if r["role"] != "router" and (r["role"], r["id"]) != me]

    def roles(f: str) -> str:
        mine = [r for r in rows if r["fleet"] == f]
        robots = sum(1 for r in mine if r["role"] == "robot")
        named = sorted({r["role"] for r in mine} - {"robot"}, key=lambda r: ROLE_ORDER.index(r) if r in ROLE_ORDER else 99)
        return ", ".join(named + ([f"{robots} robot{'s' if robots != 1 else ''}"] if robots else []))
    others = sorted({r["fleet"] for r in rows} - {fleet})
    there = f"; fleets there: {'; '.join(f'{f} ({roles(f)})' for f in others)} (--fleet NAME joins one)" if others else ""
    if any(r["fleet"] == fleet and r["role"] == "world" for r in rows):
        return (f"fleet '{fleet}' has a world on this router that did not answer (busy, still starting, or an access "
                "rule: its configuration and run keys)")
    if any(r["fleet"] == fleet for r in rows):
        return f"fleet '{fleet}' has no world on this router (there: {roles(fleet)}){there}"
    return f"no world of fleet '{fleet}' on this router{there}"
