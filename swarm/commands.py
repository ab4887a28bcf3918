"""The runtime's commands: `swarm router | world | leader | robot | viz | up` (argument parsing is in swarm.cli).

Each process opens one zenoh session (a client of a router; the router itself for `swarm
router`), closes it on every way out, and turns SIGINT/SIGTERM into a clean stop (exit 130).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import signal
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

from swarm import keys
from swarm.bus import ZENOH_RUNTIME
from swarm.launch import DEFAULT_LISTEN, VIZ_HOST, VizOptions

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
log = logging.getLogger("swarm")


class BadInput(Exception):
    """A user error: printed as one line, exit code 2."""


class Failure(Exception):
    """A runtime failure: printed as one line, exit code 1."""


# --------------------------------------------------------------------------- shared pieces


class StopEvent:
    """SIGINT and SIGTERM set a threading.Event that the process's loop polls. A second Ctrl-C stops at
    once (KeyboardInterrupt) unless hard_second is False: then the shutdown under way (bounded: it
    ends with SIGKILL) finishes, so the metrics and a recording are still written. exit_after_s
    bounds the clean shutdown: that long after the first signal, the process exits anyway.

    The handler takes no lock: it writes the signal to a pipe and a watcher thread sets the event.
    A handler that called Event.set() itself deadlocked a leader in CI: a second signal came while
    the first handler held the event's lock (or while the main thread did, inside stop.wait())."""

    def __init__(self, hard_second: bool = True, exit_after_s: float | None = None) -> None:
        self.event = threading.Event()
        self.signal: int | None = None
        self.hard_second = hard_second
        self.exit_after_s = exit_after_s

    def __enter__(self) -> threading.Event:
        self._r, self._w = os.pipe()
        self._watcher = threading.Thread(target=self._watch, name="stop-signals", daemon=True)
        self._watcher.start()
        self._old = {s: signal.signal(s, self._handle) for s in (signal.SIGINT, signal.SIGTERM)}
        return self.event

    def _handle(self, signum, frame) -> None:
        second = self.signal is not None
        self.signal = signum
        if second and signum == signal.SIGINT and self.hard_second:  # a second Ctrl-C
            raise KeyboardInterrupt
        try:
            os.write(self._w, bytes([signum]))
        except OSError:  # closed: the with block is over
            pass

    def _watch(self) -> None:
        timer = None
        while True:
            try:
                got = os.read(self._r, 16)
            except OSError:
                return
            if not got:
                return
            if self.event.is_set() and signal.SIGINT in got and not self.hard_second:
                print("swarm: stopping; the metrics and the recording are being written (a few seconds at most)",
                      file=sys.stderr, flush=True)
            if timer is None and self.exit_after_s is not None:
                timer = threading.Timer(self.exit_after_s, _hard_exit, (self.exit_after_s,))
                timer.daemon = True
                timer.start()
            self.event.set()

    def __exit__(self, *exc) -> None:
        for s, old in self._old.items():
            signal.signal(s, old)
        os.close(self._w)  # the watcher reads the end of the pipe and returns
        self._watcher.join(1.0)
        os.close(self._r)


# A swarm process told to stop (by a signal; by its parent's death through PR_SET_PDEATHSIG) exits
# within this many seconds even if its clean shutdown hangs: nobody is left to SIGKILL it when the
# launcher itself was killed.
CHILD_EXIT_AFTER_S = 5.0


def _hard_exit(after_s: float) -> None:
    print(f"swarm: the clean shutdown took more than {after_s:g} s; exiting now", file=sys.stderr, flush=True)
    os._exit(EXIT_INTERRUPTED)


def fleet_of(args) -> str:
    try:
        return keys.check_fleet(args.fleet)
    except keys.KeyError_ as e:
        raise BadInput(f"--fleet: {e}") from None


