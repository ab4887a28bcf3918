"""`swarm preflight --inventory F`: refuse to move hardware when something is off (docs/deploy.md).

    report = check(bus, fleet)          # static checks (swarm.core.inventory) + each robot over the network
    report.problems                     # [Problem(robot, reason)], in robot order; report.ok
    print(report.text())

It runs on its own (`swarm preflight`) and at the start of every real run (`swarm up --inventory`,
`swarm world --referee-only`) unless --no-preflight; a failure names each robot and its reason, and
nothing moves (exit 1). The network part, per robot of the inventory:
- its ROS 2 side answers: rmw_zenoh flavour, its liveliness tokens show a cmd_vel subscription of the
  inventory's twist type and an odom publication (a subscription of the other type names the fix);
  bridge flavour, something subscribes <ns>/cmd_vel (zenoh's matching status), and where the bridge announces
  the route (its liveliness token, with the ROS 2 type) the type is the inventory's twist;
- its odometry is fresh: readable messages come, and over a window of `window_s` none is missing for
  longer than `max_age_s` (the robot-side guard's pose timeout: a robot whose odometry is slower would
  be halted by its own guard as soon as it moved).
Nothing is ever put on a robot's cmd_vel here.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from typing import cast

from agents.guard import POSE_TIMEOUT_S
from swarm.cli.common import BadInput, Failure, StopEvent, load_scenario, open_bus, setup_logging
from swarm.core import inventory
from swarm.core.inventory import Fleet, Problem, RobotEntry
from swarm.proto import ros2
from swarm.proto.ros2 import Ros2Error

log = logging.getLogger("swarm.preflight")

DISCOVER_TIMEOUT_S = 10.0  # s: for each robot's ROS 2 side and first odometry (the drive's discovery time)
WINDOW_S = 1.5  # s: odometry watched this long once every robot has sent some


@dataclass
class _Robot:
    """What the probe learned of one robot (written on the bus's threads under the probe's lock)."""

    entry: RobotEntry
    odom_key: str | None = None
    cmd_ok: bool = False
    cmd_other: str | None = None  # a cmd_vel subscription of the other twist type (rmw_zenoh: DDS name; bridge: ROS 2)
    arrivals: list[float] = field(default_factory=list)  # monotonic times of readable odometry
    bad: str | None = None  # the last unreadable odometry's reason
    bad_count: int = 0
    attachment: str | None = None  # rmw_zenoh: the form of its odometry's attachments ("v1", "v2", "none")
    doubled: bool = False  # bridge: nothing on <ns>/cmd_vel, something on <ns>/<ns>/cmd_vel (a doubled namespace)


class OdometryProbe:
    """Watches every robot's ROS 2 side and odometry on `bus` (never publishes to a robot)."""

    def __init__(self, bus, robots: list[RobotEntry], clock=time.monotonic) -> None:
        self.bus, self.clock = bus, clock
        self.robots = {e.id: _Robot(e) for e in robots}
        self.lock = threading.Lock()
        self.seen: dict[str, ros2.Entity] = {}  # rmw_zenoh liveliness tokens
        self.routes: dict[str, ros2.BridgeRoute] = {}  # zenoh-bridge-ros2dds's subscription routes, by token
        self._subscribed: set[int] = set()
        self._handles: list = []

    def start(self) -> None:
        for domain in sorted({r.entry.domain for r in self.robots.values() if r.entry.flavor == "rmw_zenoh"}):
            self._handles.append(self.bus.watch_alive(ros2.liveliness_any(domain), self._on_token))
        if any(r.entry.flavor == "bridge" for r in self.robots.values()):
            for expr in ros2.bridge_routes("MS"):  # the 1.x form and the 0.x one
                self._handles.append(self.bus.watch_alive(expr, self._on_route))
        for r in self.robots.values():
            if r.entry.flavor == "bridge":
                r.odom_key = ros2.bridge_key(r.entry.namespace, ros2.ODOM)
        self.poll()

    def _on_route(self, key: str, up: bool) -> None:
        self._track(self.routes, ros2.parse_bridge_route(key), key, up)

    def _on_token(self, key: str, up: bool) -> None:
        self._track(self.seen, ros2.parse_liveliness(key), key, up)

    def _track(self, table: dict, parsed: object, key: str, up: bool) -> None:
        """Keep what a liveliness token says while it lives (nothing for a token that is not one of ours)."""
        if parsed is None:
            return
        with self.lock:
            if up:
                table[key] = parsed
            else:
                table.pop(key, None)

    def poll(self) -> None:
        """On the caller's thread: take what the tokens say, subscribe new odometry keys, ask whether
        the bridge robots' cmd_vel has a subscriber."""
        with self.lock:
            seen = list(self.seen.values())
        for r in self.robots.values():
            e = r.entry
            if e.flavor == "rmw_zenoh":
                odom, cmd = ros2.topic_name(e.namespace, ros2.ODOM), ros2.topic_name(e.namespace, ros2.CMD_VEL)
                want_cmd = {ros2.dds_type(ros2.twist_type(t)) for t in (ros2.TWISTS if e.twist == "auto" else (e.twist,))}
                for t in seen:
                    if t.domain != e.domain:
                        continue
                    if t.kind == "MP" and t.topic == odom and t.dds_type == ros2.dds_type(ros2.ODOMETRY):
                        r.odom_key = r.odom_key or t.data_key
                    if t.kind == "MS" and t.topic == cmd:
                        if t.dds_type in want_cmd:
                            r.cmd_ok = True
                        else:
                            r.cmd_other = t.dds_type
            else:
                self._bridge_type(r)
            if e.flavor == "bridge" and not r.cmd_ok and r.cmd_other is None:
                r.cmd_ok = self.bus.wanted(ros2.bridge_key(e.namespace, ros2.CMD_VEL))
                doubled = ros2.doubled_bridge_key(e.namespace, ros2.CMD_VEL)
                r.doubled = not r.cmd_ok and doubled is not None and self.bus.wanted(doubled)
            if r.odom_key is not None and e.id not in self._subscribed:
                self._subscribed.add(e.id)
                self._handles.append(self.bus.subscribe_raw(r.odom_key, lambda k, p, a, r=r: self._on_odom(r, p, a)))

    def _bridge_type(self, r: _Robot) -> None:
        """A bridge robot's cmd_vel type from its bridge's route, when it announces one: the inventory's twist, or
        the other (named by verdicts)."""
        key = ros2.bridge_key(r.entry.namespace, ros2.CMD_VEL)
        with self.lock:
            types = {t.ros2_type for t in self.routes.values() if t.key == key}
        if types:
            want = {ros2.twist_type(t) for t in (ros2.TWISTS if r.entry.twist == "auto" else (r.entry.twist,))}
            r.cmd_other = None if want & types else min(types)

    def _on_odom(self, r: _Robot, payload: bytes, attachment: bytes | None = None) -> None:
        now = self.clock()
        if r.entry.flavor == "rmw_zenoh" and r.attachment is None:
            r.attachment = ros2.attachment_form(attachment) or "none"
        try:
            ros2.decode_odometry(payload)
        except Ros2Error as e:
            with self.lock:
                r.bad, r.bad_count = str(e), r.bad_count + 1
            return
        with self.lock:
            r.arrivals.append(now)

    def ready(self) -> bool:
        """Every robot's ROS 2 side found and some odometry from each."""
        with self.lock:
            return all(r.cmd_ok and r.arrivals for r in self.robots.values())

    def verdicts(self, window: tuple[float, float], waited_s: float, max_age_s: float) -> list[Problem]:
        """The problems of each robot after watching `window` (monotonic start, end)."""
        out = []
        with self.lock:
            seen = list(self.seen.values())
            for i, r in sorted(self.robots.items()):
                out += _robot_problems(r, seen, window, waited_s, max_age_s)
        return out

    def rate(self, i: int, window: tuple[float, float]) -> float:
        """Robot i's odometry messages a second over the window."""
        with self.lock:
            n = sum(1 for a in self.robots[i].arrivals if window[0] <= a <= window[1])
        return n / max(1e-9, window[1] - window[0])

    def close(self) -> None:
        for h in self._handles[::-1]:
            h.close()
        self._handles.clear()


