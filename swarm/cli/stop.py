"""`swarm stop`: the emergency stop (operator -> every drive of the fleet), latched until released."""

from __future__ import annotations

import time

from swarm.cli.common import EXIT_OK, StopEvent, fleet_of, open_bus
from swarm.cli.console import printable
from swarm.proto import keys, protocol, window

WORLD_WAIT_S = 1.0  # after its messages, how long `swarm stop` waits to hear the world log the change


def cmd_stop(args, started: float) -> int:
    fleet = fleet_of(args)
    engaged = not args.release
    if len(args.reason) > protocol.MAX_TEXT:
        from swarm.cli.common import BadInput

        raise BadInput(f"--reason: at most {protocol.MAX_TEXT} characters, got {len(args.reason)}")
    want = "estop" if engaged else "estop_release"
    logged: list[float] = []  # when the world logged the change, by its clock

    def on_event(key: str, payload: bytes) -> None:
        try:
            e = protocol.decode(payload, "event")
        except protocol.ProtocolError:
            return
        if e.event == want:
            logged.append(e.t)

    with StopEvent() as stop:
        bus = open_bus(args, timeout_s=5.0, stop=stop, role="operator")
        try:
            bus.subscribe(keys.world_events(fleet), on_event)
            end = time.monotonic() + args.repeat_s
            sent = 0
            while True:  # reliable puts, repeated: a robot whose link hiccuped hears a later one
                now = time.time()
                msg = protocol.Estop(t=now, seq=int(now * 1000), engaged=engaged, reason=args.reason)
                bus.put(keys.estop(fleet), protocol.encode(msg), reliable=True)
                sent += 1
                if time.monotonic() >= end or stop.wait(0.1):
                    break
            wait_end = time.monotonic() + WORLD_WAIT_S
            while not logged and time.monotonic() < wait_end and not stop.wait(0.05):
                pass
            worlds = [] if logged else bus.alive_now(keys.alive_any(fleet, "world"))
        finally:
            bus.close()
    state = "engaged" if engaged else "released"
    if logged:
        told = f"; the world logged it at t = {logged[0]:.2f} s"
    elif worlds:
        told = (f"; the world logged no change: the stop was {state} already, or the world refused this machine's "
                f"message (its clock and the world's must agree within {window.ESTOP_SPAN_S:g} s)")
    else:
        told = "; no world on this fleet logs it (every drive obeys it all the same)"
    print(f"swarm stop: emergency stop {'ENGAGED' if engaged else 'released'} on fleet {fleet} "
          f"({sent} messages{', reason: ' + printable(args.reason) if args.reason else ''}){told}")
    return EXIT_OK
