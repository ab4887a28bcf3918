"""`swarm up`: the router, the world, the leader, one process per robot and the viewer, supervised to the end."""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import cast

from swarm.cli.parser import given
from swarm.cli.common import (EXIT_INTERRUPTED, EXIT_OK, BadInput, Failure, StopEvent, check_endpoint,
                              check_listen_free, check_out_dir, check_resources, check_viz_apart, check_viz_port,
                              clear_metrics, fleet_of, load_scenario, make_log_dir, open_bus, record_rate,
                              scenario_args, viz_options, write_metrics, close_recorder, read_metrics,
                              refuse_a_taken_fleet)
from swarm.cli import console
from swarm.cli.console import EstopFollower, cpu_counters, exit_status, progress_line, steal_pct, summary
from swarm.core.clock import WALL
from swarm.core.metrics import violations
from swarm.launch.capacity import Waves
from swarm.launch.plan import DEFAULT_LISTEN, RestartPolicy, UpOptions, VizOptions, make_plan
from swarm.process import die_with_parent
from swarm.launch.progress_pipe import ProgressPipe
from swarm.launch.supervisor import Supervisor, compile_project, exit_text
from swarm.net import presence
from swarm.proto import keys

log = logging.getLogger("swarm")


class ViewerUrl:
    """`swarm up`: the URL the viz child prints (`viewer: URL`) in its log, read without blocking;
    then whether the viz child exits early (the swarm runs on without it)."""

    PATTERN = re.compile(r"^viewer: (\S+)$", re.M)

    def __init__(self, child, timeout_s: float, offset: int = 0, attach: str = "swarm viz --connect ENDPOINT"):
        self.child = child
        self.attach = attach  # the command that attaches a viewer later
        self.offset = offset  # where this run's lines start in the log
        self.end = time.monotonic() + timeout_s
        self.url: str | None = None
        self.done = False

    def poll(self) -> str | None:
        """A line to show when something happened (the URL, or the viewer's end), else None."""
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
                return (f"viewer: no URL after the viewer's timeout; the swarm goes on without it (see "
                        f"{self.child.log}; `{self.attach}` attaches one later)")
        if rc is None:
            return None
        self.done = True
        tail = " | ".join(self._text().strip().splitlines()[-2:])
        return (f"viewer: the viz process exited ({exit_text(rc)}); the swarm goes on without it: {tail} "
                f"(`{self.attach}` attaches one later)")

    def _text(self) -> str:
        try:
            with open(self.child.log, "rb") as f:
                f.seek(self.offset)
                return f.read().decode(errors="replace")
        except OSError:
            return ""


# --------------------------------------------------------------------------- swarm up


def python_note() -> str | None:
    """Why the robots here will run slower, if they will: their message loops or law is Python, not compiled
    (setup.py found no C compiler at install, or SWARM_PURE_PYTHON is set). None when both are compiled."""
    from swarm.core import fastlaw
    from swarm.proto import protocol

    missing = [what for what, ok in (("message loops", protocol._wire is not None), ("law", fastlaw.COMPILED)) if not ok]
    if not missing:
        return None
    why = "SWARM_PURE_PYTHON is set" if os.environ.get("SWARM_PURE_PYTHON") else \
        "no C compiler was found when swarm was installed: install gcc and run pip install -e . again"
    return (f"note: the robots' {' and '.join(missing)} {'runs' if missing == ['law'] else 'run'} as Python ({why}); "
            "a robot's period costs about a third more CPU (docs/performance.md)")


def refuse_unused_flags(args) -> None:
    """BadInput for a flag of another use, given to a simulated swarm: it would be dropped in silence."""
    for flag, value in (("--initial-pose", args.initial_pose), ("--no-preflight", args.no_preflight or None)):
        if value is not None:
            raise BadInput(f"{flag} needs --inventory (real robots; a simulated swarm starts where the scenario says)")
    if args.drive != "ros2":
        for flag in given(args, "ros_flavor", "twist", "domain", "rmw_zenoh_attachment", "distro"):
            raise BadInput(f"{flag} needs --drive ros2 (the simulated ROS 2 robots' wire)")


def fresh_zid() -> str:
    """A random zenoh id for the embedded router (32 hex digits, the first not 0: as zenoh writes it)."""
    import secrets

    return format(secrets.randbits(128) | 1 << 127, "032x")