def _check_endpoint(flag: str, ep: str) -> str:
    proto, sep, rest = ep.partition("/")
    host, colon, port = rest.rpartition(":")
    if not sep or not proto or not colon or not host:
        raise BadInput(f"{flag} {ep!r}: expected an endpoint like tcp/127.0.0.1:7447")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise BadInput(f"{flag} {ep!r}: the port must be an integer in 1..65535, got {port!r}")
    return ep


def _bind_error(host: str, port: int) -> str | None:
    """Why a TCP server could not listen on host:port now (None: it could), binding as servers do
    (SO_REUSEADDR): a clear exit 2 up front rather than a child that fails later, in its log."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as e:
        return f"unknown host {host!r} ({e.strerror})"
    for family, kind, proto, _, addr in infos:
        with socket.socket(family, kind, proto) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                sock.bind(addr)
            except OSError as e:
                return e.strerror or str(e)
    return None


def _check_listen_free(ep: str) -> None:
    """A router that cannot bind its port only says so in its log, and the swarm then joins whatever
    holds the port (another swarm's router): refuse before anything starts."""
    proto, _, rest = ep.partition("/")
    if proto != "tcp":
        return
    host, _, port = rest.rpartition(":")
    error = _bind_error(host.strip("[]"), int(port))
    if error is not None:
        raise BadInput(f"--listen {ep}: cannot listen there ({error}); is another swarm or router running? "
                       "Give another port with --listen, or join it with --connect")


def open_bus(args, mode: str = "client", listen: list[str] | None = None, timeout_s: float = 10.0,
             stop: threading.Event | None = None, lean: bool = False):
    """A ZenohBus for this process; a client retries until its router answers or timeout_s passes.

    lean: zenoh's single-worker runtime (recipes/zenoh.md section 8), for the many small robot
    processes. Not for the world: there one worker thread both receives (running our callbacks,
    which need the GIL) and sends, and a burst of reliable puts from the main thread (which holds
    the GIL while it waits for room in the send queue) stalled it until the router closed the
    link after 5 s ("Unable to push non droppable network message"), once per ~2000 ticks at N = 37.
    """
    if lean:
        os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME)  # before zenoh starts its runtime
    from swarm.bus import ZenohBus, zenoh_config

    connect = [_check_endpoint("--connect", c) for c in (args.connect or [])]
    if mode == "client" and not connect:
        connect = [DEFAULT_LISTEN]
    cfg_file = getattr(args, "zenoh_config", None)
    if cfg_file is not None and not Path(cfg_file).is_file():
        raise BadInput(f"--zenoh-config {cfg_file}: no such file")
    end = time.monotonic() + timeout_s
    while True:
        try:
            conf = zenoh_config(mode, connect=connect, listen=listen, config_file=cfg_file,
                                multicast=getattr(args, "multicast", False))
        except Exception as e:
            raise BadInput(f"zenoh configuration: {e}") from None
        try:
            return ZenohBus(conf)
        except Exception as e:
            if mode != "client" or time.monotonic() >= end or (stop is not None and stop.is_set()):
                where = ", ".join(listen or []) if mode == "router" else ", ".join(connect)
                raise Failure(f"cannot open a zenoh {mode} session on {where}: {e}") from None
            time.sleep(0.1)


def _load(args):
    from swarm import scenario_file
    from swarm.scenario_file import Overrides

    dt = getattr(args, "dt", None)
    rate = getattr(args, "rate", None)
    if rate is not None:
        if dt is not None:
            raise BadInput("give --dt or --rate, not both")
        dt = 1.0 / rate
    ov = Overrides(robots=getattr(args, "robots", None), seed=getattr(args, "seed", None),
                   duration=getattr(args, "duration", None), dt=dt, governor=getattr(args, "governor", None))
    return scenario_file.load(args.scenario, ov)


def scenario_args(args) -> tuple[str, ...]:
    """The scenario flags as given, to pass on to child processes (they resolve the same scenario)."""
    out = ["--scenario", args.scenario]
    for flag, value in (("--robots", args.robots), ("--seed", args.seed), ("--duration", args.duration)):
        if value is not None:
            out += [flag, str(value) if isinstance(value, int) else repr(value)]
    if getattr(args, "rate", None) is not None:
        out += ["--dt", repr(1.0 / args.rate)]
    elif args.dt is not None:
        out += ["--dt", repr(args.dt)]
    if args.governor is not None:
        out.append("--governor" if args.governor else "--no-governor")
    return tuple(out)


