"""The commands of a real fleet (docs/deploy.md): `swarm up --inventory`, `swarm world --referee-only`,
`swarm robot --inventory F --id I` and `swarm robot --id auto`.

    cmd_up_inventory(args, started)    # pre-flight, then router, referee, leader, one agent a robot, viewer
    cmd_world_referee(args, started)   # the referee without physics (world.referee_world), after a pre-flight
    cmd_robot_fleet(args, started)     # one agent: its drive from its inventory row, or its id claimed

`swarm up`, `swarm world` and `swarm robot` hand these over when they see --inventory,
--referee-only or --id auto; everything else about those commands is theirs.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import cast

from swarm.cli import console, preflight
from swarm.cli.parser import given
from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, EXIT_OK, BadInput, Failure, StopEvent,
                              check_endpoint, check_listen_free, check_out_dir, check_resources, check_viz_apart,
                              check_viz_port, clear_metrics, load_scenario, make_log_dir, open_bus, record_rate,
                              scenario_args, setup_logging, viz_options, write_json, write_metrics, Refused, close_recorder,
                              read_metrics, refuse_a_taken_fleet)
from swarm.cli.console import EstopFollower, converged_phrase, exit_status, progress_line, summary
from swarm.core import inventory
from swarm.core.clock import WALL
from swarm.core.metrics import violations
from swarm.launch.capacity import Waves
from swarm.process import die_with_parent
from swarm.launch.inventory_plan import FleetUpOptions, make_fleet_plan
from swarm.launch.plan import DEFAULT_LISTEN, VizOptions
from swarm.launch.supervisor import Supervisor, compile_project, exit_text
from swarm.net import presence
from swarm.proto import keys

log = logging.getLogger("swarm")

DEFAULT_FLEET = "default"  # --fleet's default: the inventory's `fleet` beats it (an explicit --fleet NAME beats both)


def fleet_name(args, inv: inventory.Inventory) -> str:
    """--fleet, else the inventory's `fleet`, else "default" (a --fleet equal to the flag's default cannot
    be told from no flag: the inventory's name then wins)."""
    name = args.fleet if args.fleet != DEFAULT_FLEET else (inv.fleet or DEFAULT_FLEET)
    try:
        return keys.check_fleet(name)
    except keys.KeyError_ as e:
        raise BadInput(f"--fleet: {e}") from None


def _initial_poses(args) -> tuple[str, ...]:
    return tuple(f"{i}:{x!r},{y!r},{th!r}" for i, (x, y, th) in (getattr(args, "initial_pose", None) or []))


# --------------------------------------------------------------------------- swarm robot