def cmd_up(args, started: float) -> int:
    die_with_parent()  # started by another swarm command (swarm campaign --up): dies with it, however it dies
    if args.inventory is not None:
        from swarm.cli.up_inventory import cmd_up_inventory

        return cmd_up_inventory(args, started)
    refuse_unused_flags(args)
    scn = load_scenario(args)  # bad input is refused here, before anything starts
    if scn.control.law is not None:  # a law of one's own that does not load (a syntax error, its signature):
        from swarm.core import userlaw  # refused here, as swarm sim does, not by every robot once it started

        try:
            userlaw.load(scn.control.law)
        except userlaw.LawError as e:
            raise BadInput(str(e)) from None
    cpu0 = cpu_counters()
    from swarm.core.scenario_file import advisories

    for advice in advisories(scn):
        print(f"swarm up: warning: {advice}", file=sys.stderr)
    fleet = fleet_of(args)
    if args.connect and args.listen:
        raise BadInput("give --listen (start a router) or --connect (join one), not both")
    for ep in args.listen or []:
        check_endpoint("--listen", ep)
    for ep in args.connect or []:
        check_endpoint("--connect", ep)
    check_out_dir("--metrics", args.metrics)
    check_out_dir("--trace", args.trace)
    check_out_dir("--record", args.record)
    args.record_hz = record_rate(args)
    if args.mode == "realtime" and not scn.control.governor:
        print("swarm up: warning: real time without the governor (control.governor = false): the safety rule that "
              "keeps late commands from driving robots into each other needs it (docs/runtime.md, \"The safety "
              "invariant\"); robots may collide when messages come late", file=sys.stderr)
    if args.mode == "realtime" and not args.dry_run and args.drive == "sim":
        from swarm.launch.capacity import verdict

        note = verdict(scn.n, scn.dt, args.speed)
        if note is not None:
            print(f"swarm up: warning: {note}", file=sys.stderr)
    if args.mode == "lockstep" and args.speed != 1.0:
        raise BadInput(f"--speed {args.speed:g}: lock-step runs as fast as the robots answer, so it takes no speed; "
                       "--speed applies with --mode realtime")
    if args.log_dir is not None and Path(args.log_dir).exists() and not Path(args.log_dir).is_dir():
        raise BadInput(f"--log-dir {args.log_dir}: exists and is not a directory")
    if args.log_dir is not None and not Path(args.log_dir).absolute().parent.is_dir():
        raise BadInput(f"--log-dir {args.log_dir}: directory {Path(args.log_dir).absolute().parent} does not exist "
                       "(the log folder itself is made if missing, as with --metrics its folder must exist)")
    if args.zenoh_config is not None and not Path(args.zenoh_config).is_file():
        raise BadInput(f"--zenoh-config {args.zenoh_config}: no such file")
    secure_endpoint = _check_secure(args, scn.n) if args.secure else None
    if args.drive == "ros2":
        if args.mode != "realtime":
            raise BadInput("--drive ros2 needs --mode realtime (odometry carries no tick)")
        try:
            from swarm.proto import ros2

            ros2.require()
        except ImportError as e:
            raise BadInput(f"--drive ros2: {e}") from None
    log_dir = Path(args.log_dir or os.path.join(tempfile.gettempdir(), f"{LOG_PREFIX}{fleet}-{os.getpid()}"))
    metrics_path = (args.metrics or log_dir / "metrics.json").absolute()
    viz = viz_options(args, not args.no_viz, "has no effect with --no-viz")
    if viz is not None:
        viz = VizOptions(viz.host, viz.port, viz.rings, str((log_dir / "viz-server.log").absolute()), viz.timeout)
    opts = UpOptions(
        robots=scn.n, scenario_args=scenario_args(args), mode=args.mode, speed=args.speed, fleet=fleet,
        listen=None if args.connect else (args.listen[0] if args.listen else (None if args.secure else DEFAULT_LISTEN)),
        secure=str(Path(args.secure).absolute()) if args.secure else None, secure_endpoint=secure_endpoint,
        connect=args.connect[0] if args.connect else None, router_zid=None if args.connect else fresh_zid(),
        zenoh_config=str(Path(args.zenoh_config).absolute()) if args.zenoh_config else None,
        multicast=args.multicast, metrics=str(metrics_path),
        trace=str(Path(args.trace).absolute()) if args.trace else None, start_timeout=args.start_timeout,
        tick_timeout=args.tick_timeout, lost_timeout=args.lost_timeout, watchdog=args.watchdog,
        restart=RestartPolicy(args.restarts, args.restart_window), viz=viz, drive=args.drive, ros_flavor=args.ros_flavor,
        attachment=args.rmw_zenoh_attachment, distro=args.distro,
        twist=args.twist, domain=args.domain)
    plan = make_plan(opts)
    check_viz_apart(viz, (opts.listen or plan.endpoint) if plan.router is not None else None)
    res = check_resources(scn.n, plan, args.dry_run)
    if args.dry_run:
        print(plan.describe())
        print(res.text())
        if res.refusal() is not None:  # the run would stop here: so does the dry run, after the plan
            raise BadInput(res.refusal())
        return EXIT_OK
    if viz is not None:
        check_viz_port(viz)
    if plan.router is not None:
        check_listen_free(opts.listen or plan.endpoint)
    make_log_dir(log_dir, args.log_dir is not None)
    if args.log_dir is None:
        (log_dir / LOG_MARKER).write_text("made by swarm up: removed by a later one of the same user (keeps 10)\n")
    removed = prune_logs(Path(tempfile.gettempdir()), fleet, keep=KEEP_LOGS, current=log_dir) if args.log_dir is None else 0
    clear_metrics(metrics_path, log_dir)  # whatever is read back at the end must be this run's
    compile_project()
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
    last = None  # the world's last progress message (the run as far as the launcher saw it)
    say(f"swarm up: {scn.n} robots, scenario {scn.name}, {args.mode}, dt {scn.dt:g} s, "
        f"{'governor on' if scn.control.governor else 'governor off'}; logs in {log_dir}"
        + (f" ({removed} older log folder{'s' if removed > 1 else ''} removed: the {KEEP_LOGS} newest are kept)"
           if removed else ""))
    note = python_note()
    if note is not None:
        say(note)
    recorder = None
    pipe = ProgressPipe()  # the world's progress, heard on a pipe only it can write (swarm.launch.progress_pipe)
    with StopEvent(hard_second=False) as stop, Supervisor(plan, log_dir) as sup:
        bus = None
        try:
            t0 = time.monotonic()  # launch time: from the first process started to every token seen
            if plan.router is not None:
                sup.start(plan.router)
            if plan.viz is not None:
                viz_log = sup.log_of(plan.viz)
                offset = viz_log.stat().st_size if viz_log.exists() else 0
                viz_timeout = cast(VizOptions, viz).timeout  # plan.viz is the viewer of these options
                viewer.append(ViewerUrl(sup.start(plan.viz), viz_timeout + 5.0, offset,
                                        f"swarm viz --connect {plan.endpoint} --fleet {fleet}"))
            bus = open_bus(argparse.Namespace(connect=[plan.endpoint], zenoh_config=opts.zenoh_config, secure=opts.secure,
                                              multicast=opts.multicast), timeout_s=15.0 if plan.router is not None else args.start_timeout,
                           stop=stop, role="launcher")
            if plan.router is None:  # another's router: this fleet must be free there
                refuse_a_taken_fleet(bus, fleet, plan.endpoint)
            presence.announce(bus, fleet, "launcher")  # `swarm ps` lists this process too
            estop = EstopFollower(bus, fleet, say)  # the status line says E-STOP while it is engaged
            alive: set[str] = set()
            bus.watch_alive(keys.alive_any(fleet), lambda k, up: alive.add(k) if up else alive.discard(k))
            if args.record is not None:  # subscribed before the world starts: its first snapshot is recorded
                recorder = _start_recorder(bus, fleet, scn, args)
            sup.start(plan.world, env=pipe.env(), pass_fds=pipe.fds())  # its progress on a pipe, not the network
            pipe.started()
            sup.start(plan.leader)
            robots = {keys.alive(fleet, "robot", i) for i in range(scn.n)}
            want = {keys.alive(fleet, "world"), keys.alive(fleet, "leader")} | robots
            waves = Waves(sup.start, plan.robots, args.start_timeout)
            while not want <= alive and not stop.is_set():
                if waves.step(len(alive & want), len(alive & robots)):
                    missing = sorted(want - alive, key=lambda k: (len(k), k))
                    names = [k.split("/alive/")[1].replace("/", " ") for k in missing]
                    queued = f" ({len(waves.waiting)} of them not started yet, behind these)" if waves.waiting else ""
                    raise launch_failure(f"not alive after {args.start_timeout:g} s without a new process up: "
                                         f"{', '.join(names[:12])}{' ...' if len(names) > 12 else ''}{queued}", sup)
                if sup.children["world"].proc.poll() is not None:
                    raise launch_failure("the world process exited during start-up", sup, "world")
                notes = sup.check_restarts()  # a robot or the leader that exited: restarted, or it refused the run
                if sup.fatal is not None:  # (its law does not load, say): no use waiting for it
                    raise launch_failure(f"during start-up, {sup.fatal}", sup)
                for note in notes:
                    say(note)
                status.update(f"starting: {len(alive & want)}/{len(want)} processes alive", force=False)
                watch_viewer()
                time.sleep(0.02)
            if want <= alive:  # a launch cut short (Ctrl-C) has no launch time
                launched_s = time.monotonic() - t0
            if not stop.is_set():
                say(f"all {len(want)} processes alive after {launched_s:.2f} s; router at {plan.endpoint}")
            world = sup.children["world"]
            faults = FaultActor(scn, args.mode == "lockstep", bus, fleet, sup, say, log_dir, pipe)
            while world.proc.poll() is None:
                if stop.is_set():
                    interrupted = True
                    sup.signal("world", signal.SIGTERM)  # the world writes metrics with interrupted: true
                    sup.wait("world", 3.0)
                    break
                for note in sup.check_restarts():
                    say(note)
                if sup.fatal is not None:  # a robot refused the run (its law raised, say): the run ends, named
                    failure = sup.fatal
                    sup.signal("world", signal.SIGTERM)  # the world writes the metrics it has
                    sup.wait("world", 3.0)
                    break
                watch_viewer()
                last = pipe.last or last
                faults.act(last)
                if last is not None:
                    status.update(progress_line(last, estop.engaged))
                if plan.router is not None and sup.children["router"].proc.poll() is not None:
                    failure = f"router lost at t = {_t(last)} ({exit_text(sup.children['router'].proc.returncode)})"
                    sup.signal("world", signal.SIGTERM)  # the world writes the metrics it has
                    sup.wait("world", 3.0)
                    break
                stop.wait(faults.wait_s(0.1))
            last = pipe.last or last
            rc = world.proc.returncode
            if not interrupted and failure is None and rc not in (0, 1, 3, EXIT_INTERRUPTED):
                failure = f"world lost at t = {_t(last)} ({exit_text(rc)}); see {world.log}"
            if recorder is not None:  # the world's last messages may still be on their way
                recorder.wait_for(scn.steps * scn.dt if not interrupted else None, timeout_s=1.0)
        except Failure as e:
            failure = str(e)
        finally:
            if bus is not None:
                bus.close()
            sup.shutdown(first=("world",))
            pipe.close()
    status.close()
    interrupted = interrupted or stop.is_set()
    metrics = read_metrics(metrics_path)
    ran = metrics is not None or last is not None  # the world started the run
    if metrics is None:  # the world wrote nothing: the run as far as the launcher saw it
        metrics = metrics_from_progress(scn, args.mode, last)
        if failure is None and not interrupted:
            rc = sup.children["world"].proc.returncode if "world" in sup.children else None
            failure = f"world lost at t = {_t(last)} ({exit_text(rc)}, no metrics written); see {log_dir}/world.log"
    metrics["wall_s"] = time.perf_counter() - started
    metrics["interrupted"] = bool(interrupted or (metrics.get("interrupted") and failure is None))
    if failure is not None:
        metrics["failure"] = failure
    metrics.setdefault("failure", None)
    metrics["launch_s"] = launched_s
    metrics["processes"] = len(plan.processes)
    metrics["launcher_bad_messages"] = pipe.bad
    metrics["robot_restarts"] = sup.restarted
    metrics["leader_restarts"] = sup.leader_restarted
    metrics["host_steal_pct"] = steal_pct(cpu0, cpu_counters())
    write_metrics(metrics_path, log_dir, metrics)
    record_note = close_recorder(recorder, metrics, args.record)
    if not args.quiet and ran:
        print(summary(metrics, scn.name))
        print(f"metrics: {metrics_path}")
        if args.mode == "lockstep":  # its twin: the same scenario flags (swarm sim's default scenario is not up's)
            import shlex

            print(f"the same run in swarm sim: {shlex.join(['swarm', 'sim', *scenario_args(args)])}")
    elif not args.quiet:  # nothing ran: no table of zeros that reads like a clean run
        print(f"no run: nothing was simulated (metrics with the failure: {metrics_path})")
    if record_note and not args.quiet:
        print(record_note)
    code = exit_status(metrics, args.allow_violations)
    if metrics.get("failure") and not metrics["interrupted"]:
        print(f"swarm up: failed: {metrics['failure']}", file=sys.stderr)
    elif code == 3:
        print(f"swarm up: checks failed: {', '.join(violations(metrics))} (exit 3; --allow-violations: 0)",
              file=sys.stderr)
    return code


