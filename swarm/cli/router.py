"""`swarm router`: a zenoh router in this process (what `swarm up` embeds; several connect across machines)."""

from __future__ import annotations

import logging

from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, StopEvent, check_endpoint, fleet_of,
                              open_bus, setup_logging)
from swarm.launch.child import die_with_parent
from swarm.launch.plan import DEFAULT_LISTEN
from swarm.proto import keys

log = logging.getLogger("swarm")


def cmd_router(args, started: float) -> int:

    die_with_parent()
    setup_logging()
    default = None if args.secure else [DEFAULT_LISTEN]  # --secure: the router identity's own endpoints
    listen = [check_endpoint("--listen", ep) for ep in (args.listen or default or [])] or None
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, mode="router", listen=listen, role="router")
        try:
            bus.token(keys.alive(fleet_of(args), "router"))
            log.info("router listening on %s%s", ", ".join(listen or ["its identity's endpoints"]),
                     f" (mutual TLS, access control from {args.secure})" if args.secure else "")
            while not stop.wait(0.5):
                pass
        finally:
            bus.close()
    return EXIT_INTERRUPTED