def cmd_robot_fleet(args, started: float) -> int:
    """`swarm robot --inventory F --id I` (the drive from row I) or `swarm robot --id auto` (an id claimed
    from the world)."""
    from agents import robot
    from agents.control import LawFailure
    from agents.follow import NoAnswer, RunRefused
    from world import claims

    die_with_parent()
    setup_logging()
    auto = args.id is None
    entry = None
    fleet = args.fleet
    if args.inventory is not None:
        inv = inventory.load(args.inventory)
        if auto:
            raise BadInput("--id auto with --inventory: a real robot's id is its inventory row's (hardware has fixed "
                           "ids); give --id I")
        entry = inv.entry(args.id)
        for flag in given(args, "ros_flavor", "twist", "domain", "rmw_zenoh_attachment", "robot_model", "distro"):
            raise BadInput(f"{flag} with --inventory: the robot's drive comes from its inventory row "
                           f"({entry.key}: flavor, twist, domain, attachment, model)")
        for flag, value in (("--scenario", args.scenario), ("--initial-pose", args.initial_pose),
                            ("--namespace", args.namespace)):
            if value is not None:
                raise BadInput(f"{flag} with --inventory: the robot takes its configuration (its start and limits, "
                               "tightened by the inventory) from the world, and its drive from the inventory; give "
                               "starts to swarm up or swarm world --referee-only (--initial-pose I:X,Y,THETA)")
        fleet = fleet_name(args, inv)
        if not args.connect and entry.connect:
            args = argparse.Namespace(**{**vars(args), "connect": [entry.connect]})
    else:
        try:
            fleet = keys.check_fleet(fleet)
        except keys.KeyError_ as e:
            raise BadInput(f"--fleet: {e}") from None
    key = None
    if auto:
        if args.drive == "ros2":
            raise BadInput("--id auto with --drive ros2: hardware has fixed ids; give --id I (or an inventory row)")
        if args.secure is not None:
            raise BadInput("--id auto with --secure: the robot's certificate says its id; give --id I")
        try:
            key = claims.claim_key(args.claim_key)
        except keys.KeyError_ as e:
            raise BadInput(f"--claim-key: {e}") from None
    elif args.claim_key is not None:
        raise BadInput("--claim-key needs --id auto")
    scn = load_scenario(args, quiet=True) if args.scenario is not None else None
    if scn is not None and not auto and args.id >= scn.n:
        raise BadInput(f"--id {args.id}: the scenario has {scn.n} robots (ids 0..{scn.n - 1})")
    if entry is None and args.drive == "ros2" and getattr(args, "distro", None) is not None and \
            (args.ros_flavor != "bridge" or args.twist != "auto"):
        raise BadInput(DISTRO_ONLY)
    factory = _row_drive(entry) if entry is not None else (_flag_drive(args) if args.drive == "ros2" else None)
    if factory is not None and args.mode == "lockstep":
        raise BadInput("a ROS 2 drive with --mode lockstep: a ROS 2 robot runs in real time only (odometry carries no "
                       "tick); give --mode realtime, or leave --mode out")
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, lean=True, role="robot", robot_id=args.id)
        rid = args.id
        try:
            if auto:
                rid = claims.request_id(bus, fleet, cast(str, key), args.start_timeout, stop)  # set above when auto
                log.info("robot: claimed id %d (claim key %s)", rid, key)
                if scn is not None and rid >= scn.n:
                    raise BadInput(f"the world gave id {rid}, but this robot's scenario has {scn.n} robots")
            opts = robot.RobotOptions(scenario=scn, start_timeout=args.start_timeout,
                                      make_drive=None if factory is None else factory(bus),
                                      ref_timeout=args.ref_timeout, mode=args.mode,
                                      law_file=getattr(args, "law_file", None))
            agents = robot.run_robot(bus, WALL, rid, fleet, stop, opts)
        except LawFailure as e:  # the run's own law: EXIT_REFUSED, which swarm up does not restart (it ends the run)
            raise Refused(str(e)) from None
        except (NoAnswer, claims.NoClaimAnswer) as e:
            if stop.is_set():
                return EXIT_INTERRUPTED
            raise Failure(str(e)) from None
        except claims.ClaimRefused as e:
            raise Failure(str(e)) from None
        except RunRefused as e:
            raise BadInput(f"robot {rid} refuses the run: {e}") from None
        except robot.DriveRefused as e:
            raise BadInput(f"robot {rid}: {e}") from None
        except RuntimeError as e:  # a ROS 2 robot not found (swarm.drives.ros2.DiscoveryError)
            if type(e).__name__ == "DiscoveryError":
                raise Failure(f"robot {rid}: {e}") from None
            raise
        finally:
            bus.close()
    for a in agents:
        log.info("robot %d, run %s: %d ticks, %d states received, %d bad messages", rid, a.cfg.run, a.ticks,
                 a.states_received, a.bad_count())
    return EXIT_INTERRUPTED


DISTRO_ONLY = ("--distro sets only what --twist auto falls back to behind a zenoh-bridge-ros2dds that announces no "
               "route (rmw_zenoh robots and a given --twist say their type themselves): give it with --ros-flavor bridge "
               "and --twist auto, or leave it out")