class FaultActor:
    """`swarm up`: the scenario's scheduled kills and hangs done for real (swarm.launch.process_faults):
    lock-step by the world's tick, real time by its clock (epoch + t / speed), both told by the world over the
    progress pipe (never the network: anyone on the router could say them). Each is said on the status line and
    written to faults.log in the log directory (unix time, simulated time, what)."""

    def __init__(self, scn, lockstep: bool, bus, fleet: str, sup, say, log_dir: Path, pipe) -> None:
        from swarm.launch.process_faults import ProcessFaults

        self.pf = ProcessFaults(scn.faults, scn.dt, lockstep)
        self.lockstep, self.sup, self.say, self.dt = lockstep, sup, say, scn.dt
        self.bus, self.fleet, self.pipe = bus, fleet, pipe
        self.path = log_dir / "faults.log"
        self.epoch: tuple[float, float] | None = None  # real time: (epoch, speed) of the world's clock
        self.done: list[tuple[int, str]] = []  # (robot, the action done), in order

    def _epoch(self) -> tuple[float, float] | None:
        if self.epoch is None and self.pipe.epoch is not None:
            WALL.anchor()  # take up a step of the system clock made before this run
            self.epoch = self.pipe.epoch
        return self.epoch

    def now(self, last) -> float | None:
        """Lock-step: the world's tick; real time: the simulated time now (None before the world's clock)."""
        if self.lockstep:
            return None if last is None else last.seq
        epoch = self._epoch()
        return None if epoch is None else (WALL.time() - epoch[0]) * epoch[1]

    def act(self, last) -> None:
        if not self.pf:
            return
        now = self.now(last)
        due = self.pf.due(tick=cast("int | None", now)) if self.lockstep else self.pf.due(t=now)  # lock-step: a tick
        for robot, action in due:
            done = self.sup.fault(f"robot {robot}", action)
            self.done.append((robot, action))
            when = f"tick {now}" if self.lockstep else f"t = {now:.3f} s"
            self.say(f"fault: {done} at {when}")
            with open(self.path, "a") as f:
                f.write(f"{time.time():.6f} {when}: {done}\n")
            self._tell(cast(float, now), robot, done)  # due() returns nothing while now is None

    def _tell(self, now: float, robot: int, done: str) -> None:
        """The signal, on world/events (viewers and the recording show it)."""
        from swarm.proto import protocol

        t, seq = (now * self.dt, int(now)) if self.lockstep else (now, int(now / self.dt))
        self.bus.put(keys.world_events(self.fleet), protocol.encode(protocol.Event(
            t=max(0.0, t), seq=max(0, seq), event="signal", robots=(robot,), detail=done)), reliable=True)

    def wait_s(self, longest: float) -> float:
        """How long the launcher's loop may sleep: until the next real-time action, at most `longest`."""
        nxt = self.pf.next_time()
        epoch = None if self.lockstep else self._epoch()
        if nxt is None or epoch is None:
            return longest
        at = epoch[0] + nxt / epoch[1]
        return max(0.0, min(longest, at - WALL.time()))


