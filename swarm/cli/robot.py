"""`swarm robot --id I`: one robot's agent (agents.robot) on a zenoh session, serving run after run."""

from __future__ import annotations

import logging

from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, BadInput, Failure, StopEvent, fleet_of,
                              load_scenario, open_bus, setup_logging)
from swarm.core.clock import WALL
from swarm.launch.child import die_with_parent

log = logging.getLogger("swarm")


def cmd_robot(args, started: float) -> int:
    from agents import robot
    from agents.follow import NoAnswer, RunRefused

    die_with_parent()
    setup_logging()
    fleet = fleet_of(args)
    scn = load_scenario(args) if args.scenario is not None else None
    if scn is not None and args.id >= scn.n:
        raise BadInput(f"--id {args.id}: the scenario has {scn.n} robots (ids 0..{scn.n - 1})")
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, lean=True, role="robot", robot_id=args.id)
        try:
            agents = robot.run_robot(bus, WALL, args.id, fleet, stop, scenario=scn, start_timeout=args.start_timeout)
        except NoAnswer as e:
            if stop.is_set():
                return EXIT_INTERRUPTED
            raise Failure(str(e)) from None
        except RunRefused as e:
            raise BadInput(f"robot {args.id} refuses the run: {e}") from None
        finally:
            bus.close()
    for a in agents:
        log.info("robot %d, run %s: %d ticks, %d skipped, %d states received, %d bad messages, %d stale, "
                 "loop CPU %.0f us a tick", args.id, a.cfg.run, a.ticks, a.skipped, a.states_received, a.bad.count,
                 a.bad.stale, 1e6 * a.loop_cpu_s / max(1, a.ticks))
    return EXIT_INTERRUPTED
