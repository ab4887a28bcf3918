"""`swarm robot --id I`: one robot's agent (agents.robot) on a zenoh session."""

from __future__ import annotations

import logging

from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, Failure, StopEvent, fleet_of, load_scenario,
                              open_bus, setup_logging)
from swarm.core.clock import WALL
from swarm.launch.child import die_with_parent

log = logging.getLogger("swarm")


def cmd_robot(args, started: float) -> int:
    from agents import robot

    die_with_parent()
    setup_logging()
    fleet = fleet_of(args)
    cfg = None
    if args.scenario is not None:
        scn = load_scenario(args)
        cfg = scn.robot_config(args.id, lockstep=args.mode == "lockstep")
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, lean=True)
        try:
            if cfg is None:
                cfg = robot.fetch_config(bus, fleet, args.id, args.start_timeout, stop)
            obstacles = robot.fetch_obstacles(bus, fleet, args.start_timeout, stop)
            agent = robot.run_robot(bus, WALL, cfg, fleet, stop, obstacles)
        except robot.NoAnswer as e:
            if stop.is_set():
                return EXIT_INTERRUPTED
            raise Failure(str(e)) from None
        finally:
            bus.close()
    log.info("robot %d: %d ticks, %d skipped, %d states received, %d bad messages, loop CPU %.0f us a tick",
             args.id, agent.ticks, agent.skipped, agent.states_received, agent.bad.count,
             1e6 * agent.loop_cpu_s / max(1, agent.ticks))
    return EXIT_INTERRUPTED


