"""What every `swarm` command shares: exit codes and errors, the stop signal, the zenoh session,
the scenario from the command line, output checks. Imported by the parser and the commands alike
(it imports neither), so no command reaches back into another.
"""

from __future__ import annotations

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
from typing import Literal, overload

from swarm.launch.plan import DEFAULT_LISTEN, VIZ_HOST, VizOptions
from swarm.net.bus import ROUTER_RUNTIME, ZENOH_RUNTIME
from swarm.proto import keys
from swarm.core.errors import SwarmError

EXIT_OK, EXIT_FAILURE, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130
# a robot process whose run cannot go on for a reason a restart would meet again (the run's own law raised, gave
# a non-finite command, or this machine's copy differs): swarm up never restarts it and ends the run with its reason
EXIT_REFUSED = 4


class Refused(SwarmError, RuntimeError):
    """The process refuses its run (EXIT_REFUSED); the message says why."""
SAY_WAIT_S = 3.0  # s: a client still without its router says why after this long (then waits on, or gives up)
log = logging.getLogger("swarm")


class BadInput(SwarmError):
    """A user error: printed as one line, exit code 2."""


class Failure(SwarmError):
    """A runtime failure: printed as one line, exit code 1."""


# --------------------------------------------------------------------------- shared pieces


class StopEvent:
    """SIGINT, SIGTERM and SIGHUP (the terminal closed; not under nohup) set a threading.Event that the process's loop polls. A second Ctrl-C stops at
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
        # SIGHUP unless ignored (nohup): a run started with nohup outlives the terminal, as it asked
        caught = (signal.SIGINT, signal.SIGTERM) + (() if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN else
                                                    (signal.SIGHUP,))
        self._old = {s: signal.signal(s, self._handle) for s in caught}
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
                timer = threading.Timer(self.exit_after_s, hard_exit, (self.exit_after_s,))
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


def hard_exit(after_s: float) -> None:
    print(f"swarm: the clean shutdown took more than {after_s:g} s; exiting now", file=sys.stderr, flush=True)
    os._exit(EXIT_INTERRUPTED)


def fleet_of(args) -> str:
    try:
        return keys.check_fleet(args.fleet)
    except keys.KeyError_ as e:
        raise BadInput(f"--fleet: {e}") from None


def check_endpoint(flag: str, ep: str) -> str:
    proto, sep, rest = ep.partition("/")
    host, colon, port = rest.rpartition(":")
    if not sep or not proto or not colon or not host:
        raise BadInput(f"{flag} {ep!r}: expected an endpoint like tcp/127.0.0.1:7447")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise BadInput(f"{flag} {ep!r}: the port must be an integer in 1..65535, got {port!r}")
    return ep


def bind_error(host: str, port: int) -> str | None:
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


def check_listen_free(ep: str) -> None:
    """A router that cannot bind its port exits (its log says why), and meanwhile the processes started
    after it join whatever holds the port (another swarm's router): refuse before anything starts. A
    program that takes the port between this check and the bind gets a run that fails ("router lost"),
    and processes that keep their ingress checks (--router-checks ZID names swarm up's own router)."""
    proto, _, rest = ep.partition("/")
    if proto not in ("tcp", "tls"):
        return
    host, _, port = rest.rpartition(":")
    error = bind_error(host.strip("[]"), int(port))
    if error is not None:
        raise BadInput(f"--listen {ep}: cannot listen there ({error}); is another swarm or router running? "
                       "Give another port with --listen, or join it with --connect")


def open_bus(args, mode: str = "client", listen: list[str] | None = None, timeout_s: float = 10.0,
             stop: threading.Event | None = None, lean: bool = False, role: str | None = None,
             robot_id: int | None = None):
    """A ZenohBus for this process; a client retries until its router answers or timeout_s passes.

    With --secure DIR the session is identity `role` (robot `robot_id`) of that fleet directory (or
    that identity's own folder): mutual TLS with its certificate, which the router's access control
    knows by name; the endpoints must then be tls/ and default to the identity's config.

    lean: zenoh's lean runtime (swarm.net.bus.ZENOH_RUNTIME, docs/runtime.md), for the many small robot
    processes. Not for the world: there one worker thread both receives (running our callbacks, which
    need the GIL) and sends, and a burst of reliable puts from the main thread (which holds the GIL
    while it waits for room in the send queue) stalled it until the router closed the link after 5 s
    ("Unable to push non droppable network message"), once per ~2000 ticks at N = 37. A router gets
    swarm.net.bus.ROUTER_RUNTIME. A ZENOH_RUNTIME of the user's own environment wins.
    """
    if lean:
        os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME)  # before zenoh starts its runtime
    elif mode == "router":
        os.environ.setdefault("ZENOH_RUNTIME", ROUTER_RUNTIME)
    from swarm.net.bus import ZenohBus, zenoh_config

    secure_dir = getattr(args, "secure", None)
    cfg_file = getattr(args, "zenoh_config", None)
    if secure_dir is not None and cfg_file is not None:
        raise BadInput("give --secure (the fleet's certificates and access control) or --zenoh-config, not both")
    connect = [check_endpoint("--connect", c) for c in (args.connect or [])]
    if mode == "client" and not connect and secure_dir is None:
        connect = [DEFAULT_LISTEN]
    if cfg_file is not None and not Path(cfg_file).is_file():
        raise BadInput(f"--zenoh-config {cfg_file}: no such file")
    if secure_dir is not None:
        secure_base(secure_dir, role, robot_id, connect, listen)  # refuse a bad directory or identity now
    start = time.monotonic()
    end = start + timeout_s
    told = False  # a client said why it still waits
    # --router-checks ZID: the checks are left to router ZID, and kept if this session's router is another
    checker = getattr(args, "router_checks", None) if mode == "client" else None
    while True:
        try:
            base = secure_base(secure_dir, role, robot_id, connect, listen) if secure_dir is not None else None
            conf = zenoh_config(mode, connect=None if base is not None else connect,
                                listen=None if base is not None else listen, config_file=cfg_file,
                                multicast=getattr(args, "multicast", False), base=base,
                                ingress_checks=checker is None,
                                zid=getattr(args, "zid", None) if mode == "router" else None)
        except BadInput:
            raise
        except Exception as e:
            raise BadInput(f"zenoh configuration: {zenoh_error(e)}") from None
        try:
            bus = ZenohBus(conf)
        except Exception as e:
            where = ", ".join(listen or []) if mode == "router" else ", ".join(connect) or "the identity's router"
            if mode != "client":
                raise Failure(f"cannot open a zenoh {mode} session on {where}: {zenoh_error(e)}") from None
            now = time.monotonic()
            if now >= end or (stop is not None and stop.is_set()) or (not told and now - start >= SAY_WAIT_S):
                from swarm.net import reach

                why = reach.explain(conf)
                hopeless = why is not None and ("unknown" in why or "certificate" in why or "TLS" in why)
                if hopeless:
                    end = now  # no router will change that: say it now
                if now < end and not (stop is not None and stop.is_set()):
                    log.warning("still no router after %g s, waiting up to %.1f s more: %s", SAY_WAIT_S, end - now,
                                why or zenoh_error(e))
                    told = True
                else:
                    hint = " (is a router running there? `swarm router --listen ENDPOINT` starts one)" \
                        if why is None or "refused" in why else ""
                    within = "" if hopeless else f" within {timeout_s:g} s"
                    raise Failure(f"cannot open a zenoh client session{within}: "
                                  f"{why or f'{where}: {zenoh_error(e)}'}{hint}") from None
            time.sleep(0.1)
            continue
        if checker is None:
            return bus
        routers = [str(z) for z in bus.session.info.routers_zid()]
        if routers == [checker]:
            return bus
        bus.close()  # not the router that checks: this session checks what comes in itself
        log.warning("--router-checks %s: this session's router is %s, not it: zenoh's ingress checks stay on",
                    checker, ", ".join(routers) or "none")
        checker = None


_RUST_WHERE = re.compile(r"\s+at\s+\S+\.rs:\d+\.?")


def zenoh_error(e: Exception) -> str:
    """zenoh's error text without the Rust source locations it appends (`at /root/.cargo/...rs:447.`)."""
    return _RUST_WHERE.sub("", str(e)).strip()


def secure_base(directory: str, role: str | None, robot_id: int | None, connect: list[str], listen):
    """The zenoh config of identity `role` in a --secure directory (BadInput if it is not one)."""
    from swarm.net import secure

    if role is None:
        raise BadInput("--secure: this command has no role in the fleet")
    try:
        return secure.secure_config(directory, role, robot_id, connect=connect or None, listen=listen)
    except secure.SecureError as e:
        raise BadInput(f"--secure {directory}: {e}") from None


def overrides(args):
    """The scenario flags of a command line as swarm.core.scenario_file.Overrides (absent: None)."""
    from swarm.core.scenario_file import Overrides

    dt = getattr(args, "dt", None)
    rate = getattr(args, "rate", None)
    if rate is not None:
        if dt is not None:
            raise BadInput("give --dt or --rate, not both")
        dt = 1.0 / rate
    return Overrides(robots=getattr(args, "robots", None), seed=getattr(args, "seed", None),
                     duration=getattr(args, "duration", None), dt=dt, governor=getattr(args, "governor", None),
                     faults=getattr(args, "faults", None), drop=getattr(args, "drop", None),
                     kill=getattr(args, "kill", None))


def load_scenario(args, quiet: bool = False):
    """The scenario of the command line (a flag beats the file, which beats the built-in default);
    quiet: no progress lines (the child processes of swarm up, --quiet)."""
    from swarm.core import scenario_file

    quiet = quiet or getattr(args, "quiet", False)
    return scenario_file.load(args.scenario, overrides(args), progress=scenario_file.silent if quiet else None)


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
    if getattr(args, "faults", None) is not None:
        out += ["--faults", str(Path(args.faults).absolute())]
    if getattr(args, "drop", None) is not None:
        out += ["--drop", repr(args.drop)]
    if getattr(args, "kill", None) is not None:
        out += ["--kill", args.kill]
    return tuple(out)


def setup_logging(quiet: bool = False) -> None:
    """Log lines on stderr at --log-level (SWARM_LOG_LEVEL, which swarm up hands its children), else INFO
    (WARNING when quiet)."""
    level = os.environ.get("SWARM_LOG_LEVEL", "").upper()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_Printable("%(asctime)s %(name)s %(levelname)s: %(message)s"))
    logging.basicConfig(level=getattr(logging, level) if level in ("DEBUG", "INFO", "WARNING", "ERROR")
                        else logging.WARNING if quiet else logging.INFO, handlers=[handler])


