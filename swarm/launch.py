"""`swarm up`: the launch plan (a pure function of the options) and the supervisor.

    plan = make_plan(options)          # what to start, with which arguments (--dry-run prints it)
    with Supervisor(plan, log_dir) as sup:
        sup.start_all(...)             # each child in its own process group, logs to log_dir
        ...
                                       # leaving: SIGTERM to every group, SIGKILL after a grace

Children are `python -m swarm.cli <role> ...` processes (subprocess, never fork after a zenoh
session is open). They die with the launcher even if it is SIGKILLed (PR_SET_PDEATHSIG, see
die_with_parent), and robots are restarted on failure under RestartPolicy.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path


PARENT_ENV = "SWARM_PARENT_PID"
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
    """The browser viewer of `swarm up` (a `swarm viz` child; see swarm.watch)."""

    host: str = VIZ_HOST  # where its web server listens
    port: int = 0  # 0: a free one
    rings: bool = False
    server_log: str | None = None  # the meshcat server's own log


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
    zenoh_config: str | None = None
    multicast: bool = False
    metrics: str | None = None
    trace: str | None = None
    start_timeout: float = 60.0
    tick_timeout: float = 1.0
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
    endpoint = o.connect or _client_endpoint(o.listen or DEFAULT_LISTEN)
    net = ["--fleet", o.fleet, "--connect", endpoint]
    if o.zenoh_config:
        net += ["--zenoh-config", o.zenoh_config]
    if o.multicast:
        net += ["--multicast"]
    base = (python, "-m", "swarm.cli")
    router = None
    if o.connect is None:
        r_argv = [*base, "router", "--listen", o.listen or DEFAULT_LISTEN]
        if o.zenoh_config:
            r_argv += ["--zenoh-config", o.zenoh_config]
        if o.multicast:
            r_argv += ["--multicast"]
        router = ProcSpec("router", "router", 0, tuple(r_argv))
    w_argv = [*base, "world", *o.scenario_args, "--mode", o.mode, "--speed", repr(o.speed),
              "--start-timeout", repr(o.start_timeout), "--tick-timeout", repr(o.tick_timeout),
              "--watchdog", repr(o.watchdog), *net]
    if o.metrics:
        w_argv += ["--metrics", o.metrics]
    if o.trace:
        w_argv += ["--trace", o.trace]
    world = ProcSpec("world", "world", 0, tuple(w_argv))
    leader = ProcSpec("leader", "leader", 0, (*base, "leader", *o.scenario_args, "--mode", o.mode, *net))
    robots = tuple(ProcSpec(f"robot {i}", "robot", i,
                            (*base, "robot", "--id", str(i), "--start-timeout", repr(o.start_timeout), *net))
                   for i in range(o.robots))
    viz = None
    if o.viz is not None:
        v_argv = [*base, "viz", *o.scenario_args, "--viz-host", o.viz.host, "--viz-port", str(o.viz.port),
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


# --------------------------------------------------------------------------- children


PACKAGES = ("swarm", "agents", "world")  # this project's code, which every child process imports


def compile_project() -> None:
    """Compile this project's modules to bytecode once, here, before forty processes import them.

    Each child would otherwise compile every module of ours it imports (~40 ms of CPU each, twice
    that on a busy machine) wherever Python does not write bytecode by itself: the first run after
    an install from source, PYTHONDONTWRITEBYTECODE. That was about 1 s of a 2-core machine's
    launch. The .pyc files go where Python looks for them (__pycache__ next to the sources); a
    module is compiled only when its source changed; where the sources are read-only nothing is
    written (an installed wheel has its bytecode already)."""
    import compileall
    import importlib.util

    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        for where in (spec.submodule_search_locations or []) if spec is not None else []:
            if os.access(where, os.W_OK):
                try:
                    compileall.compile_dir(where, quiet=2)
                except OSError:  # a file we may not write: that module is compiled by each child, as before
                    pass


def die_with_parent() -> None:
    """In a child started by the launcher: get SIGTERM when the launcher dies, however it dies.

    Linux's PR_SET_PDEATHSIG; the check after it closes the race where the parent died first."""
    parent = os.environ.get(PARENT_ENV)
    if not parent:
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):  # not Linux: the launcher's own cleanup has to do
        return
    if os.getppid() != int(parent):
        os.kill(os.getpid(), signal.SIGTERM)


