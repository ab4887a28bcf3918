"""`swarm world`: the simulated world and referee (world.world) on a zenoh session."""

from __future__ import annotations

import logging

from swarm.cli.parser import given
from swarm.cli.common import (CHILD_EXIT_AFTER_S, BadInput, Failure, StopEvent, check_out_dir,
                              fleet_of, load_scenario, open_bus, refuse_a_taken_fleet, setup_logging, write_json)
from swarm.cli.console import converged_phrase, exit_status
from swarm.core.clock import WALL
from swarm.core.metrics import violations
from swarm.process import die_with_parent

log = logging.getLogger("swarm")


def cmd_world(args, started: float) -> int:
    if args.referee_only or args.inventory is not None:
        from swarm.cli.up_inventory import cmd_world_referee

        return cmd_world_referee(args, started)
    from world.world import NotReady, WorldOptions, run_world

    for flag, value in (("--initial-pose", args.initial_pose), ("--no-preflight", args.no_preflight or None)):
        if value is not None:
            raise BadInput(f"{flag} needs --inventory (real robots; a simulated world starts its robots where the "
                           "scenario says)")
    if args.ros2_sim is None:
        for flag in given(args, "twist", "domain", "rmw_zenoh_attachment", "distro"):
            raise BadInput(f"{flag} needs --ros2-sim (it sets the simulated ROS 2 robots' {flag[2:]})")
    die_with_parent()
    setup_logging()
    scn = load_scenario(args, quiet=True)
    fleet = fleet_of(args)
    check_out_dir("--metrics", args.metrics)
    check_out_dir("--trace", args.trace)
    if args.ros2_sim is not None and args.mode != "realtime":
        raise BadInput("--ros2-sim needs --mode realtime (odometry carries no tick)")
    if args.ros2_sim is not None:
        try:
            from swarm.proto import ros2

            ros2.require()
        except ImportError as e:
            raise BadInput(f"--ros2-sim: {e}") from None
    opts = WorldOptions(lockstep=args.mode == "lockstep", speed=args.speed, watchdog=args.watchdog,
                        tick_timeout=args.tick_timeout, lost_timeout=args.lost_timeout,
                        start_timeout=args.start_timeout,
                        ros2=(args.ros2_sim, args.twist, args.domain, args.rmw_zenoh_attachment, args.distro)
                        if args.ros2_sim else None, trace=args.trace is not None,
                        process_faults=args.process_faults)
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, role="world")
        try:
            refuse_a_taken_fleet(bus, fleet, ", ".join(args.connect or []) or "the router")
        except BadInput:
            bus.close()
            raise
        log.info("world: connected (fleet %s)", fleet)
        from swarm.launch.progress_pipe import Teller
        from world.claims import ClaimServer

        claims = ClaimServer(bus, fleet, scn.n)  # robots started with --id auto
        claims.start()
        try:
            metrics, world = run_world(bus, WALL, scn, opts, stop, fleet, started, teller=Teller.from_env())
        except NotReady as e:
            raise Failure(str(e)) from None
        finally:
            claims.close()
            bus.close()
    metrics["interrupted"] = bool(metrics["interrupted"] or stop.is_set())
    if args.metrics is not None:
        write_json(args.metrics, metrics)
    if args.trace is not None and world.trace is not None:
        import numpy as np

        np.savez_compressed(args.trace, q=np.array(world.trace).reshape(-1, scn.n, 3), t=np.array(world.trace_t),
                            dt=scn.dt)
    log.info("world: done at t = %s s, %s, %d collisions, %d misses%s", metrics["duration_s"],
             converged_phrase(metrics["converged_at_s"]), metrics["collisions"], metrics["cmd_misses"],
             f"; FAILED: {metrics['failure']}" if metrics.get("failure") else "")
    bad = violations(metrics)
    if bad and not metrics["interrupted"] and not metrics.get("failure"):
        log.warning("world: checks failed: %s%s", ", ".join(bad), "" if args.allow_violations else " (exit 3)")
    return exit_status(metrics, args.allow_violations)
