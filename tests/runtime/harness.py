"""Run a whole swarm in one process on an in-memory bus: world, leader and agents as threads."""

from __future__ import annotations

import threading

from agents import leader as leader_mod
from agents import robot
from swarm.net.bus import MemoryBus, MemoryNet
from world.world import World


def run_swarm(scn, lockstep: bool = True, fleet: str = "t", trace: bool = True, timeout_s: float = 60.0,
              kill: dict | None = None, net: MemoryNet | None = None):
    """Returns (metrics, world, agents). `kill` maps robot id -> the tick at which its agent stops;
    `net`: the in-memory network to run on (default: a new one), for observers subscribed beforehand."""
    net = net or MemoryNet()
    wbus = MemoryBus(net)
    world = World(wbus, scn, fleet, lockstep=lockstep, trace=trace, tick_timeout=5.0)
    world.start()
    stop = threading.Event()
    lbus = MemoryBus(net)
    lead = leader_mod.Leader(lbus, scn.leader.table(), scn.dt, fleet, lockstep=lockstep)
    lead.start()
    threads = [threading.Thread(target=lead.run, args=(stop,), daemon=True)]
    agents = []
    obstacles = robot.fetch_obstacles(MemoryBus(net), fleet, 1.0)
    for i in range(scn.n):
        bus = MemoryBus(net)
        cfg = robot.fetch_config(bus, fleet, i, 1.0)
        a = robot.Agent(bus, cfg, fleet, wait_timeout=5.0, faults=scn.faults)  # under faults: played by the schedule
        a.start(obstacles)
        agents.append(a)

        def loop(a=a):
            try:
                robot._loop_lockstep(a, stop) if lockstep else robot._loop_realtime(a, stop)
            finally:
                a.close()

        threads.append(threading.Thread(target=loop, daemon=True))
    for t in threads:
        t.start()
    try:
        world.wait_ready(5.0)
        metrics = world.run(threading.Event())
    finally:
        stop.set()
        for t in threads:
            t.join(timeout_s)
        world.close()
        lead.close()
    return metrics, world, agents
