"""`swarm stop`: the emergency stop (operator -> every drive of the fleet), latched until released."""

from __future__ import annotations

import time

from swarm.cli.common import EXIT_OK, StopEvent, fleet_of, open_bus
from swarm.proto import keys, protocol


def cmd_stop(args, started: float) -> int:
    fleet = fleet_of(args)
    engaged = not args.release
    if len(args.reason) > protocol.MAX_TEXT:
        from swarm.cli.common import BadInput

        raise BadInput(f"--reason: at most {protocol.MAX_TEXT} characters, got {len(args.reason)}")
    with StopEvent() as stop:
        bus = open_bus(args, timeout_s=5.0, stop=stop, role="operator")
        try:
            end = time.monotonic() + args.repeat_s
            sent = 0
            while True:  # reliable puts, repeated: a robot whose link hiccuped hears a later one
                now = time.time()
                msg = protocol.Estop(t=now, seq=int(now * 1000), engaged=engaged, reason=args.reason)
                bus.put(keys.estop(fleet), protocol.encode(msg), reliable=True)
                sent += 1
                if time.monotonic() >= end or stop.wait(0.1):
                    break
        finally:
            bus.close()
    print(f"swarm stop: emergency stop {'ENGAGED' if engaged else 'released'} on fleet {fleet} "
          f"({sent} messages{', reason: ' + args.reason if args.reason else ''})")
    return EXIT_OK
