"""`swarm leader`: the virtual leader's reference (agents.leader) on a zenoh session."""

from __future__ import annotations

from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, StopEvent, fleet_of, load_scenario, open_bus,
                              setup_logging)
from swarm.core.clock import WALL
from swarm.launch.child import die_with_parent


def cmd_leader(args, started: float) -> int:
    from agents.leader import run_leader

    die_with_parent()
    setup_logging()
    scn = load_scenario(args)
    fleet = fleet_of(args)
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, stop=stop, lean=True)
        try:
            run_leader(bus, WALL, scn, fleet, lockstep=args.mode == "lockstep", stop=stop)
        finally:
            bus.close()
    return EXIT_INTERRUPTED