def _setup_logging(quiet: bool = False) -> None:
    logging.basicConfig(level=logging.WARNING if quiet else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s: %(message)s")


def _write_json(path: Path, obj: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, allow_nan=False) + "\n")
    tmp.replace(path)


def record_rate(args) -> float:
    """--record-hz (default swarm.record.DEFAULT_RECORD_HZ), refused without --record rather than ignored."""
    if args.record_hz is not None and args.record is None:
        raise BadInput("--record-hz needs --record PATH.mcap")
    if args.record_hz is None:
        from swarm.record import DEFAULT_RECORD_HZ

        return DEFAULT_RECORD_HZ
    return args.record_hz


def check_out_dir(flag: str, path: Path | None) -> None:
    """An output file's directory must exist (and be a directory), and the file must not be a directory."""
    if path is None:
        return
    if not path.parent.exists():
        raise BadInput(f"{flag} {path}: directory {path.parent} does not exist")
    if not path.parent.is_dir():
        raise BadInput(f"{flag} {path}: {path.parent} is not a directory")
    if path.is_dir():
        raise BadInput(f"{flag} {path}: is a directory (give a file name)")


def viz_options(args, enabled: bool, otherwise: str, extra: tuple[tuple[str, object], ...] = ()) -> VizOptions | None:
    """The viewer's options from --viz-host/--viz-port/--viz-rings (types already checked by the
    parser); None when the viewer is off, and then any of those flags is bad input ("--viz-port
    `otherwise`")."""
    given = (("--viz-host", args.viz_host), ("--viz-port", args.viz_port), ("--viz-rings", args.viz_rings or None),
             *extra)
    if not enabled:
        for flag, value in given:
            if value is not None:
                raise BadInput(f"{flag} {otherwise}")
        return None
    return VizOptions(host=args.viz_host or VIZ_HOST, port=args.viz_port or 0, rings=bool(args.viz_rings))


def check_viz_port(v: VizOptions) -> None:
    """A fixed --viz-port must be free now (a clear exit 2 rather than a viewer that fails later)."""
    if not v.port:
        return
    error = _bind_error(v.host, v.port)
    if error is not None:
        raise BadInput(f"--viz-port {v.port}: cannot listen on {v.host}:{v.port} ({error})")


# --------------------------------------------------------------------------- processes


def cmd_router(args, started: float) -> int:
    from swarm.launch import die_with_parent

    die_with_parent()
    _setup_logging()
    listen = [_check_endpoint("--listen", ep) for ep in (args.listen or [DEFAULT_LISTEN])]
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, mode="router", listen=listen)
        try:
            bus.token(keys.alive(fleet_of(args), "router"))
            log.info("router listening on %s", ", ".join(listen))
            while not stop.wait(0.5):
                pass
        finally:
            bus.close()
    return EXIT_INTERRUPTED


def settle_heap() -> None:
    """Before a process's run loop: collect once, then move everything alive (imports, sessions,
    configuration) out of the garbage collector's sight (gc.freeze). A full collection of a robot
    process costs about 3 ms (13 000 objects after its imports); frozen, the ones that still come
    now and then cost microseconds, so they do not show up in the control round trip."""
    import gc

    gc.collect()
    gc.freeze()


def cmd_robot(args, started: float) -> int:
    from agents import robot
    from swarm.launch import die_with_parent

    die_with_parent()
    _setup_logging()
    fleet = fleet_of(args)
    cfg = None
    if args.scenario is not None:
        scn = _load(args)
        cfg = scn.robot_config(args.id, lockstep=args.mode == "lockstep")
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, lean=True)
        try:
            if cfg is None:
                cfg = robot.fetch_config(bus, fleet, args.id, args.start_timeout, stop)
            obstacles = robot.fetch_obstacles(bus, fleet, args.start_timeout, stop)
            settle_heap()
            agent = robot.run(bus, cfg, fleet, stop, obstacles)
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


