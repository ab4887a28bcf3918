"""`swarm ps`: the swarms on a router, and their live processes (from liveliness tokens and each process's
proc queryable: host, pid, age, run)."""

from __future__ import annotations

import json
import queue
import time

from swarm.cli.common import EXIT_OK, BadInput, StopEvent, fleet_of, open_bus
from swarm.proto import keys, protocol
from swarm.proto.protocol import ProtocolError

ROLE_ORDER = ("router", "launcher", "world", "leader", "robot", "viz", "recorder")
QUIET_S = 0.3  # tokens stop coming this long: the listing is whole (bounded by --wait)


def _expr(fleet: str | None, what: str) -> str:
    """The key expression of every `what` (alive, proc) key of one fleet, or of every fleet."""
    if fleet is None:
        return f"{keys.PREFIX}/*/{what}/*/*"
    return keys.alive_any(fleet) if what == "alive" else keys.proc_any(fleet)


def collect(bus, fleet: str | None, wait_s: float, stop=None) -> list[dict]:
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
            if parsed is not None and parsed.kind == "alive":
                found[(parsed.fleet, parsed.role, parsed.id)] = up
    finally:
        handle.close()
    procs: dict[tuple[str, str, int], protocol.Proc] = {}
    for key, payload in bus.query(_expr(fleet, "proc"), timeout_s=max(0.5, wait_s)):
        parsed = keys.parse(key)
        try:
            p = protocol.decode(payload, "proc")
        except ProtocolError:
            continue  # a reply that does not decode says nothing
        if parsed is not None and parsed.kind == "proc" and (p.role, p.id) == (parsed.role, parsed.id):
            procs[(parsed.fleet, p.role, p.id)] = p
    rows = []
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


def _age(started: float | None, now: float) -> str:
    if started is None:
        return "-"
    s = max(0, int(now - started))
    return f"{s}s" if s < 120 else f"{s // 60}m" if s < 7200 else f"{s // 3600}h"


def table(rows: list[dict], now: float) -> str:
    """The listing as aligned columns, one line per process."""
    head = ("FLEET", "ROLE", "ID", "HOST", "PID", "AGE", "RUN")
    lines = [head] + [(r["fleet"], r["role"], str(r["id"]), r["host"] or "-", str(r["pid"] or "-"),
                       _age(r["started"], now), r["run"] or ("-" if r["alive"] else "(waiting for a run)"))
                      for r in rows]
    widths = [max(len(line[c]) for line in lines) for c in range(len(head))]
    return "\n".join("  ".join(cell.ljust(w) for cell, w in zip(line, widths)).rstrip() for line in lines)


def cmd_ps(args, started: float) -> int:
    if args.wait <= 0:
        raise BadInput(f"--wait: must be > 0 seconds, got {args.wait:g}")
    fleet = None if args.fleet is None else fleet_of(args)
    if fleet is None and args.secure:
        raise BadInput("--secure: give --fleet (the fleet of the certificates; the access control is per fleet)")
    with StopEvent() as stop:
        if fleet is None:
            args.fleet = "default"  # open_bus names no fleet but a secure one
        bus = open_bus(args, timeout_s=3.0, stop=stop, role="operator")
        try:
            rows = collect(bus, fleet, args.wait, stop)
        finally:
            bus.close()
    now = time.time()
    if args.json:
        print(json.dumps(rows, indent=2))
        return EXIT_OK
    where = ", ".join(args.connect or ["tcp/127.0.0.1:7447"]) if not args.secure else f"the router of {args.secure}"
    if not rows:
        print(f"swarm ps: no swarm process on {where}{'' if fleet is None else f' in fleet {fleet}'}")
        return EXIT_OK
    print(table(rows, now))
    fleets = sorted({r["fleet"] for r in rows})
    print(f"{len(rows)} processes in {len(fleets)} fleet{'s' if len(fleets) != 1 else ''} ({', '.join(fleets)}) "
          f"on {where}")
    return EXIT_OK