def _robot_problems(r: _Robot, seen: list, window: tuple[float, float], waited_s: float,
                    max_age_s: float) -> list[Problem]:
    e, out = r.entry, []
    where = f"/{e.namespace}" if e.namespace else "/"
    if e.flavor == "rmw_zenoh":
        if not r.cmd_ok:
            cmd = ros2.topic_name(e.namespace, ros2.CMD_VEL)
            if r.cmd_other is not None:
                other = "stamped" if r.cmd_other == ros2.dds_type(ros2.TWIST_STAMPED) else "plain"
                out.append(Problem(e.id, f"subscribes {cmd} as {r.cmd_other}, not as the inventory's twist = "
                                         f"{e.twist!r}: set twist = \"{other}\" in {e.key}"))
            else:
                out.append(Problem(e.id, f"no subscriber of {cmd} in the ROS 2 graph of domain {e.domain} within "
                                         f"{waited_s:.3g} s ({_graph(seen, e.domain)})"))
        if r.odom_key is None:
            out.append(Problem(e.id, f"no publisher of {ros2.topic_name(e.namespace, ros2.ODOM)} "
                                     f"({ros2.ODOMETRY}) in the ROS 2 graph of domain {e.domain} within "
                                     f"{waited_s:.3g} s"))
            return out
    elif r.cmd_other is not None:
        cmd = ros2.bridge_key(e.namespace, ros2.CMD_VEL)
        twist = ros2.twist_of(r.cmd_other)
        fix = f"set twist = \"{twist}\" in {e.key}" if twist else "it takes no Twist at all"
        out.append(Problem(e.id, f"its zenoh-bridge-ros2dds routes {cmd} to a subscriber of {r.cmd_other}, not of the "
                                 f"inventory's twist = {e.twist!r}: {fix}"))
    elif not r.cmd_ok and r.doubled:
        out.append(Problem(e.id, f"nothing subscribes {ros2.bridge_key(e.namespace, ros2.CMD_VEL)}, but something "
                                 f"subscribes {ros2.doubled_bridge_key(e.namespace, ros2.CMD_VEL)}: the namespace is "
                                 f"given twice (the robot's nodes in {where} and its bridge started with -n {where}); "
                                 "start the bridge without -n, or the robot without its namespace"))
    elif not r.cmd_ok:
        out.append(Problem(e.id, f"nothing subscribes {ros2.bridge_key(e.namespace, ros2.CMD_VEL)} (is the robot's "
                                 f"zenoh-bridge-ros2dds up with namespace {where}, and linked to this router?)"))
    verdict = odometry_verdict(r.arrivals, window, max_age_s)
    if verdict is not None:
        if not r.arrivals and r.bad is not None:
            verdict = f"odometry on {r.odom_key} is unreadable ({r.bad_count} messages; the last: {r.bad})"
        elif not r.arrivals:
            verdict = f"no odometry on {r.odom_key} within {waited_s:.3g} s"
        out.append(Problem(e.id, verdict))
    return out