def cmd_leader(args, started: float) -> int:
    from agents.leader import Leader
    from swarm.launch import die_with_parent

    die_with_parent()
    _setup_logging()
    scn = _load(args)
    fleet = fleet_of(args)
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, stop=stop, lean=True)
        try:
            lead = Leader(bus, scn.leader.table(), scn.dt, fleet, lockstep=args.mode == "lockstep")
            lead.start()
            try:
                lead.run(stop)
            finally:
                lead.close()
        finally:
            bus.close()
    return EXIT_INTERRUPTED


def cmd_world(args, started: float) -> int:
    from swarm.launch import die_with_parent
    from world.world import NotReady, World

    die_with_parent()
    _setup_logging()
    scn = _load(args)
    fleet = fleet_of(args)
    check_out_dir("--metrics", args.metrics)
    check_out_dir("--trace", args.trace)
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, stop=stop)
        try:
            world = World(bus, scn, fleet, lockstep=args.mode == "lockstep", speed=args.speed,
                          watchdog=args.watchdog, tick_timeout=args.tick_timeout, trace=args.trace is not None)
            world.start()
            try:
                log.info("world: %d robots, %d obstacles, %s, waiting for robots and leader", scn.n,
                         len(scn.obstacles), args.mode)
                try:
                    world.wait_ready(args.start_timeout, stop)
                except NotReady as e:
                    raise Failure(str(e)) from None
                except InterruptedError:
                    pass
                settle_heap()
                metrics = world.run(stop, started) if not stop.is_set() else \
                    world.referee.metrics(time.perf_counter() - started, True, args.mode)
            finally:
                world.close()
        finally:
            bus.close()
    metrics["interrupted"] = bool(metrics["interrupted"] or stop.is_set())
    if args.metrics is not None:
        _write_json(args.metrics, metrics)
    if args.trace is not None and world.trace is not None:
        import numpy as np

        np.savez_compressed(args.trace, q=np.array(world.trace).reshape(-1, scn.n, 3), dt=scn.dt)
    log.info("world: done at t = %s s, converged at %s s, %d collisions, %d misses",
             metrics["duration_s"], metrics["converged_at_s"], metrics["collisions"], metrics["cmd_misses"])
    return EXIT_INTERRUPTED if metrics["interrupted"] else EXIT_OK


def cmd_viz(args, started: float) -> int:
    from swarm.launch import die_with_parent
    from swarm.meshcat_server import MeshcatServer, ServerError
    from swarm.viz import SceneInfo, Viewer
    from swarm.watch import SwarmWatcher

    die_with_parent()
    _setup_logging()
    fleet = fleet_of(args)
    scene = SceneInfo.from_scenario(_load(args)) if args.scenario is not None else None
    v = viz_options(args, True, "")
    check_viz_port(v)
    check_out_dir("--server-log", args.server_log)
    connect = [_check_endpoint("--connect", c) for c in (args.connect or [DEFAULT_LISTEN])]
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        # the server first: fork before zenoh starts its threads, and from this (main) thread, which
        # its PR_SET_PDEATHSIG follows
        server = MeshcatServer(v.host, v.port, log=args.server_log)
        try:
            server.start()
            print(f"viewer: {server.web_url}", flush=True)
            log.info("viz: fleet %s on %s, %s", fleet, ", ".join(connect),
                     f"scenario {scene.name}" if scene else "scene from the world")
            bus = open_bus(args, timeout_s=args.start_timeout, stop=stop)
            try:
                watcher = SwarmWatcher(bus, fleet, Viewer(server, scene, rings=v.rings), scene=scene)
                watcher.start()
                bus.token(keys.alive(fleet, "viz"))
                while watcher.running and not stop.wait(0.5):
                    pass
                watcher.close()
            finally:
                bus.close()
        except ServerError as e:
            raise Failure(f"viewer: {e}") from None
        finally:
            server.stop()
    log.info("viz: %d snapshots, %d drawn, %d skipped, %d bad messages", watcher.received, watcher.drawn,
             watcher.skipped, watcher.bad.count)
    if watcher.error is not None:
        raise Failure(f"the viewer stopped: {watcher.error}")
    return EXIT_INTERRUPTED


