"""`swarm ps`: the swarms on a router, and their live processes (from liveliness tokens and each process's
proc queryable: host, pid, age, run)."""

from __future__ import annotations

import json
import time

from swarm.cli.common import EXIT_FAILURE, EXIT_OK, BadInput, StopEvent, fleet_of, open_bus
from swarm.cli.console import counted, printable
from swarm.net.presence import collect

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
    lines = [tuple(printable(cell) for cell in line) for line in lines]  # what other processes said of themselves
    widths = [max(len(line[c]) for line in lines) for c in range(len(head))]
    return "\n".join("  ".join(cell.ljust(w) for cell, w in zip(line, widths)).rstrip() for line in lines)


def cmd_ps(args, started: float) -> int:
    """List the processes; exit 1 when none answered (as swarm echo when nothing came: a script can wait on it)."""
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
        return EXIT_OK if rows else EXIT_FAILURE
    where = ", ".join(args.connect or ["tcp/127.0.0.1:7447"]) if not args.secure else f"the router of {args.secure}"
    if not rows:
        print(f"swarm ps: no swarm process on {where}{'' if fleet is None else f' in fleet {fleet}'}")
        return EXIT_FAILURE
    print(table(rows, now))
    fleets = sorted({r["fleet"] for r in rows})
    print(f"{counted(len(rows), 'process', 'processes')} in {counted(len(fleets), 'fleet')} ({', '.join(fleets)}) "
          f"on {where}")
    return EXIT_OK