def _graph(seen: list, domain: int) -> str:
    nodes = sorted({f"{t.namespace.rstrip('/')}/{t.node}" for t in seen if t.kind == "NN" and t.domain == domain})
    if not nodes:
        return "no ROS 2 node at all: is the robot's bringup running with RMW_IMPLEMENTATION=rmw_zenoh_cpp and " \
               "its zenoh router linked to this one?"
    return f"nodes seen: {', '.join(nodes[:12])}{' ...' if len(nodes) > 12 else ''}"


def odometry_verdict(arrivals: list[float], window: tuple[float, float], max_age_s: float) -> str | None:
    """None if odometry was fresh over `window` (monotonic start, end [s]): some came, and no gap (from
    the last message before the window, or its start, through each message to its end) longer than
    max_age_s [s]. Otherwise the reason. Pure."""
    if not arrivals:
        return "no odometry"
    start, end = window
    before = [a for a in arrivals if a < start]
    inside = sorted(a for a in arrivals if start <= a <= end)
    points = [before[-1] if before else start] + inside + [end]
    gap = max(b - a for a, b in zip(points, points[1:]))
    if gap > max_age_s:
        rate = len(inside) / max(1e-9, end - start)
        return (f"odometry is stale: {len(inside)} message{'s' if len(inside) != 1 else ''} in {end - start:.2g} s "
                f"({rate:.2g} Hz), a gap of "
                f"{gap:.2f} s, more than the {max_age_s:g} s after which the robot's own guard would halt it")
    return None