class _Printable(logging.Formatter):
    """Log lines with the control characters of their text escaped (a forged estop reason, key or payload quoted
    in a refusal must not retitle the terminal or erase lines); line breaks and a traceback's stay."""

    def formatMessage(self, record: logging.LogRecord) -> str:
        from swarm.cli.console import printable

        return printable(super().formatMessage(record), keep="\n\t")


def write_json(path: Path, obj: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, allow_nan=False) + "\n")
    tmp.replace(path)


def clear_metrics(metrics_path: Path, log_dir: Path) -> None:
    """Before a run of swarm up: no earlier run's metrics at --metrics or in the log directory (what is read
    back at the end must be this run's)."""
    for path in dict.fromkeys((metrics_path, (log_dir / "metrics.json").absolute())):
        try:
            path.unlink(missing_ok=True)
        except OSError as e:
            raise BadInput(f"--metrics {path}: cannot replace it: {e.strerror or e}") from None


def write_metrics(metrics_path: Path, log_dir: Path, metrics: dict) -> None:
    """After a run of swarm up: the metrics at metrics_path, and a copy in the log directory when --metrics
    put them elsewhere (docs/metrics.md). A copy that cannot be written is said on stderr; the run stands."""
    from swarm.core.metrics import in_contract_order

    metrics = in_contract_order(metrics)
    write_json(metrics_path, metrics)
    copy = (log_dir / "metrics.json").absolute()
    if copy != metrics_path:
        try:
            write_json(copy, metrics)
        except OSError as e:
            print(f"swarm up: could not write the log directory's copy of the metrics, {copy}: {e.strerror or e}",
                  file=sys.stderr)


