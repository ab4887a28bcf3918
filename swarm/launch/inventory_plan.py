"""`swarm up --inventory`'s launch plan: real robots, so no simulated world (a pure function, like plan.py).

    plan = make_fleet_plan(FleetUpOptions(...))   # a swarm.launch.plan.Plan: --dry-run prints it
    plan.processes                                # router, viz, world (the referee), leader, one agent a robot

The router listens where `swarm up` does and connects to every robot's zenoh endpoint (the
inventory's `connect`: a robot's rmw_zenoh router or its zenoh-bridge-ros2dds), so every process of
the swarm reaches every robot's ROS 2 topics through it. The world is `swarm world --referee-only`
(no physics; the launcher has run the pre-flight already, so it gets --no-preflight); each agent is
`swarm robot --inventory F --id I` on this machine, a client of that router. Nothing is restarted:
an agent started again mid-run would anchor its robot's odometry at the start pose while the robot
stands elsewhere (docs/deploy.md), and a lost leader halts every robot (the robots' guards).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from swarm.launch.plan import DEFAULT_LISTEN, Plan, ProcSpec, RestartPolicy, VizOptions

NO_RESTARTS = RestartPolicy(max_restarts=0)


@dataclass(frozen=True)
class FleetUpOptions:
    """The options of `swarm up --inventory` (already validated by the CLI)."""

    inventory: str  # the inventory file (an absolute path: children may run elsewhere)
    robots: int  # the scenario's robots: ids 0 .. robots - 1, one agent each
    scenario_args: tuple[str, ...]  # --scenario/--robots/--seed/--duration/--dt/--governor as given
    robot_endpoints: tuple[str, ...] = ()  # the robots' zenoh endpoints: the router connects to each
    initial_poses: tuple[str, ...] = ()  # --initial-pose I:X,Y,THETA as given
    fleet: str = "default"
    listen: str | None = DEFAULT_LISTEN  # the embedded router's endpoint (None with connect)
    connect: str | None = None  # join an existing router instead (it must reach the robots itself)
    zenoh_config: str | None = None
    multicast: bool = False
    speed: float = 1.0
    metrics: str | None = None
    trace: str | None = None
    start_timeout: float = 60.0
    lost_timeout: float = 10.0
    watchdog: float = 0.5
    ref_timeout: float = 2.5
    viz: VizOptions | None = None


def make_fleet_plan(o: FleetUpOptions, python: str = sys.executable, module: str = "swarm.cli") -> Plan:
    """The processes of `swarm up --inventory`, in start order; children run `python -m module`. Pure."""
    endpoint = o.connect or _client_endpoint(o.listen or DEFAULT_LISTEN)
    net = ["--fleet", o.fleet, "--connect", endpoint]
    if o.zenoh_config:
        net += ["--zenoh-config", o.zenoh_config]
    if o.multicast:
        net += ["--multicast"]
    base = (python, "-m", module)
    router = None
    if o.connect is None:
        r_argv = [*base, "router", "--listen", o.listen or DEFAULT_LISTEN, "--fleet", o.fleet]
        for ep in o.robot_endpoints:
            r_argv += ["--connect", ep]
        if o.zenoh_config:
            r_argv += ["--zenoh-config", o.zenoh_config]
        if o.multicast:
            r_argv += ["--multicast"]
        router = ProcSpec("router", "router", 0, tuple(r_argv))
    poses = [a for p in o.initial_poses for a in ("--initial-pose", p)]
    w_argv = [*base, "world", "--referee-only", "--inventory", o.inventory, "--no-preflight", *o.scenario_args,
              *poses, "--mode", "realtime", "--speed", repr(o.speed), "--start-timeout", repr(o.start_timeout),
              "--lost-timeout", repr(o.lost_timeout), "--watchdog", repr(o.watchdog), *net]
    if o.metrics:
        w_argv += ["--metrics", o.metrics]
    if o.trace:
        w_argv += ["--trace", o.trace]
    world = ProcSpec("world", "world", 0, tuple(w_argv))
    leader = ProcSpec("leader", "leader", 0, (*base, "leader", *o.scenario_args, "--mode", "realtime", *net))
    robots = tuple(ProcSpec(f"robot {i}", "robot", i,
                            (*base, "robot", "--inventory", o.inventory, "--id", str(i), "--mode", "realtime",
                             "--start-timeout", repr(o.start_timeout), "--ref-timeout", repr(o.ref_timeout), *net))
                   for i in range(o.robots))
    viz = None
    if o.viz is not None:
        v_argv = [*base, "viz", "--viz-host", o.viz.host, "--viz-port", str(o.viz.port),
                  "--start-timeout", repr(o.start_timeout), *net]
        if o.viz.rings:
            v_argv.append("--viz-rings")
        if o.viz.server_log:
            v_argv += ["--server-log", o.viz.server_log]
        viz = ProcSpec("viz", "viz", 0, tuple(v_argv))
    return Plan(endpoint, o.fleet, router, world, leader, robots, (), NO_RESTARTS, viz)


def _client_endpoint(listen: str) -> str:
    """Where a local client reaches a router listening on `listen` (0.0.0.0 / [::] -> loopback)."""
    proto, _, rest = listen.partition("/")
    host, _, port = rest.rpartition(":")
    if host in ("0.0.0.0", "[::]", "::", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"