@dataclass(frozen=True)
class Report:
    fleet: Fleet
    problems: list[Problem]
    notes: list[str]
    rates: dict[int, float]  # odometry messages a second per robot (network part only)
    attachments: dict[int, str] = field(default_factory=dict)  # rmw_zenoh robots: their odometry's attachment form

    @property
    def ok(self) -> bool:
        return not self.problems

    def text(self) -> str:
        scn = self.fleet.scenario
        lines = [f"pre-flight: scenario {scn.name}, {scn.n} robots, inventory {self.fleet.inventory.where}"]
        lines += [f"  warning: {n}" for n in self.notes]
        bad = {p.robot for p in self.problems}
        named = sorted(cast("set[int]", bad - {None}))
        for r in self.fleet.robots:
            if r.id in bad:
                lines += [f"  {p}" for p in self.problems if p.robot == r.id]
            else:
                rate = f", odometry {self.rates[r.id]:.3g} Hz" if r.id in self.rates else ""
                form = self.attachments.get(r.id)
                rate += f", rmw_zenoh attachments {form} ({ros2.RELEASES.get(form, 'neither form')})" if form else ""
                lines.append(f"  robot {r.id}: ok (start ({r.start[0]:g}, {r.start[1]:g}) from {r.start_from}{rate})")
        lines += [f"  {p}" for p in self.problems if p.robot is None]
        if self.problems:
            lines.append(f"pre-flight FAILED: {len(self.problems)} problem{'s' if len(self.problems) != 1 else ''}, "
                         f"robot{'s' if len(named) != 1 else ''} {', '.join(map(str, named))}"
                         "; no robot was moved")
        else:
            lines.append("pre-flight passed")
        return "\n".join(lines)


def static_report(fleet: Fleet) -> Report:
    return Report(fleet, inventory.static_problems(fleet), inventory.notes(fleet), {})


def unreached(fleet: Fleet) -> dict[int, str]:
    """The robots whose own `connect` endpoint does not answer as a router would, with why ({id: "tcp/...: connection
    refused ..."}): a network or router fault, told apart from a ROS 2 side that does not answer. Each endpoint
    probed once, all at once (swarm.net.reach, PROBE_S each)."""
    from concurrent.futures import ThreadPoolExecutor

    from swarm.net import reach

    eps = list(fleet.inventory.endpoints)
    if not eps:
        return {}
    def probe(ep: str) -> str | None:  # without --secure no TLS files are here: a tls/ endpoint's TCP is checked
        return reach.probe("tcp/" + ep[4:] if ep.startswith("tls/") else ep)

    with ThreadPoolExecutor(max_workers=min(32, len(eps))) as pool:
        why = dict(zip(eps, pool.map(probe, eps)))
    return {r.id: f"{r.entry.connect}: {why[r.entry.connect]}" for r in fleet.robots
            if r.entry.connect and why.get(r.entry.connect)}