def _ros2_available(flag: str) -> None:
    try:
        from swarm.proto import ros2

        ros2.require()
    except ImportError as e:
        raise BadInput(f"{flag}: {e}") from None


def _row_drive(entry: inventory.RobotEntry):
    """make_drive for an inventory row (its ROS 2 topics), anchored at the start the world gives."""
    _ros2_available(f"the inventory's {entry.key}.drive = {entry.drive!r}")
    return _drive_factory(entry.namespace, entry.flavor, entry.twist, entry.domain, None, entry.cmd_timeout,
                          attachment=entry.attachment)


def _flag_drive(args):
    _ros2_available("--drive ros2")
    return _drive_factory(args.namespace, args.ros_flavor, args.twist, args.domain, args.initial_pose,
                          attachment=getattr(args, "rmw_zenoh_attachment", "auto"),
                          speed_limits=inventory.model_limits(getattr(args, "robot_model", None)),
                          distro=getattr(args, "distro", None))


def _drive_factory(namespace: str | None, flavor: str, twist: str, domain: int, pose, cmd_timeout=None,
                   attachment: str = "auto", speed_limits: tuple[float, float] | None = None,
                   distro: str | None = None):
    def factory(bus):
        def make(cfg, now):
            from agents.robot import DriveRefused
            from swarm.drives.ros2 import Ros2Drive

            if cfg.lockstep:
                raise DriveRefused("a ROS 2 robot runs in real time only (odometry carries no tick): the run is "
                                   "lock-step; start the world with --mode realtime (or --referee-only)")
            return Ros2Drive(bus, namespace=f"robot{cfg.id}" if namespace is None else namespace, now=now,
                             flavor=flavor, twist=twist, domain=domain, initial_pose=pose or (cfg.x, cfg.y, cfg.theta),
                             base_timeout_s=cmd_timeout, attachment=attachment, speed_limits=speed_limits,
                             distro=distro)

        return make

    return factory


# --------------------------------------------------------------------------- swarm world --referee-only


def cmd_world_referee(args, started: float) -> int:
    from world.referee_world import NotReady, RefereeOptions, run_referee

    die_with_parent()
    setup_logging()
    if args.inventory is None:
        raise BadInput("--referee-only needs --inventory FILE (which robots, their topics, starts and limits)")
    if args.ros2_sim is not None:
        raise BadInput("--referee-only with --ros2-sim: the referee simulates nothing (the robots are real)")
    if args.secure is not None and not args.no_preflight:
        raise BadInput("--secure with the pre-flight: it reads every robot's ROS 2 topics, which only each robot's "
                       "identity may; run swarm preflight on the robots' network and give --no-preflight here")
    fleet = preflight.fleet_of_args(args, quiet=True)
    name = fleet_name(args, fleet.inventory)
    check_out_dir("--metrics", args.metrics)
    check_out_dir("--trace", args.trace)
    if args.speed != 1.0:
        log.warning("referee: --speed %g: real robots keep real time; only a simulated fleet can follow", args.speed)
    opts = RefereeOptions(speed=args.speed, watchdog=args.watchdog, lost_timeout=args.lost_timeout,
                          start_timeout=args.start_timeout, trace=args.trace is not None)
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, role="world")
        try:
            refuse_a_taken_fleet(bus, name, ", ".join(args.connect or []) or "the router")
            if not args.no_preflight:
                try:
                    report = preflight.check(bus, fleet, stop=stop)
                except InterruptedError:
                    return EXIT_INTERRUPTED
                for line in report.text().splitlines():
                    log.info("%s", line)
                if not report.ok:
                    raise Failure("pre-flight failed; no robot was moved:\n" + report.text())
            metrics, ref = run_referee(bus, WALL, fleet, opts, stop, name, started)
        except NotReady as e:
            raise Failure(str(e)) from None
        finally:
            bus.close()
    metrics["interrupted"] = bool(metrics["interrupted"] or stop.is_set())
    metrics["preflight"] = "skipped" if args.no_preflight else "passed"
    if args.metrics is not None:
        write_json(args.metrics, metrics)
    if args.trace is not None and ref.trace is not None:
        import numpy as np

        np.savez_compressed(args.trace, q=np.array(ref.trace).reshape(-1, fleet.scenario.n, 3), dt=fleet.scenario.dt)
    log.info("referee: done at t = %s s, %s, %d collisions, largest pose age %s s%s", metrics["duration_s"],
             converged_phrase(metrics["converged_at_s"]), metrics["collisions"], metrics["max_pose_age_s"],
             f"; FAILED: {metrics['failure']}" if metrics.get("failure") else "")
    bad = violations(metrics)
    if bad and not metrics["interrupted"] and not metrics.get("failure"):
        log.warning("referee: checks failed: %s%s", ", ".join(bad), "" if args.allow_violations else " (exit 3)")
    return exit_status(metrics, args.allow_violations)


