"""`swarm echo KEY`: the swarm's messages on KEY, decoded, one line each (like `ros2 topic echo`)."""

from __future__ import annotations

import json
import math
import queue
import time

import msgspec

from swarm.cli.common import EXIT_FAILURE, EXIT_OK, BadInput, StopEvent, fleet_of, open_bus
from swarm.cli.console import printable
from swarm.cli.console import counted
from swarm.net.presence import collect
from swarm.proto import keys, protocol
from swarm.proto.protocol import ProtocolError

# the message kind each key carries (keys.parse's kind -> protocol's)
KIND_OF_KEY = {"ref": "ref", "pose": "pose", "cmd": "cmd", "status": "status", "faults": "faultstats",
               "cell": "state", "snapshot": "snapshot", "clock": "clock", "progress": "progress", "run": "run",
               "bodies": "bodies", "events": "event", "estop": "estop", "obstacles": "obstacles",
               "config": "config", "claim": "claim", "proc": "proc"}


def key_expr(fleet: str, key: str) -> str:
    """KEY as the user gave it: a full key expression (swarm/...) as it is, else one under swarm/FLEET/."""
    key = key.strip()
    if not key or key.startswith("/") or key.endswith("/") or "//" in key:
        raise BadInput(f"KEY {key!r}: expected a key like robot/3/pose, cell/** or swarm/{fleet}/leader/ref")
    if key.split("/")[0] == keys.PREFIX:
        return key
    return f"{keys.base(fleet)}/{key}"


def served(expr: str) -> bool:
    """Is expr a key of a queryable (world/obstacles, world/config/..., world/claim/..., proc/...), asked rather than
    followed?"""
    rest = expr.split("/")[2:]
    return bool(rest) and (rest[0] == "proc" or rest[0] == "world" and len(rest) > 1 and
                           rest[1] in ("obstacles", "config", "claim"))


def line(key: str, payload: bytes) -> tuple[str, bool]:
    """One message as a line: `key kind {fields}` (JSON), or `key ! why` when it does not decode; and whether
    it decoded."""
    parsed = keys.parse(key)
    kind = KIND_OF_KEY.get(parsed.kind) if parsed is not None else None
    try:
        msg = protocol.decode(payload, kind)
    except ProtocolError as e:
        return printable(f"{key} ! not a {kind or 'swarm'} message: {e}"), False
    fields = msgspec.to_builtins(msg)
    text = json.dumps(fields, separators=(", ", ": "), default=str,
                      allow_nan=True).replace("NaN", "nan") if fields else "{}"
    return printable(f"{key} {protocol.kind_of(msg)} {text}"), True


def cmd_echo(args, started: float) -> int:
    if args.count is not None and args.count < 1:
        raise BadInput(f"--count: must be at least 1, got {args.count}")
    if args.timeout is not None and not (args.timeout > 0 and math.isfinite(args.timeout)):
        raise BadInput(f"--timeout: must be > 0 seconds, got {args.timeout:g}")
    fleet = fleet_of(args)
    expr = key_expr(fleet, args.key)
    asked = served(expr)
    printed = bad = 0
    with StopEvent() as stop:
        bus = open_bus(args, timeout_s=3.0, stop=stop, role="operator")
        try:
            if asked:  # a queryable's key: ask once, print every reply
                for key, payload in bus.query(expr, timeout_s=args.timeout or 2.0):
                    text, ok = line(key, payload)
                    print(text, flush=True)
                    printed += 1
                    bad += not ok
                    if args.count is not None and printed >= args.count:
                        break
            else:
                got: queue.Queue = queue.Queue(maxsize=10_000)  # a slow terminal drops, never blocks zenoh

                def take(key: str, payload: bytes) -> None:
                    try:
                        got.put_nowait((key, payload))
                    except queue.Full:
                        pass

                handle = bus.subscribe(expr, take)
                end = math.inf if args.timeout is None else time.monotonic() + args.timeout
                try:
                    while not stop.is_set() and (args.count is None or printed < args.count):
                        left = end - time.monotonic()
                        if left <= 0:
                            break
                        try:
                            key, payload = got.get(timeout=min(left, 0.2))
                        except queue.Empty:
                            continue
                        text, ok = line(key, payload)
                        print(text, flush=True)
                        printed += 1
                        bad += not ok
                finally:
                    handle.close()
            live = len(collect(bus, fleet, 0.5, stop)) if printed == 0 and not stop.is_set() else 0
        finally:
            bus.close()
    if printed == 0 and not stop.is_set():
        if live:  # the fleet runs: the key is quiet (estop, events: only when something happens)
            why = (f"; fleet {fleet} has {counted(live, 'live process', 'live processes')} (`swarm ps` lists them), "
                   "so nothing was put on this key in that time")
        else:
            why = f" (no process of fleet {fleet} is live there: `swarm ps` lists the fleets a router has)"
        print(f"swarm echo: nothing on {expr}" + (f" within {args.timeout:g} s" if args.timeout else "") + why)
        return EXIT_FAILURE
    if bad:
        print(f"swarm echo: {bad} of {printed} messages did not decode")
    return EXIT_OK