def record_rate(args) -> float:
    """--record-hz (default swarm.view.record.DEFAULT_RECORD_HZ), refused without --record rather than ignored; a
    --record path not named *.mcap refused."""
    if args.record_hz is not None and args.record is None:
        raise BadInput("--record-hz needs --record PATH.mcap")
    if args.record is not None and args.record.suffix.lower() != ".mcap":
        raise BadInput(f"--record {args.record}: a recording is an MCAP file, name it *.mcap (swarm report, swarm "
                       "replay and Foxglove know it by that)")
    if args.record_hz is None:
        from swarm.view.record import DEFAULT_RECORD_HZ

        return DEFAULT_RECORD_HZ
    return args.record_hz


def check_out_dir(flag: str, path: Path | None) -> None:
    """An output file's directory must exist (and be a directory, where this user can write), and the file
    must not be a directory: said before the run, not after it."""
    if path is None:
        return
    if not path.parent.exists():
        raise BadInput(f"{flag} {path}: directory {path.parent} does not exist")
    if not path.parent.is_dir():
        raise BadInput(f"{flag} {path}: {path.parent} is not a directory")
    if path.is_dir():
        raise BadInput(f"{flag} {path}: is a directory (give a file name)")
    if flag == "--trace" and path.suffix != ".npz":  # numpy would write PATH.npz, not the name given
        raise BadInput(f"--trace {path}: a trace is a numpy .npz file, name it *.npz")
    check_writable(flag, path, path.parent)


def make_log_dir(log_dir: Path, given: bool) -> None:
    """The run's log folder (--log-dir's parents too), or BadInput saying why not, before any process starts."""
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise BadInput(f"{'--log-dir ' if given else 'the log folder '}{log_dir}: cannot make it "
                       f"({e.strerror or e})") from None
    check_writable("--log-dir" if given else "the log folder", log_dir, log_dir)