# --------------------------------------------------------------------------- swarm up --inventory


class _ViewerUrl:
    """The URL the viz child prints (`viewer: URL`) in its log, read without blocking."""

    PATTERN = re.compile(r"^viewer: (\S+)$", re.M)

    def __init__(self, child, offset: int, timeout_s: float) -> None:
        self.child, self.offset, self.end = child, offset, time.monotonic() + timeout_s
        self.done = False

    def poll(self) -> str | None:
        if self.done:
            return None
        try:
            with open(self.child.log, "rb") as f:
                f.seek(self.offset)
                text = f.read().decode(errors="replace")
        except OSError:
            text = ""
        m = self.PATTERN.search(text)
        if m:
            self.done = True
            return f"viewer: {m.group(1)}"
        rc = self.child.proc.poll()
        if rc is not None or time.monotonic() > self.end:
            self.done = True
            return f"viewer: no URL ({exit_text(rc)}); see {self.child.log}"
        return None


# `swarm up` flags that mean nothing with --inventory, and why: given, they are refused, not dropped
IGNORED_WITH_INVENTORY = {
    "drive": "each robot's drive comes from its inventory row (drive)",
    "ros_flavor": "each robot's ROS 2 flavor comes from its inventory row (flavor)",
    "twist": "each robot's cmd_vel type comes from its inventory row (twist)",
    "domain": "each robot's ROS domain comes from its inventory row (domain)",
    "rmw_zenoh_attachment": "each robot's attachment form comes from its inventory row (attachment, auto by default)",
    "distro": "the robots are real: their ROS 2 distribution is theirs",
    "restarts": "a real fleet's processes are never restarted (a robot whose agent died stands still)",
    "restart_window": "a real fleet's processes are never restarted (a robot whose agent died stands still)",
    "tick_timeout": "real robots run in real time; a tick's timeout is lock-step's",
}


def refuse_fleet_flags(args) -> None:
    """BadInput for a flag given with --inventory that would be dropped (IGNORED_WITH_INVENTORY), and for
    --mode lockstep: real robots keep real time. `--mode realtime` says what happens anyway."""
    flags = given(args, *IGNORED_WITH_INVENTORY, "mode")
    for flag in flags:
        why = IGNORED_WITH_INVENTORY.get(flag[2:].replace("-", "_"))
        if why is not None:
            raise BadInput(f"{flag} with --inventory: {why} (docs/deploy.md)")
    if "--mode" in flags and args.mode != "realtime":
        raise BadInput("--mode lockstep with --inventory: real robots keep real time, they cannot wait for a tick "
                       "(leave --mode out, or give --mode realtime)")