LOG_PREFIX = "swarm-"  # swarm up's default log folders: <temp dir>/swarm-<fleet>-<pid>
LOG_MARKER = ".swarm-up"  # the file swarm up puts in each default log folder it makes (only those are pruned)
KEEP_LOGS = 10  # default log folders kept per fleet (the newest); older ones are removed at the next start


def prune_logs(tmp: Path, fleet: str, keep: int, current: Path) -> int:
    """Remove the default log folders of `fleet` in `tmp` beyond the `keep` newest (by modification time;
    `current` is never removed, nor anything not made by swarm up for this user: only folders named
    swarm-<fleet>-<pid> that hold swarm up's marker file, belong to this user, and whose process is gone; another
    user's runs on a shared machine are theirs). Returns how many were removed."""
    import shutil

    mine = re.compile(rf"^{re.escape(LOG_PREFIX + fleet)}-(\d+)$")
    found = []
    for p in tmp.iterdir() if tmp.is_dir() else ():
        m = mine.match(p.name)
        if m and p.is_dir() and not p.is_symlink() and p.resolve() != current.resolve():
            try:
                st = p.stat()
                if st.st_uid != os.getuid() or not (p / LOG_MARKER).is_file():
                    continue  # another user's, or not made by swarm up: never ours to remove
                found.append((st.st_mtime, p, int(m.group(1))))
            except OSError:
                continue
    found.sort(reverse=True)
    removed = 0
    for _, p, pid in found[max(0, keep - 1):]:
        if _pid_alive(pid):
            continue  # a swarm up still running writes there
        shutil.rmtree(p, ignore_errors=True)
        removed += not p.exists()
    return removed


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _check_secure(args, robots: int) -> str:
    """`swarm up --secure DIR`: DIR must be a fleet directory with an identity for every process of
    this run; returns the router's endpoint (tls/127.0.0.1:PORT)."""
    from swarm.net import secure

    if args.zenoh_config is not None:
        raise BadInput("give --secure (the fleet's certificates and access control) or --zenoh-config, not both")
    try:
        manifest = secure.read_manifest(args.secure)
        for role in ("router", "world", "leader", "launcher") + (() if args.no_viz else ("viz",)):
            secure.find_identity(args.secure, role)
        for i in range(robots):
            secure.find_identity(args.secure, "robot", i)
    except secure.SecureError as e:
        raise BadInput(f"--secure {args.secure}: {e} (swarm secure init {args.secure} --robots {robots} "
                       "makes a fleet directory)") from None
    if manifest.get("fleet") not in (None, args.fleet):
        raise BadInput(f"--secure {args.secure}: its certificates are for fleet {manifest['fleet']!r}, not "
                       f"{args.fleet!r} (give --fleet {manifest['fleet']})")
    for flag, eps in (("--listen", args.listen or []), ("--connect", args.connect or [])):
        for ep in eps:
            if not ep.startswith("tls/"):
                raise BadInput(f"{flag} {ep}: with --secure every endpoint is tls/HOST:PORT")
    return f"tls/127.0.0.1:{manifest['port']}"


