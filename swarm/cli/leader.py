"""`swarm leader`: the virtual leader's reference (agents.leader) on a zenoh session."""

from __future__ import annotations

import logging

from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, BadInput, Failure, StopEvent, fleet_of, load_scenario, open_bus,
                              setup_logging)
from swarm.core.clock import WALL
from swarm.process import die_with_parent

log = logging.getLogger("swarm.leader")


def cmd_leader(args, started: float) -> int:
    from agents.follow import NoAnswer, RunRefused
    from agents.leader import run_leader

    die_with_parent()
    setup_logging()
    scn = load_scenario(args, quiet=True)
    fleet = fleet_of(args)
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, lean=True, role="leader")
        log.info("leader: connected (fleet %s), waiting for a run", fleet)
        try:
            try:
                run_leader(bus, WALL, scn, fleet, stop=stop, start_timeout=args.start_timeout)
            except NoAnswer as e:
                if stop.is_set():
                    return EXIT_INTERRUPTED
                raise Failure(str(e)) from None
            except RunRefused as e:
                raise BadInput(f"the leader refuses the run: {e}") from None
        finally:
            bus.close()
    return EXIT_INTERRUPTED
