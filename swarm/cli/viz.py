"""`swarm viz`: watch a running swarm in the browser (swarm.view)."""

from __future__ import annotations

import logging

from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, Failure, StopEvent, check_endpoint, check_out_dir,
                              check_viz_port, fleet_of, load_scenario, open_bus, setup_logging, viz_options)
from swarm.process import die_with_parent
from swarm.launch.plan import DEFAULT_LISTEN
from swarm.net import presence

log = logging.getLogger("swarm")


def cmd_viz(args, started: float) -> int:
    from swarm.view.meshcat_server import MeshcatServer, ServerError
    from swarm.view.viz import SceneInfo, Viewer
    from swarm.view.watch import SwarmWatcher

    die_with_parent()
    setup_logging()
    fleet = fleet_of(args)
    scene = SceneInfo.from_scenario(load_scenario(args, quiet=True)) if args.scenario is not None else None
    v = viz_options(args, True, "")
    check_viz_port(v)
    check_out_dir("--server-log", args.server_log)
    connect = [check_endpoint("--connect", c) for c in (args.connect or [DEFAULT_LISTEN])]
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        # the server first: fork before zenoh starts its threads, and from this (main) thread, which
        # its PR_SET_PDEATHSIG follows
        server = MeshcatServer(v.host, v.port, log=args.server_log, start_timeout_s=v.timeout)
        try:
            server.start()
            print(f"viewer: {server.web_url}", flush=True)
            log.info("viz: fleet %s on %s, %s", fleet, ", ".join(connect),
                     f"scenario {scene.name}" if scene else "scene from the world")
            bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, role="viz")
            try:
                watcher = SwarmWatcher(bus, fleet, Viewer(server, scene, rings=v.rings), scene=scene)
                watcher.start()
                presence.announce(bus, fleet, "viz")
                while watcher.running and not stop.wait(0.5):
                    pass
                watcher.close()
            finally:
                bus.close()
        except ServerError as e:
            raise Failure(f"viewer: {e} (a loaded machine may need a longer --viz-timeout; `swarm viz --connect "
                          f"{connect[0]} --fleet {fleet}` attaches a viewer to a running swarm later)") from None
        finally:
            server.stop()
    log.info("viz: %d snapshots, %d drawn, %d skipped, %d bad messages", watcher.received, watcher.drawn,
             watcher.skipped, watcher.bad.count)
    if watcher.error is not None:
        raise Failure(f"the viewer stopped: {watcher.error}")
    return EXIT_INTERRUPTED