class ViewerUrl:
    """`swarm up`: the URL the viz child prints (`viewer: URL`) in its log, read without blocking;
    then whether the viz child exits early (the swarm runs on without it)."""

    PATTERN = re.compile(r"^viewer: (\S+)$", re.M)

    def __init__(self, child, timeout_s: float, offset: int = 0):
        self.child = child
        self.offset = offset  # where this run's lines start in the log
        self.end = time.monotonic() + timeout_s
        self.url: str | None = None
        self.done = False

    def poll(self) -> str | None:
        """A line to show when something happened (the URL, or the viewer's end), else None."""
        from swarm import launch

        if self.done:
            return None
        rc = self.child.proc.poll()
        if self.url is None:
            m = self.PATTERN.search(self._text())
            if m:
                self.url = m.group(1)
                return f"viewer: {self.url}"
            if rc is None and time.monotonic() > self.end:
                self.done = True
                return f"viewer: no URL after the start timeout; see {self.child.log}"
        if rc is None:
            return None
        self.done = True
        tail = " | ".join(self._text().strip().splitlines()[-2:])
        return f"viewer: the viz process exited ({launch._rc(rc)}); the swarm goes on without it: {tail}"

    def _text(self) -> str:
        try:
            with open(self.child.log, "rb") as f:
                f.seek(self.offset)
                return f.read().decode(errors="replace")
        except OSError:
            return ""


# --------------------------------------------------------------------------- swarm up