def cmd_up_inventory(args, started: float, module: str = "swarm.cli") -> int:
    """`swarm up --inventory F`: the pre-flight, then the router (connected to every robot's endpoint),
    the referee, the leader and one agent a robot, with the viewer and the recorder as in simulation.
    module: what the children run (`python -m module`)."""
    refuse_fleet_flags(args)
    fleet = preflight.fleet_of_args(args)
    scn = fleet.scenario
    from swarm.core.scenario_file import advisories

    for note in advisories(fleet.given):
        print(f"swarm up: warning: {note}", file=sys.stderr)
    name = fleet_name(args, fleet.inventory)
    if args.secure is not None:
        raise BadInput("--secure with --inventory: not yet (the pre-flight and the launcher read every robot's ROS 2 "
                       "topics); start the processes by hand with their identities (docs/deploy.md)")
    if args.connect and args.listen:
        raise BadInput("give --listen (start a router) or --connect (join one), not both")
    for ep in (args.listen or []) + (args.connect or []):
        check_endpoint("--listen" if ep in (args.listen or []) else "--connect", ep)
    check_out_dir("--metrics", args.metrics)
    check_out_dir("--trace", args.trace)
    check_out_dir("--record", args.record)
    args.record_hz = record_rate(args)
    if args.speed != 1.0:
        print(f"swarm up: warning: --speed {args.speed:g}: real robots keep real time; only a simulated fleet can "
              "follow", file=sys.stderr)
    if args.log_dir is not None and Path(args.log_dir).exists() and not Path(args.log_dir).is_dir():
        raise BadInput(f"--log-dir {args.log_dir}: exists and is not a directory")
    if args.zenoh_config is not None and not Path(args.zenoh_config).is_file():
        raise BadInput(f"--zenoh-config {args.zenoh_config}: no such file")
    log_dir = Path(args.log_dir or os.path.join(tempfile.gettempdir(), f"swarm-{name}-{os.getpid()}"))
    metrics_path = (args.metrics or log_dir / "metrics.json").absolute()
    viz = viz_options(args, not args.no_viz, "has no effect with --no-viz")
    if viz is not None:
        viz = VizOptions(viz.host, viz.port, viz.rings, str((log_dir / "viz-server.log").absolute()), viz.timeout)
    opts = FleetUpOptions(
        inventory=str(Path(args.inventory).absolute()), robots=scn.n, scenario_args=scenario_args(args),
        robot_endpoints=fleet.inventory.endpoints, initial_poses=_initial_poses(args), fleet=name,
        listen=None if args.connect else (args.listen[0] if args.listen else DEFAULT_LISTEN),
        connect=args.connect[0] if args.connect else None,
        zenoh_config=str(Path(args.zenoh_config).absolute()) if args.zenoh_config else None, multicast=args.multicast,
        speed=args.speed, metrics=str(metrics_path), trace=str(Path(args.trace).absolute()) if args.trace else None,
        start_timeout=args.start_timeout, lost_timeout=args.lost_timeout, watchdog=args.watchdog, viz=viz)
    plan = make_fleet_plan(opts, module=module)
    check_viz_apart(viz, (opts.listen or plan.endpoint) if plan.router is not None else None)
    res = check_resources(len(plan.robots), plan, args.dry_run)
    static = preflight.static_report(fleet)
    if args.dry_run:
        print(plan.describe())
        print(res.text())
        if res.refusal() is not None:  # the run would stop here: so does the dry run, after the plan
            raise BadInput(res.refusal())
        print(f"fleet '{name}' (inventory {fleet.inventory.where}):\n{inventory.describe(fleet)}")
        print(static.text() if not args.no_preflight else "pre-flight: skipped (--no-preflight)")
        if not args.no_preflight and not static.ok:  # the run would stop here: so does the dry run (exit 1)
            raise Failure("pre-flight failed (the dry run's checks of the inventory and the scenario)")
        return EXIT_OK
    if not args.no_preflight and not static.ok:
        print(static.text())
        raise Failure("pre-flight failed; no robot was moved")
    if viz is not None:
        check_viz_port(viz)
    if plan.router is not None:
        check_listen_free(opts.listen or plan.endpoint)
    make_log_dir(log_dir, args.log_dir is not None)
    clear_metrics(metrics_path, log_dir)  # whatever is read back at the end must be this run's
    compile_project()
    status = console.StatusLine(enabled=not args.quiet, log_every=2.0)
    say = (lambda text: None) if args.quiet else status.note
    say(f"swarm up: real fleet '{name}', {scn.n} robots, scenario {scn.name}, real time, dt {scn.dt:g} s; logs in "
        f"{log_dir}")
    interrupted, failure, launched_s, last, recorder, checked = False, None, None, None, None, "skipped"
    viewer: list[_ViewerUrl] = []
    with StopEvent(hard_second=False) as stop, Supervisor(plan, log_dir) as sup:
        bus = None
        try:
            t0 = time.monotonic()
            if plan.router is not None:
                sup.start(plan.router)
            if plan.viz is not None:
                vlog = sup.log_of(plan.viz)
                viewer.append(_ViewerUrl(sup.start(plan.viz), vlog.stat().st_size if vlog.exists() else 0,
                                         args.start_timeout))
            bus = open_bus(argparse.Namespace(connect=[plan.endpoint], zenoh_config=opts.zenoh_config, secure=None,
                                              multicast=opts.multicast), timeout_s=15.0, stop=stop, role="launcher")
            if plan.router is None:  # another's router: this fleet must be free there
                refuse_a_taken_fleet(bus, name, plan.endpoint)
            presence.announce(bus, name, "launcher")  # `swarm ps` lists this process too
            estop = EstopFollower(bus, name, say)  # the status line says E-STOP while it is engaged
            if not args.no_preflight:
                say("pre-flight: checking every robot's ROS 2 side and odometry ...")
                try:  # our router links every robot's: one that does not answer is a network fault, said so
                    report = preflight.check(bus, fleet, stop=stop,
                                             cut_off=preflight.unreached(fleet) if plan.router is not None else None)
                except InterruptedError:
                    raise KeyboardInterrupt from None
                status.clear()
                if not (args.quiet and report.ok):
                    print(report.text(), flush=True)
                if not report.ok:
                    raise Failure("pre-flight failed; no robot was moved")
                checked = "passed"
            alive: set[str] = set()
            progress: list = [None]
            bus.watch_alive(keys.alive_any(name), lambda k, up: alive.add(k) if up else alive.discard(k))
            bus.subscribe(keys.world_progress(name), lambda k, b: progress.__setitem__(0, b))
            if args.record is not None:
                recorder = _start_recorder(bus, name, scn, args)
            for spec in (plan.world, plan.leader):
                sup.start(spec)
            robots = {keys.alive(name, "robot", i) for i in range(scn.n)}
            want = {keys.alive(name, "world"), keys.alive(name, "leader")} | robots
            waves = Waves(sup.start, plan.robots, args.start_timeout)
            while not want <= alive and not stop.is_set():
                if waves.step(len(alive & want), len(alive & robots)):
                    missing = sorted(want - alive, key=lambda k: (len(k), k))
                    names = [k.split("/alive/")[1].replace("/", " ") for k in missing]
                    raise Failure(f"not alive after {args.start_timeout:g} s without a new process up: "
                                  f"{', '.join(names[:12])}"
                                  f"{' ...' if len(names) > 12 else ''}" + _tail(sup, _child_name(names[0])))
                for spec in (plan.world, *plan.robots):
                    if spec.name not in sup.children:  # a robot its wave has not started yet
                        continue
                    rc = sup.children[spec.name].proc.poll()
                    if rc is not None:
                        raise Failure(f"{spec.name} exited during start-up ({exit_text(rc)})" + _tail(sup, spec.name))
                status.update(f"starting: {len(alive & want)}/{len(want)} processes alive", force=False)
                _watch_viewer(viewer, status)
                time.sleep(0.02)
            if want <= alive:
                launched_s = time.monotonic() - t0
                say(f"all {len(want)} processes alive after {launched_s:.2f} s; router at {plan.endpoint}")
            world = sup.children["world"]
            while world.proc.poll() is None:
                if stop.is_set():
                    interrupted = True
                    sup.signal("world", signal.SIGTERM)
                    sup.wait("world", 3.0)
                    break
                for note in sup.check_restarts():
                    say(note)
                _watch_viewer(viewer, status)
                last = _progress(progress[0]) or last
                if last is not None:
                    status.update(progress_line(last, estop.engaged))
                if plan.router is not None and sup.children["router"].proc.poll() is not None:
                    failure = f"router lost at t = {_t(last)} ({exit_text(sup.children['router'].proc.returncode)})"
                    sup.signal("world", signal.SIGTERM)
                    sup.wait("world", 3.0)
                    break
                stop.wait(0.1)
            last = _progress(progress[0]) or last
            rc = world.proc.returncode
            if not interrupted and failure is None and rc not in (0, 1, 3, EXIT_INTERRUPTED):
                failure = f"referee lost at t = {_t(last)} ({exit_text(rc)}); see {world.log}"
            if recorder is not None:
                recorder.wait_for(scn.steps * scn.dt if not interrupted else None, timeout_s=1.0)
        finally:
            if bus is not None:
                bus.close()
            sup.shutdown(first=("world", *[s.name for s in plan.robots]))
    status.close()
    interrupted = interrupted or stop.is_set()
    metrics = read_metrics(metrics_path)
    if metrics is None:
        from world.referee import Referee

        metrics = Referee(scn).metrics(0.0, interrupted, "realtime", odometry_based=True, max_pose_age_s=None,
                                       referee_only=True)
        if failure is None and not interrupted:
            failure = f"the referee wrote no metrics (t = {_t(last)}); see {log_dir}/world.log"
    metrics["wall_s"] = time.perf_counter() - started
    metrics["interrupted"] = bool(interrupted or (metrics.get("interrupted") and failure is None))
    if failure is not None:
        metrics["failure"] = failure
    metrics.setdefault("failure", None)
    metrics["preflight"] = checked
    metrics["launch_s"] = launched_s
    metrics["processes"] = len(plan.processes)
    write_metrics(metrics_path, log_dir, metrics)
    record_note = close_recorder(recorder, metrics, args.record)
    if not args.quiet:
        print(summary(metrics, scn.name))
        print(f"metrics: {metrics_path} (odometry-based; largest pose age {metrics.get('max_pose_age_s')} s)")
        if record_note:
            print(record_note)
    code = exit_status(metrics, args.allow_violations)
    if metrics.get("failure") and not metrics["interrupted"]:
        print(f"swarm up: failed: {metrics['failure']}", file=sys.stderr)
    elif code == 3:
        print(f"swarm up: checks failed: {', '.join(violations(metrics))} (exit 3; --allow-violations: 0)",
              file=sys.stderr)
    return code