class Child:
    def __init__(self, spec: ProcSpec, proc: subprocess.Popen, log: Path):
        self.spec, self.proc, self.log = spec, proc, log
        self.restarts: deque[float] = deque()
        self.given_up = False

    @property
    def pid(self) -> int:
        return self.proc.pid


class Supervisor:
    """Starts children in their own process groups and makes sure none outlives it."""

    def __init__(self, plan: Plan, log_dir: Path, grace_s: float = 3.0):
        self.plan, self.log_dir, self.grace_s = plan, log_dir, grace_s
        self.children: dict[str, Child] = {}
        self.env = {**os.environ, **dict(plan.env), PARENT_ENV: str(os.getpid())}
        self.restarted = 0

    def __enter__(self) -> "Supervisor":
        return self

    def __exit__(self, *exc) -> None:
        self.shutdown()

    def log_of(self, spec: ProcSpec) -> Path:
        """The child's log file (appended to: a reused --log-dir keeps earlier runs' lines)."""
        return self.log_dir / (spec.name.replace(" ", "-") + ".log")

    def start(self, spec: ProcSpec) -> Child:
        log = self.log_of(spec)
        with open(log, "ab") as out:
            proc = subprocess.Popen(spec.argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT,
                                    env=self.env, process_group=0)
        old = self.children.get(spec.name)
        child = Child(spec, proc, log)
        if old is not None:
            child.restarts = old.restarts
        self.children[spec.name] = child
        return child

    def pids(self) -> list[int]:
        return [c.pid for c in self.children.values()]

    def check_robots(self, now: float | None = None) -> list[str]:
        """Restart robot processes that exited, under the policy. Returns log lines of what happened."""
        now = time.monotonic() if now is None else now
        notes = []
        pol = self.plan.restart
        for name, c in list(self.children.items()):
            if c.spec.role != "robot" or c.given_up or c.proc.poll() is None:
                continue
            rc = c.proc.returncode
            while c.restarts and now - c.restarts[0] > pol.window_s:
                c.restarts.popleft()
            if len(c.restarts) >= pol.max_restarts:
                c.given_up = True
                notes.append(f"{name} exited ({_rc(rc)}); restarted {len(c.restarts)} times in "
                             f"{pol.window_s:g} s, giving up on it (log: {c.log})")
                continue
            c.restarts.append(now)
            self.restarted += 1
            self.start(c.spec)
            notes.append(f"{name} exited ({_rc(rc)}); restarted (log: {c.log})")
        return notes

    def signal(self, name: str, sig: int) -> None:
        c = self.children.get(name)
        if c is not None and c.proc.poll() is None:
            try:
                os.killpg(c.pid, sig)
            except ProcessLookupError:
                pass

    def wait(self, name: str, timeout_s: float) -> int | None:
        c = self.children.get(name)
        if c is None:
            return None
        try:
            return c.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def shutdown(self, first: tuple[str, ...] = ()) -> None:
        """SIGTERM every child's group (`first` ones first, the router last), SIGKILL after the grace."""
        order = [n for n in first if n in self.children]
        order += [n for n in self.children if n not in order and n != "router"]
        if "router" in self.children:
            order.append("router")
        for n in order:
            self.signal(n, signal.SIGTERM)
            if n == "router":
                self.wait(n, self.grace_s)
        end = time.monotonic() + self.grace_s
        for n in order:
            c = self.children[n]
            try:
                c.proc.wait(max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        for n in order:
            c = self.children[n]
            if c.proc.poll() is None:
                self.signal(n, signal.SIGKILL)
            try:
                os.killpg(c.pid, signal.SIGKILL)  # anything the child itself left in its group
            except (ProcessLookupError, PermissionError):
                pass
            try:
                c.proc.wait(2.0)
            except subprocess.TimeoutExpired:
                pass


def _rc(rc: int | None) -> str:
    if rc is None:
        return "running"
    if rc < 0:
        try:
            return f"killed by {signal.Signals(-rc).name}"
        except ValueError:
            return f"killed by signal {-rc}"
    return f"exit code {rc}"