def cmd_up(args, started: float) -> int:
    from swarm import console, launch, protocol
    from swarm.launch import RestartPolicy, Supervisor, UpOptions

    scn = _load(args)  # bad input is refused here, before anything starts
    from swarm.scenario_file import advisories

    for note in advisories(scn):
        print(f"swarm up: warning: {note}", file=sys.stderr)
    fleet = fleet_of(args)
    if args.connect and args.listen:
        raise BadInput("give --listen (start a router) or --connect (join one), not both")
    for ep in args.listen or []:
        _check_endpoint("--listen", ep)
    for ep in args.connect or []:
        _check_endpoint("--connect", ep)
    check_out_dir("--metrics", args.metrics)
    check_out_dir("--trace", args.trace)
    check_out_dir("--record", args.record)
    args.record_hz = record_rate(args)
    if args.mode == "lockstep" and args.speed != 1.0:
        log.warning("--speed %g has no effect in lock-step, which runs as fast as the robots answer; "
                    "it applies with --mode realtime", args.speed)
    if args.log_dir is not None and Path(args.log_dir).exists() and not Path(args.log_dir).is_dir():
        raise BadInput(f"--log-dir {args.log_dir}: exists and is not a directory")
    if args.zenoh_config is not None and not Path(args.zenoh_config).is_file():
        raise BadInput(f"--zenoh-config {args.zenoh_config}: no such file")
    log_dir = Path(args.log_dir or os.path.join(tempfile.gettempdir(), f"swarm-{fleet}-{os.getpid()}"))
    metrics_path = (args.metrics or log_dir / "metrics.json").absolute()
    viz = viz_options(args, not args.no_viz, "has no effect with --no-viz")
    if viz is not None:
        viz = VizOptions(viz.host, viz.port, viz.rings, str((log_dir / "viz-server.log").absolute()))
    opts = UpOptions(
        robots=scn.n, scenario_args=scenario_args(args), mode=args.mode, speed=args.speed, fleet=fleet,
        listen=None if args.connect else (args.listen[0] if args.listen else DEFAULT_LISTEN),
        connect=args.connect[0] if args.connect else None,
        zenoh_config=str(Path(args.zenoh_config).absolute()) if args.zenoh_config else None,
        multicast=args.multicast, metrics=str(metrics_path),
        trace=str(Path(args.trace).absolute()) if args.trace else None, start_timeout=args.start_timeout,
        tick_timeout=args.tick_timeout, watchdog=args.watchdog,
        restart=RestartPolicy(args.restarts, args.restart_window), viz=viz)
    plan = launch.make_plan(opts)
    if args.dry_run:
        print(plan.describe())
        return EXIT_OK
    if viz is not None:
        check_viz_port(viz)
    if plan.router is not None:
        _check_listen_free(opts.listen)
    log_dir.mkdir(parents=True, exist_ok=True)
    try:  # whatever is read back at the end must be this run's: never an earlier run's file
        metrics_path.unlink(missing_ok=True)
    except OSError as e:
        raise BadInput(f"--metrics {metrics_path}: cannot replace it: {e.strerror or e}") from None
    launch.compile_project()
    status = console.StatusLine(enabled=not args.quiet, log_every=2.0)
    say = (lambda text: None) if args.quiet else (lambda text: status.note(text))
    viewer: list[ViewerUrl] = []

    def watch_viewer() -> None:
        """The viewer's URL (on stdout, even with --quiet: it is what the user opens), or why not."""
        note = viewer[0].poll() if viewer else None
        if note is not None:
            status.clear()
            print(note, flush=True)
    interrupted = False
    failure: str | None = None
    launched_s = None
    say(f"swarm up: {scn.n} robots, scenario {scn.name}, {args.mode}, dt {scn.dt:g} s, "
        f"{'governor on' if scn.control.governor else 'governor off'}; logs in {log_dir}")
    recorder = None
    with StopEvent(hard_second=False) as stop, Supervisor(plan, log_dir) as sup:
        bus = None
        try:
            t0 = time.monotonic()  # launch time: from the first process started to every token seen
            if plan.router is not None:
                sup.start(plan.router)
            if plan.viz is not None:
                viz_log = sup.log_of(plan.viz)
                offset = viz_log.stat().st_size if viz_log.exists() else 0
                viewer.append(ViewerUrl(sup.start(plan.viz), args.start_timeout, offset))
            bus = open_bus(argparse.Namespace(connect=[plan.endpoint], zenoh_config=opts.zenoh_config,
                                              multicast=opts.multicast), timeout_s=15.0, stop=stop)
            alive: set[str] = set()
            progress: list = [None]
            bus.watch_alive(keys.alive_any(fleet), lambda k, up: alive.add(k) if up else alive.discard(k))
            bus.subscribe(keys.world_progress(fleet), lambda k, b: progress.__setitem__(0, b))
            if args.record is not None:  # subscribed before the world starts: its first snapshot is recorded
                recorder = _start_recorder(bus, fleet, scn, args)
            sup.start(plan.world)
            sup.start(plan.leader)
            for spec in plan.robots:
                sup.start(spec)
            want = {keys.alive(fleet, "world"), keys.alive(fleet, "leader")} | \
                   {keys.alive(fleet, "robot", i) for i in range(scn.n)}
            end = time.monotonic() + args.start_timeout
            while not want <= alive and not stop.is_set():
                if time.monotonic() > end:
                    missing = sorted(want - alive, key=lambda k: (len(k), k))
                    names = [k.split("/alive/")[1].replace("/", " ") for k in missing]
                    raise launch_failure(f"not alive after {args.start_timeout:g} s: "
                                         f"{', '.join(names[:12])}{' ...' if len(names) > 12 else ''}", sup)
                if sup.children["world"].proc.poll() is not None:
                    raise launch_failure("the world process exited during start-up", sup, "world")
                status.update(f"starting: {len(alive & want)}/{len(want)} processes alive", force=False)
                watch_viewer()
                time.sleep(0.02)
            if want <= alive:  # a launch cut short (Ctrl-C) has no launch time
                launched_s = time.monotonic() - t0
            if not stop.is_set():
                say(f"all {len(want)} processes alive after {launched_s:.2f} s; router at {plan.endpoint}")
            world = sup.children["world"]
            while world.proc.poll() is None:
                if stop.is_set():
                    interrupted = True
                    sup.signal("world", signal.SIGTERM)  # the world writes metrics with interrupted: true
                    sup.wait("world", 3.0)
                    break
                for note in sup.check_robots():
                    say(note)
                watch_viewer()
                if progress[0] is not None:
                    try:
                        p = protocol.decode(progress[0], "progress")
                        status.update(_progress_line(p))
                    except protocol.ProtocolError:
                        pass
                stop.wait(0.1)
            if not interrupted and world.proc.returncode not in (0, EXIT_INTERRUPTED):
                failure = f"the world process failed ({launch._rc(world.proc.returncode)}); see {world.log}"
            if recorder is not None:  # the world's last messages may still be on their way
                recorder.wait_for(scn.steps * scn.dt if not interrupted else None, timeout_s=1.0)
        except Failure as e:
            failure = str(e)
        finally:
            if bus is not None:
                bus.close()
            sup.shutdown(first=("world",))
    status.close()
    interrupted = interrupted or stop.is_set()
    metrics = _read_metrics(metrics_path)
    if metrics is None:
        metrics = _empty_metrics(scn, args.mode)
        if failure is None and not interrupted:
            failure = f"the world wrote no metrics; see {log_dir}/world.log"
    metrics["wall_s"] = time.perf_counter() - started
    metrics["interrupted"] = bool(interrupted or metrics.get("interrupted"))
    metrics["launch_s"] = launched_s
    metrics["processes"] = len(plan.processes)
    metrics["robot_restarts"] = sup.restarted
    _write_json(metrics_path, metrics)
    record_note = _close_recorder(recorder, metrics, args.record)
    if not args.quiet:
        from swarm.cli import summary

        print(summary(metrics, scn.name))
        print(f"metrics: {metrics_path}")
        if record_note:
            print(record_note)
    if failure is not None:
        print(f"swarm up: failed: {failure}", file=sys.stderr)
        return EXIT_INTERRUPTED if interrupted else EXIT_FAILURE
    return EXIT_INTERRUPTED if metrics["interrupted"] else EXIT_OK


