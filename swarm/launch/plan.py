"""`swarm up`'s launch plan: what to start, with which arguments, as a pure function of the options.

    plan = make_plan(options)          # --dry-run prints plan.describe(); tests check it
    plan.processes                     # router, viz, world, leader, robots: start order

Children are `python -m swarm.cli <role> ...` processes; swarm.launch.supervisor starts and
watches them (the one place that touches subprocess).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field


DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
VIZ_HOST = "127.0.0.1"  # the viewer's web server: this machine only unless asked


@dataclass(frozen=True)
class RestartPolicy:
    """A robot process that exits on its own is restarted, at most `max_restarts` times in any
    `window_s` seconds; after that it is left dead (the world keeps its body as an obstacle)."""

    max_restarts: int = 3
    window_s: float = 60.0


@dataclass(frozen=True)
class VizOptions:
    """The browser viewer of `swarm up` (a `swarm viz` child; see swarm.view.watch)."""

    host: str = VIZ_HOST  # where its web server listens
    port: int = 0  # 0: a free one
    rings: bool = False
    server_log: str | None = None  # the meshcat server's own log
    timeout: float = 60.0  # s the meshcat server may take to give its address (--viz-timeout)


@dataclass(frozen=True)
class UpOptions:
    """The options of `swarm up` (already validated by the CLI)."""

    robots: int
    scenario_args: tuple[str, ...]  # --scenario/--robots/--seed/--duration/--dt/--governor as given
    mode: str = "lockstep"
    speed: float = 1.0
    fleet: str = "default"
    listen: str | None = DEFAULT_LISTEN  # the embedded router's endpoint (None with connect)
    connect: str | None = None  # join an existing router instead
    router_zid: str | None = None  # the embedded router's zenoh id: the processes on it leave it the ingress checks
    zenoh_config: str | None = None
    secure: str | None = None  # a fleet directory of `swarm secure init`: every process with its role (mutual TLS, ACL)
    secure_endpoint: str | None = None  # with secure and no listen: the router identity's (tls/127.0.0.1:PORT)
    drive: str = "sim"  # ros2: the world simulates a ROS 2 fleet and every robot drives through it
    ros_flavor: str = "rmw_zenoh"
    attachment: str = "v2"  # the simulated fleet's rmw_zenoh attachment form (the robots find it themselves)
    distro: str = "jazzy"  # the simulated fleet's ROS 2 distribution (humble: no type hashes)
    twist: str = "plain"
    domain: int = 0
    multicast: bool = False
    metrics: str | None = None
    trace: str | None = None
    start_timeout: float = 60.0
    tick_timeout: float = 1.0
    lost_timeout: float = 10.0
    watchdog: float = 0.5
    restart: RestartPolicy = RestartPolicy()
    viz: VizOptions | None = None  # None: no viewer


@dataclass(frozen=True)
class ProcSpec:
    name: str  # "router", "viz", "world", "leader", "robot 7"
    role: str
    id: int
    argv: tuple[str, ...]


@dataclass(frozen=True)
class Plan:
    endpoint: str  # where every client connects
    fleet: str
    router: ProcSpec | None
    world: ProcSpec
    leader: ProcSpec
    robots: tuple[ProcSpec, ...]
    env: tuple[tuple[str, str], ...] = field(default=())
    restart: RestartPolicy = RestartPolicy()
    viz: ProcSpec | None = None  # the viewer: an observer, never restarted, stopped with the rest

    @property
    def processes(self) -> tuple[ProcSpec, ...]:
        return ((self.router,) if self.router else ()) + ((self.viz,) if self.viz else ()) + \
            (self.world, self.leader) + self.robots

    def describe(self) -> str:
        lines = [f"launch plan: fleet '{self.fleet}', {len(self.robots)} robots, clients connect to {self.endpoint}",
                 f"restart policy: a robot is restarted at most {self.restart.max_restarts} times "
                 f"in {self.restart.window_s:g} s"]
        for p in self.processes:
            lines.append(f"  {p.name:<10} " + " ".join(_quote(a) for a in p.argv))
        return "\n".join(lines)


def _quote(a: str) -> str:
    return a if a and all(c.isalnum() or c in "-_./:=," for c in a) else repr(a)


def make_plan(o: UpOptions, python: str = sys.executable) -> Plan:
    """The processes `swarm up` starts, in start order (the viewer right after the router, so its URL
    is known early). Pure: no side effect, no I/O."""
    endpoint = o.connect or _client_endpoint(o.listen or o.secure_endpoint or DEFAULT_LISTEN)
    net = ["--fleet", o.fleet, "--connect", endpoint]
    if o.zenoh_config:
        net += ["--zenoh-config", o.zenoh_config]
    if o.secure:
        net += ["--secure", o.secure]
    if o.multicast:
        net += ["--multicast"]
    if o.connect is None and o.router_zid is not None:
        # its own router checks what comes in (bus.size_limits, wildcard_guard): a process on it need not
        net += ["--router-checks", o.router_zid]
    base = (python, "-m", "swarm.cli")
    router = None
    if o.connect is None:
        r_argv = [*base, "router"] + ([] if o.secure and not o.listen else ["--listen", o.listen or DEFAULT_LISTEN])
        if o.zenoh_config:
            r_argv += ["--zenoh-config", o.zenoh_config]
        if o.secure:
            r_argv += ["--secure", o.secure]
        if o.multicast:
            r_argv += ["--multicast"]
        if o.router_zid is not None:
            r_argv += ["--zid", o.router_zid]
        router = ProcSpec("router", "router", 0, tuple(r_argv))
    w_argv = [*base, "world", *o.scenario_args, "--mode", o.mode, "--speed", repr(o.speed),
              "--start-timeout", repr(o.start_timeout), "--tick-timeout", repr(o.tick_timeout),
              "--lost-timeout", repr(o.lost_timeout),
              "--watchdog", repr(o.watchdog), *net]
    if o.mode == "lockstep":
        w_argv += ["--process-faults", "signals"]  # this supervisor does scheduled kills and hangs for real
    if o.metrics:
        w_argv += ["--metrics", o.metrics]
    if o.trace:
        w_argv += ["--trace", o.trace]
    ros = []
    if o.drive == "ros2":
        w_argv += ["--ros2-sim", o.ros_flavor, "--twist", o.twist, "--domain", str(o.domain),
                   "--rmw-zenoh-attachment", o.attachment, "--distro", o.distro]
        # the robots run with the defaults a robot of the field would: their twist type and attachment form found
        # from the simulated robots themselves (their tokens or bridge routes, their odometry)
        ros = ["--drive", "ros2", "--ros-flavor", o.ros_flavor, "--domain", str(o.domain)]
    world = ProcSpec("world", "world", 0, tuple(w_argv))
    leader = ProcSpec("leader", "leader", 0, (*base, "leader", *o.scenario_args, "--mode", o.mode, *net))
    robots = tuple(ProcSpec(f"robot {i}", "robot", i,
                            (*base, "robot", "--id", str(i), "--start-timeout", repr(o.start_timeout), *ros, *net))
                   for i in range(o.robots))
    viz = None
    if o.viz is not None:
        v_argv = [*base, "viz", *o.scenario_args, "--viz-host", o.viz.host, "--viz-port", str(o.viz.port),
                  "--viz-timeout", repr(o.viz.timeout),
                  "--start-timeout", repr(o.start_timeout), *net]
        if o.viz.rings:
            v_argv.append("--viz-rings")
        if o.viz.server_log:
            v_argv += ["--server-log", o.viz.server_log]
        viz = ProcSpec("viz", "viz", 0, tuple(v_argv))
    return Plan(endpoint, o.fleet, router, world, leader, robots, (), o.restart, viz)


def _client_endpoint(listen: str) -> str:
    """Where a local client reaches a router listening on `listen` (0.0.0.0 / [::] -> loopback)."""
    proto, _, rest = listen.partition("/")
    host, _, port = rest.rpartition(":")
    if host in ("0.0.0.0", "[::]", "::", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"