def _child_name(alive_name: str) -> str:
    """The supervisor's name of the process of an alive key's "role id": "world 0" -> "world"."""
    role, _, i = alive_name.partition(" ")
    return alive_name if role == "robot" else role


def _tail(sup, name: str | None) -> str:
    child = sup.children.get(name) if name else None
    if child is None:
        return ""
    lines = child.log.read_text(errors="replace").strip().splitlines()[-5:]
    return ("\n  " + "\n  ".join(lines)) if lines else ""


def _watch_viewer(viewer: list, status) -> None:
    note = viewer[0].poll() if viewer else None
    if note is not None:
        status.clear()
        print(note, flush=True)


def _progress(payload: bytes | None):
    from swarm.proto import protocol

    if payload is None:
        return None
    try:
        return protocol.decode(payload, "progress")
    except protocol.ProtocolError:
        return None


def _t(p) -> str:
    return "0 s (before the first period)" if p is None else f"{p.t:g} s"


def _start_recorder(bus, fleet: str, scn, args):
    from swarm.view.record import BusRecorder, Recorder, RecordError

    try:
        return BusRecorder(bus, fleet, Recorder(args.record, scn, args.record_hz, source="realtime", fleet=fleet))
    except RecordError as e:
        raise Failure(str(e)) from None