def _start_recorder(bus, fleet: str, scn, args):
    from swarm.record import BusRecorder, Recorder, RecordError

    try:
        return BusRecorder(bus, fleet, Recorder(args.record, scn, args.record_hz, source=args.mode, fleet=fleet),
                           commands_from_snapshots=args.mode == "lockstep")
    except RecordError as e:
        raise Failure(str(e)) from None


def _close_recorder(recorder, metrics: dict, path) -> str | None:
    """Finish the recording with the run's final metrics (those written to --metrics)."""
    if recorder is None:
        return None
    recorder.close(metrics)
    missed = f", {recorder.snapshots_missed} lost on the way" if recorder.snapshots_missed else ""
    bad = f", {recorder.bad} bad messages dropped" if recorder.bad else ""
    return f"record:  {path} ({recorder.snapshots} snapshots received{missed}{bad})"


def launch_failure(text: str, sup, name: str | None = None) -> Failure:
    if name is not None and name in sup.children:
        tail = sup.children[name].log.read_text(errors="replace").strip().splitlines()[-5:]
        if tail:
            text += "\n  " + "\n  ".join(tail)
    return Failure(text)


def _progress_line(p) -> str:
    from swarm import console

    dist = "-" if p.min_distance < 0 else f"{p.min_distance:.3f} m"
    return (f"{console.bar(p.t / p.duration if p.duration else 1)} t {p.t:7.2f}/{p.duration:.1f} s"
            f"  alive {p.alive}/{p.robots}  converged {p.converged}  frozen {p.frozen}  min distance {dist}"
            f"  misses {p.misses}  bad {p.bad}")


def _read_metrics(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _empty_metrics(scn, mode: str) -> dict:
    from world.referee import Referee

    return Referee(scn).metrics(0.0, True, mode)