def check(bus, fleet: Fleet, timeout_s: float = DISCOVER_TIMEOUT_S, window_s: float = WINDOW_S,
          max_age_s: float = POSE_TIMEOUT_S, stop: threading.Event | None = None,
          cut_off: dict[int, str] | None = None) -> Report:
    """Every check: static, then each robot's ROS 2 side and odometry on `bus` (up to timeout_s for the
    robots to show up, then window_s of odometry). cut_off: robots whose router was not reached ({id: why},
    unreached()): each is that problem alone, its ROS 2 side not checked."""
    stop = stop or threading.Event()
    cut_off = cut_off or {}
    problems = inventory.static_problems(fleet)
    problems += [Problem(i, f"cannot reach its zenoh router at {why}; the network or that router, not the robot's "
                            "ROS 2 side (not checked)") for i, why in sorted(cut_off.items())]
    probe = OdometryProbe(bus, [r.entry for r in fleet.robots if r.id not in cut_off])
    probe.start()
    try:
        t0 = time.monotonic()
        while not probe.ready() and time.monotonic() - t0 < timeout_s and not stop.wait(0.05):
            probe.poll()
        waited = time.monotonic() - t0
        start = time.monotonic()
        end = start + window_s
        while not stop.is_set() and time.monotonic() < end:
            probe.poll()  # late subscribers and bridges still count
            stop.wait(min(0.1, max(0.0, end - time.monotonic())))
        window = (start, time.monotonic())
        if stop.is_set():
            raise InterruptedError
        problems += probe.verdicts(window, waited, max_age_s)
        rates = {r.id: probe.rate(r.id, window) for r in fleet.robots if r.id not in cut_off}
        forms = {i: r.attachment for i, r in probe.robots.items() if r.attachment is not None}
    finally:
        probe.close()
    problems.sort(key=lambda p: -1 if p.robot is None else p.robot)
    return Report(fleet, problems, inventory.notes(fleet), rates, forms)


# --------------------------------------------------------------------------- the command


def fleet_of_args(args, quiet: bool = False) -> Fleet:
    """The fleet of a command line: --inventory on the scenario flags, --initial-pose I:X,Y,THETA."""
    inv = inventory.load(args.inventory)
    scn = load_scenario(args, quiet=quiet)
    poses = {}
    for i, pose in getattr(args, "initial_pose", None) or []:
        if i in poses:
            raise BadInput(f"--initial-pose: robot {i} is given twice")
        poses[i] = pose
    return inventory.apply(inv, scn, poses)


def bus_args(args, fleet: Fleet):
    """Where a pre-flight reaches the robots: --connect (a client of that router), else a router session
    listening nowhere and connected to every robot's `connect` endpoint, else the local router."""
    import argparse

    if args.connect or not fleet.inventory.endpoints:
        return argparse.Namespace(**{**vars(args), "secure": None}), "client"
    return argparse.Namespace(**{**vars(args), "connect": list(fleet.inventory.endpoints), "secure": None}), "router"


def cmd_preflight(args, started: float) -> int:
    setup_logging(quiet=True)
    if args.secure is not None:
        raise BadInput("--secure: the pre-flight reads every robot's ROS 2 topics, which only each robot's own "
                       "identity may; run it on the robots' network without --secure (docs/deploy.md)")
    fleet = fleet_of_args(args, quiet=True)
    with StopEvent() as stop:  # every check, static or not: the whole list at once
        ns, mode = bus_args(args, fleet)
        try:
            bus = open_bus(ns, mode=mode, listen=[] if mode == "router" else None, stop=stop,
                           timeout_s=args.start_timeout)
        except Failure:  # no robot reachable: what was checked without them is still worth printing
            print(static_report(fleet).text().replace("pre-flight passed", "pre-flight: the checks that need no "
                                                      "robot passed; the robots were not reached"))
            raise
        try:
            report = check(bus, fleet, args.odom_timeout, args.odom_window, stop=stop,
                           cut_off=unreached(fleet) if mode == "router" else None)
        except InterruptedError:
            return 130
        finally:
            bus.close()
    print(report.text())
    if not report.ok:
        raise Failure(f"{len(report.problems)} problem(s); no robot was moved")
    return 0