def check_writable(flag: str, given: Path, directory: Path) -> None:
    """BadInput naming `flag given` unless a file can be made in `directory` (a read-only mount, a folder of
    another user, a pseudo file system such as /proc: each found by making one, and removing it)."""
    try:
        with tempfile.TemporaryFile(dir=directory):
            pass
    except OSError as e:
        raise BadInput(f"{flag} {given}: cannot write in {directory} ({e.strerror or e})") from None


@overload
def viz_options(args, enabled: Literal[True], otherwise: str, extra: tuple[tuple[str, object], ...] = ()) -> VizOptions:
    ...


@overload
def viz_options(args, enabled: bool, otherwise: str, extra: tuple[tuple[str, object], ...] = ()) -> VizOptions | None:
    ...


def viz_options(args, enabled: bool, otherwise: str, extra: tuple[tuple[str, object], ...] = ()) -> VizOptions | None:
    """The viewer's options from --viz-host/--viz-port/--viz-rings (types already checked by the
    parser); None when the viewer is off, and then any of those flags is bad input ("--viz-port
    `otherwise`")."""
    given = (("--viz-host", args.viz_host), ("--viz-port", args.viz_port), ("--viz-rings", args.viz_rings or None),
             ("--viz-timeout", getattr(args, "viz_timeout", None)), *extra)
    if not enabled:
        for flag, value in given:
            if value is not None:
                raise BadInput(f"{flag} {otherwise}")
        return None
    return VizOptions(host=args.viz_host or VIZ_HOST, port=args.viz_port or 0, rings=bool(args.viz_rings),
                      timeout=getattr(args, "viz_timeout", None) or 60.0)


def check_resources(robots: int, plan, dry_run: bool):
    """This machine's memory and cores for `robots` robot processes and the plan's router and viewer
    (swarm.launch.capacity.Resources): the warning on stderr, BadInput when they do not fit (a dry run prints its
    plan first, then refuses as the run would). Returns the Resources, for the dry run's line."""
    from swarm.launch.capacity import Resources

    res = Resources(robots, router=plan.router is not None, viewer=plan.viz is not None)
    if res.refusal() is not None and not dry_run:
        raise BadInput(res.refusal())
    if res.warning() is not None:
        print(f"swarm up: warning: {res.warning()}", file=sys.stderr)
    return res


def check_viz_apart(v: VizOptions | None, router_listen: str | None) -> None:
    """--viz-port on the port this command's router listens on: the second to bind would fail after the start
    (the router first, so the viewer); refuse before anything starts, the dry run included."""
    if v is None or not v.port or not router_listen:
        return
    proto, _, rest = router_listen.partition("/")
    host, _, port = rest.rpartition(":")
    if proto not in ("tcp", "tls") or not port.isdigit() or int(port) != v.port:
        return  # the viewer is HTTP: only a TCP listener on its port can clash
    host, wild = host.strip("[]"), ("0.0.0.0", "::", "")
    if host in wild or v.host in wild or host == v.host or {host, v.host} <= {"127.0.0.1", "localhost"}:
        raise BadInput(f"--viz-port {v.port}: the router listens on that port ({router_listen}); "
                       "give the viewer another port, or leave --viz-port out for a free one")


def check_viz_port(v: VizOptions) -> None:
    """A fixed --viz-port must be free now (a clear exit 2 rather than a viewer that fails later)."""
    if not v.port:
        return
    error = bind_error(v.host, v.port)
    if error is not None:
        raise BadInput(f"--viz-port {v.port}: cannot listen on {v.host}:{v.port} ({error})")


def close_recorder(recorder, metrics: dict, path) -> str | None:
    """Finish the recording with the run's final metrics (those written to --metrics); what it holds, said:
    snapshots received, those kept (the --record-hz grid's: 25 Hz unless said) and any lost or bad."""
    from swarm.view.record import TOPIC_SNAPSHOT

    if recorder is None:
        return None
    recorder.close(metrics)
    missed = f", {recorder.snapshots_missed} lost on the way" if recorder.snapshots_missed else ""
    bad = f", {recorder.bad} bad messages dropped" if recorder.bad else ""
    kept = recorder.rec.counts[TOPIC_SNAPSHOT]
    return f"record:  {path} ({recorder.snapshots} snapshots received, {kept} of them kept{missed}{bad})"


def read_metrics(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def refuse_a_taken_fleet(bus, fleet: str, endpoint: str) -> None:
    """BadInput when a world of `fleet` is alive on the router: a second swarm on one fleet takes the other's
    robots, leader and run (both runs fail, neither says why)."""
    from swarm.proto import keys

    if bus.alive_now(keys.alive_any(fleet, "world")):
        raise BadInput(f"fleet {fleet!r} on {endpoint} already has a world running (another swarm up or swarm world; "
                       f"`swarm ps --connect {endpoint} --fleet {fleet}` lists it): give this run its own --fleet NAME, "
                       "or stop that one first")