def _t(p) -> str:
    return "0 s (before the first tick)" if p is None else f"{p.t:g} s"


def _start_recorder(bus, fleet: str, scn, args):
    from swarm.view.record import BusRecorder, Recorder, RecordError

    try:
        return BusRecorder(bus, fleet, Recorder(args.record, scn, args.record_hz, source=args.mode, fleet=fleet),
                           commands_from_snapshots=args.mode == "lockstep")
    except RecordError as e:
        raise Failure(str(e)) from None


def launch_failure(text: str, sup, name: str | None = None) -> Failure:
    if name is not None and name in sup.children:
        tail = sup.children[name].log.read_text(errors="replace").strip().splitlines()[-5:]
        if tail:
            text += "\n  " + "\n  ".join(tail)
    return Failure(text)


def metrics_from_progress(scn, mode: str, p) -> dict:
    """The metrics of a run whose world wrote none (it was lost): what its last progress message said,
    null where it said nothing."""
    from swarm.core.metrics import step_time
    from world.referee import Referee

    m = Referee(scn).metrics(0.0, False, mode)
    if p is None:
        return m

    def opt(x: float):
        return None if x < 0 else x

    def opt_time(x: float):  # step times rounded as swarm.core.metrics.record rounds them (163 * 0.02 reads 3.26)
        return None if x < 0 else step_time(x)

    m.update(duration_s=step_time(p.t), converged_at_s=opt_time(p.converged_at), final_position_error_max_m=opt(p.position_error),
             final_orientation_error_max_rad=opt(p.orientation_error), min_robot_distance_m=opt(p.min_distance),
             min_obstacle_distance_m=opt(p.min_obstacle), collisions=p.collisions, last_freeze_end_s=opt_time(p.last_freeze),
             cmd_misses=p.misses, bad_messages=p.bad, messages_dropped=p.dropped, steps=p.seq,
             robots_alive_at_end=p.alive, **({"lockstep_overruns": p.overruns} if mode == "lockstep" else {}))
    return m
