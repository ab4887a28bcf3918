"""A real fleet's inventory (TOML, docs/deploy.md): which robot is which, and the pre-flight's static checks.

    inv = load("fleet.toml")                        # InventoryError (a ScenarioError: file, key, reason)
    fleet = apply(inv, scn, poses={3: (x, y, th)})  # this run's robots: start, limits, drive settings
    fleet.scenario                                  # the scenario with the robots' real starts
    problems = static_problems(fleet)               # pre-flight checks that need no network: [Problem]

The file:

    fleet = "lab"                          # optional: the swarm's name (--fleet beats it)

    [[robot]]                              # one table a robot
    id = 0                                 # required: the robots of the scenario, 0 .. N-1, each once
    drive = "ros2"                         # how the agent meets the robot (ros2: the only real drive so far)
    flavor = "rmw_zenoh"                   # or "bridge" (zenoh-bridge-ros2dds on the robot)
    namespace = "robot0"                   # its ROS namespace (default robot<id>)
    domain = 0                             # its ROS_DOMAIN_ID (default 0)
    twist = "plain"                        # cmd_vel as Twist, "stamped" (TwistStamped: TurtleBot3 on Jazzy), or
                                           # "auto" (the type the robot subscribes, as its drive finds it)
    attachment = "auto"                    # rmw_zenoh's attachment form: auto (its odometry's), v1 or v2
    connect = "tcp/192.168.1.20:7447"      # its zenoh router or bridge (optional)
    initial_pose = [-1.0, -2.5, 0.0]       # where it stands, x [m], y [m], theta [rad] (default: the scenario's start)
    v_max = 0.2                            # [m/s], may only tighten the scenario's control.v_max
    w_max = 2.0                            # [rad/s], may only tighten control.w_max
    cmd_timeout = 0.5                      # [s] the base's own: how long it executes a cmd_vel with no newer one
                                           # (twist_mux, a velocity smoother); real time's safety rule counts it
    model = "burger"                       # or "waffle", "waffle_pi": ROBOTIS's limits (v_max, w_max unless
                                           # given, tighter) and footprint (bodies.r >= twice its radius)

Precedence: a flag beats the inventory, which beats the scenario. The scenario gives the starts and
the limits; the inventory may move a start (`initial_pose`, where the robot really stands) and
tighten a limit, never loosen one; `--initial-pose I:X,Y,THETA` moves one robot's start again.

A `model` (MODELS: ROBOTIS's values) gives the robot's v_max and w_max where the row gives none (a row's own may
only be tighter than the model's) and its footprint radius rho: the scenario's bodies.r (the distance of two
robots' centres at contact) must be at least 2 rho, and every obstacle's r at least rho.

Pre-flight (static part; docs/deploy.md): every robot has both limits and a footprint within r; every leader segment is
within PREFLIGHT_SHARE of every robot's limits (|v| <= 0.8 v_max, |w| <= 0.8 w_max: a follower
away from its slot needs the rest to catch up) and v_max >= control.vt; starts at least r apart (the
referee's collision distance), outside every obstacle's r, and inside arena.bounds. The odometry
check needs the robots and lives with the command (swarm.cli.preflight). Pure: no zenoh, no I/O
but reading the file.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from swarm.core.geometry import pairs_within
from swarm.core.scenario import Scenario, ScenarioError
from swarm.core.scenario_file import MAX_COORD, MAX_ROBOTS, _Reader
from swarm.core.toml_reader import read_toml
from swarm.proto import ros2

if TYPE_CHECKING:
    _Pose = tuple[float, float, float]

DRIVES = ("ros2",)
FLAVORS = ("rmw_zenoh", "bridge")
TWISTS = ("plain", "stamped", "auto")  # auto: the robot says (its token, its bridge's route)
ATTACHMENTS = ("auto", "v1", "v2")  # swarm.proto.ros2.ATTACHMENT_FORMS, or the robot's own
PREFLIGHT_SHARE = 0.8  # a leader segment may use this share of a robot's speed limits
ROBOT_KEYS = ("id", "drive", "flavor", "namespace", "domain", "twist", "attachment", "connect", "initial_pose",
              "v_max", "w_max", "cmd_timeout", "model")


@dataclass(frozen=True)
class RobotModel:
    """A robot model's limits and footprint, as its maker gives them."""

    name: str
    v_max: float  # m/s
    w_max: float  # rad/s
    radius: float  # m: the footprint's radius (ROBOTIS's navigation robot_radius)


# ROBOTIS's TurtleBot3 values: the teleop's maximum speeds (the firmware clamps to about these) and the navigation
# stack's robot_radius
MODELS = {m.name: m for m in (RobotModel("burger", 0.22, 2.84, 0.105), RobotModel("waffle", 0.26, 1.82, 0.22),
                              RobotModel("waffle_pi", 0.26, 1.82, 0.22))}


def model_limits(model: str | None) -> tuple[float, float] | None:
    """A model's (v_max, w_max) (--robot-model); None without one."""
    return None if model is None else (MODELS[model].v_max, MODELS[model].w_max)
_FLEET = re.compile(r"^[A-Za-z0-9_\-]{1,64}$")  # swarm.proto.keys' fleet names
_ENDPOINT = re.compile(r"^(tcp|tls|udp|quic|ws|unixsock-stream)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+):([0-9]{1,5})$")


class InventoryError(ScenarioError):
    """An inventory that cannot be used: `where` is the file, `key` the dotted key (exit 2)."""


@dataclass(frozen=True)
class RobotEntry:
    """One [[robot]] table, checked; `key` says where it is in the file ("robot[2]")."""

    id: int
    key: str
    drive: str = "ros2"
    flavor: str = "rmw_zenoh"
    namespace: str = ""
    domain: int = 0
    twist: str = "plain"
    connect: str | None = None
    initial_pose: tuple[float, float, float] | None = None
    v_max: float | None = None  # m/s
    w_max: float | None = None  # rad/s
    cmd_timeout: float | None = None  # s: the base's own cmd_vel timeout (None: not known)
    attachment: str = "auto"  # rmw_zenoh's attachment form: auto (the robot's odometry says), v1 or v2
    model: str | None = None  # a MODELS name: its limits where v_max/w_max are not given, and its footprint


@dataclass(frozen=True)
class Inventory:
    where: str
    fleet: str | None
    robots: tuple[RobotEntry, ...]  # by id

    def entry(self, i: int) -> RobotEntry:
        for e in self.robots:
            if e.id == i:
                return e
        ids = ", ".join(str(e.id) for e in self.robots)
        raise InventoryError(self.where, "robot", f"has no robot {i} (its robots: {ids})")

    @property
    def endpoints(self) -> tuple[str, ...]:
        """Every robot's `connect` endpoint, each once, in id order."""
        return tuple(dict.fromkeys(e.connect for e in self.robots if e.connect))


@dataclass(frozen=True)
class FleetRobot:
    """One robot of this run: its inventory entry, its start and limits, and where each came from."""

    entry: RobotEntry
    start: tuple[float, float, float]  # x [m], y [m], theta [rad]
    start_from: str  # "the scenario", "the inventory (robot[k].initial_pose)", "--initial-pose"
    v_max: float | None  # m/s, the tighter of the scenario's and the inventory's (None: neither has one)
    w_max: float | None  # rad/s
    v_from: str  # where v_max comes from
    w_from: str

    @property
    def id(self) -> int:
        return self.entry.id


@dataclass(frozen=True)
class Fleet:
    """An inventory applied to a scenario: `scenario` has the robots' real starts (its limits are the
    scenario's: each robot's own, maybe tighter, are in `robots`); `given` is the scenario as given
    (its digest is the run's: the inventory belongs to the fleet, not to the scenario)."""

    inventory: Inventory
    given: Scenario
    scenario: Scenario
    robots: tuple[FleetRobot, ...]  # by id, one for each robot of the scenario

    def limits(self, i: int) -> tuple[float, float]:
        """Robot i's (v_max, w_max) for its configuration (0.0: none)."""
        r = self.robots[i]
        return (r.v_max or 0.0, r.w_max or 0.0)


@dataclass(frozen=True)
class Problem:
    """A pre-flight failure: which robot (None: the fleet as a whole) and why."""

    robot: int | None
    reason: str

    def __str__(self) -> str:
        return self.reason if self.robot is None else f"robot {self.robot}: {self.reason}"


# --------------------------------------------------------------------------- reading


def load(path: str | Path) -> Inventory:
    """Read and check an inventory file (InventoryError naming the file, the key and the reason)."""
    where = str(path)
    try:
        doc = read_toml(where, "inventory file (TOML)")
    except ScenarioError as e:
        raise InventoryError(e.where, e.key, e.reason) from None
    return parse(doc, where)


def parse(doc: dict[str, Any], where: str) -> Inventory:
    """Check a parsed inventory document."""
    rd = _Reader(where)
    try:
        rd.table(doc, "", ("fleet", "robot"), ("robot",))
        fleet = doc.get("fleet")
        if fleet is not None and (not isinstance(fleet, str) or not _FLEET.match(fleet)):
            raise rd.fail("fleet", f"must be 1-64 characters of letters, digits, '_' or '-', got {fleet!r}")
        rows = doc["robot"]
        if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) for r in rows):
            raise rd.fail("robot", "must be one or more [[robot]] tables")
        if len(rows) > MAX_ROBOTS:
            raise rd.fail("robot", f"lists {len(rows)} robots; a fleet has at most {MAX_ROBOTS}")
        robots = [_robot(rd, row, f"robot[{k}]") for k, row in enumerate(rows)]
    except ScenarioError as err:
        raise InventoryError(err.where, err.key, err.reason) from None
    seen: dict[int, str] = {}
    names: dict[tuple[int, str], str] = {}
    for e in robots:
        if e.id in seen:
            raise InventoryError(where, f"{e.key}.id", f"robot {e.id} is listed twice (also {seen[e.id]})")
        seen[e.id] = e.key
        topic = (e.domain, e.namespace)
        if topic in names:
            raise InventoryError(where, f"{e.key}.namespace", f"namespace {e.namespace!r} on domain {e.domain} is "
                                 f"also {names[topic]}'s: two robots would share cmd_vel and odom")
        names[topic] = e.key
    return Inventory(where, fleet, tuple(sorted(robots, key=lambda e: e.id)))


def _robot(rd: _Reader, row: dict[str, Any], key: str) -> RobotEntry:
    rd.table(row, key, ROBOT_KEYS, ("id",))
    i = rd.integer(row["id"], f"{key}.id")
    if i >= MAX_ROBOTS:
        raise rd.fail(f"{key}.id", f"must be below {MAX_ROBOTS}, got {i}")
    drive = rd.choice(row.get("drive", "ros2"), f"{key}.drive", DRIVES)
    flavor = rd.choice(row.get("flavor", "rmw_zenoh"), f"{key}.flavor", FLAVORS)
    twist = rd.choice(row.get("twist", "plain"), f"{key}.twist", TWISTS)
    try:
        namespace = ros2.check_namespace(row.get("namespace", f"robot{i}"))
    except ros2.Ros2Error as e:
        raise rd.fail(f"{key}.namespace", str(e)) from None
    domain = rd.integer(row.get("domain", 0), f"{key}.domain")
    if domain > 232:
        raise rd.fail(f"{key}.domain", f"a ROS domain id is in 0..232, got {domain}")
    connect = row.get("connect")
    if connect is not None and (not isinstance(connect, str) or not _ENDPOINT.match(connect)
                                or not 0 < int(connect.rpartition(":")[2]) < 65536):
        raise rd.fail(f"{key}.connect", f"must be a zenoh endpoint like tcp/192.168.1.20:7447, got {connect!r}")
    pose = None
    if "initial_pose" in row:
        pose = cast("_Pose", tuple(rd.vector(row["initial_pose"], f"{key}.initial_pose", 3, "x, y, theta")))
        for c in range(2):
            rd.number(pose[c], f"{key}.initial_pose[{c}]", bound=MAX_COORD)
    v_max = rd.number(row["v_max"], f"{key}.v_max", gt=0) if "v_max" in row else None
    w_max = rd.number(row["w_max"], f"{key}.w_max", gt=0) if "w_max" in row else None
    timeout = rd.number(row["cmd_timeout"], f"{key}.cmd_timeout", gt=0) if "cmd_timeout" in row else None
    if timeout is not None and timeout > 60.0:
        raise rd.fail(f"{key}.cmd_timeout", f"must be at most 60 s (a base that keeps a command longer is not "
                                            f"stopped by anything swarm can do), got {timeout:g}")
    attachment = rd.choice(row.get("attachment", "auto"), f"{key}.attachment", ATTACHMENTS)
    model = rd.choice(row["model"], f"{key}.model", tuple(MODELS)) if "model" in row else None
    if model is not None:
        m = MODELS[model]
        for name, mine, most, unit in (("v_max", v_max, m.v_max, "m/s"), ("w_max", w_max, m.w_max, "rad/s")):
            if mine is not None and mine > most:
                raise rd.fail(f"{key}.{name}", f"{mine:g} {unit} is more than a {model} can do ({most:g} {unit}); "
                                               f"leave it out to take the {model}'s, or lower it")
    return RobotEntry(i, key, drive, flavor, namespace, domain, twist, connect, pose, v_max, w_max, timeout, attachment,
                      model)


# --------------------------------------------------------------------------- applying to a scenario


def apply(inv: Inventory, scn: Scenario, poses: dict[int, tuple[float, float, float]] | None = None) -> Fleet:
    """The inventory on scenario `scn`: the same robots (InventoryError otherwise), limits only tightened
    (InventoryError for a looser one), starts from `poses` (--initial-pose), else the inventory's
    initial_pose, else the scenario's. The starts are not checked here: that is the pre-flight's job."""
    ids = {e.id for e in inv.robots}
    extra = sorted(ids - set(range(scn.n)))
    if extra:
        e = inv.entry(extra[0])
        raise InventoryError(inv.where, f"{e.key}.id", f"robot {e.id} is not in scenario {scn.name!r} ({scn.n} robots: "
                             f"ids 0..{scn.n - 1}); give --robots {len(ids)} if the scenario can be resized")
    missing = sorted(set(range(scn.n)) - ids)
    if missing:
        shown = ", ".join(map(str, missing[:12])) + (" ..." if len(missing) > 12 else "")
        raise InventoryError(inv.where, "robot", f"scenario {scn.name!r} has {scn.n} robots (ids 0..{scn.n - 1}); "
                             f"the inventory has no robot {shown} (give --robots {len(ids)} if the scenario can be "
                             "resized, or list every robot)")
    poses = dict(poses or {})
    for i, p in poses.items():
        if not 0 <= i < scn.n:
            raise ScenarioError("command line", "--initial-pose", f"robot {i} is not in the scenario ({scn.n} robots: "
                                f"ids 0..{scn.n - 1})")
        if len(p) != 3 or not all(math.isfinite(a) for a in p) or max(abs(p[0]), abs(p[1])) > MAX_COORD:
            raise ScenarioError("command line", "--initial-pose", f"robot {i}: expected finite x, y, theta, got {p}")
    c = scn.control
    robots = []
    starts = np.array(scn.poses, float)
    for e in inv.robots:
        v_max, v_from = _tighter(inv, e, "v_max", c.v_max, "m/s")
        w_max, w_from = _tighter(inv, e, "w_max", c.w_max, "rad/s")
        if e.id in poses:
            start, start_from = cast("_Pose", tuple(map(float, poses[e.id]))), "--initial-pose"
        elif e.initial_pose is not None:
            start, start_from = e.initial_pose, f"the inventory ({e.key}.initial_pose)"
        else:
            start, start_from = cast("_Pose", tuple(map(float, scn.poses[e.id]))), "the scenario"
        starts[e.id] = start
        robots.append(FleetRobot(e, start, start_from, v_max, w_max, v_from, w_from))
    return Fleet(inv, scn, scn.replace(poses=np.ascontiguousarray(starts)), tuple(robots))


def _tighter(inv: Inventory, e: RobotEntry, name: str, scenario: float | None, unit: str) -> tuple[float | None, str]:
    mine = getattr(e, name)
    if mine is None and e.model is not None:  # the model's, or the scenario's where it is tighter
        most = getattr(MODELS[e.model], name)
        if scenario is not None and scenario <= most:
            return scenario, f"the scenario's control.{name}"
        return most, f"a {e.model}'s ({e.key}.model)"
    if mine is None:
        return scenario, (f"the scenario's control.{name}" if scenario is not None else "nowhere")
    if scenario is not None and mine > scenario:
        raise InventoryError(inv.where, f"{e.key}.{name}", f"{mine:g} {unit} would loosen the scenario's "
                             f"control.{name} = {scenario:g} {unit}; an inventory may only tighten a limit")
    return mine, f"the inventory's {e.key}.{name}"


# --------------------------------------------------------------------------- static pre-flight


def static_problems(fleet: Fleet) -> list[Problem]:
    """The pre-flight's checks that need no network, in robot order (see the module's docstring)."""
    scn = fleet.scenario
    out: list[Problem] = []
    segs = scn.leader.segments
    vt = scn.control.vt
    for r in fleet.robots:
        i = r.id
        for name, value, unit in (("v_max", r.v_max, "m/s"), ("w_max", r.w_max, "rad/s")):
            if value is None:
                out.append(Problem(i, f"no {name}: neither the scenario's control.{name} nor the inventory gives one, "
                                      f"and a real robot needs a limit [{unit}]"))
        if r.v_max is not None:
            k = max(range(len(segs)), key=lambda k: abs(segs[k].v))
            if abs(segs[k].v) > PREFLIGHT_SHARE * r.v_max * (1 + 1e-12):
                out.append(Problem(i, f"leader.segments[{k}] moves at |v| = {abs(segs[k].v):g} m/s, more than "
                                      f"{PREFLIGHT_SHARE:g} x v_max = {PREFLIGHT_SHARE * r.v_max:.4g} m/s (v_max "
                                      f"{r.v_max:g} m/s from {r.v_from}): a follower could not catch up"))
            if r.v_max < vt:
                out.append(Problem(i, f"v_max = {r.v_max:g} m/s (from {r.v_from}) is below control.vt = {vt:g} m/s"))
        if r.w_max is not None:
            k = max(range(len(segs)), key=lambda k: abs(segs[k].w))
            if abs(segs[k].w) > PREFLIGHT_SHARE * r.w_max * (1 + 1e-12):
                out.append(Problem(i, f"leader.segments[{k}] turns at |w| = {abs(segs[k].w):g} rad/s, more than "
                                      f"{PREFLIGHT_SHARE:g} x w_max = {PREFLIGHT_SHARE * r.w_max:.4g} rad/s (w_max "
                                      f"{r.w_max:g} rad/s from {r.w_from}): a follower could not catch up"))
        m = MODELS.get(r.entry.model or "")
        if m is not None and 2 * m.radius > scn.r * (1 + 1e-12):
            out.append(Problem(i, f"two {m.name}s touch with their centres {2 * m.radius:g} m apart (a footprint radius of "
                                  f"{m.radius:g} m), more than the scenario's bodies.r = {scn.r:g} m, the distance the "
                                  f"law keeps robots apart by and the referee counts a collision at: give bodies.r >= "
                                  f"{2 * m.radius:g}"))
        if m is not None and len(scn.obstacles) and float(np.min(scn.obstacles[:, 2])) < m.radius * (1 - 1e-12):
            k = int(np.argmin(scn.obstacles[:, 2]))
            out.append(Problem(i, f"obstacle {k}'s r = {scn.obstacles[k, 2]:g} m is less than a {m.name}'s footprint "
                                  f"radius {m.radius:g} m: a robot would reach into it before the referee counts a "
                                  "collision"))
    out += _start_problems(fleet)
    return sorted(out, key=lambda p: (-1 if p.robot is None else p.robot))


def _start_problems(fleet: Fleet) -> list[Problem]:
    scn = fleet.scenario
    out: list[Problem] = []
    x, y = scn.poses[:, 0], scn.poses[:, 1]
    where = {r.id: r.start_from for r in fleet.robots}
    if scn.bounds is not None:
        xmin, xmax, ymin, ymax = scn.bounds
        for i in np.flatnonzero((x < xmin) | (x > xmax) | (y < ymin) | (y > ymax)).tolist():
            out.append(Problem(i, f"starts at ({x[i]:g}, {y[i]:g}) (from {where[i]}), outside arena.bounds "
                                  f"[{xmin:g}, {xmax:g}, {ymin:g}, {ymax:g}]"))
    ii, jj, dd = pairs_within(x, y, float(scn.r))
    for a, b, dist in sorted(zip(ii.tolist(), jj.tolist(), dd.tolist())):
        text = (f"starts {dist:.3g} m from robot {{other}}, closer than r = {scn.r:g} m (starts from {where[a]} "
                f"and {where[b]})")
        out.append(Problem(a, text.format(other=b)))
        out.append(Problem(b, text.format(other=a)))
    for o, (ox, oy, orr, _oR) in enumerate(scn.obstacles.tolist()):
        dist = np.hypot(x - ox, y - oy)
        for k in np.flatnonzero(dist < orr).tolist():
            out.append(Problem(k, f"starts {dist[k]:.3g} m from obstacle {o} at ({ox:g}, {oy:g}), inside its r = "
                                  f"{orr:g} m (start from {where[k]})"))
    return out


def notes(fleet: Fleet) -> list[str]:
    """Warnings that do not stop a run."""
    out = []
    if fleet.scenario.bounds is None:
        out.append("the scenario has no arena.bounds: no robot is stopped at a boundary (give [arena] bounds = "
                   "[xmin, xmax, ymin, ymax] in the scenario)")
    unknown = [r.id for r in fleet.robots if r.entry.cmd_timeout is None]
    if unknown:
        ids = ", ".join(map(str, unknown[:12])) + (" ..." if len(unknown) > 12 else "")
        out.append(f"no cmd_timeout for robot{'s' if len(unknown) != 1 else ''} {ids}: should its agent die, the "
                   "safety rule cannot count how long its base goes on with the last command (give the base's own "
                   "cmd_vel timeout, in s, as cmd_timeout in its [[robot]] table)")
    return out


def describe(fleet: Fleet) -> str:
    """One line a robot: drive, topics, start, limits (for --dry-run and logs)."""
    lines = []
    for r in fleet.robots:
        e = r.entry
        lim = ", ".join(f"{n} {v:g}" for n, v in (("v_max", r.v_max), ("w_max", r.w_max)) if v is not None)
        lines.append(f"  robot {e.id}: {e.drive} {e.flavor} /{e.namespace} domain {e.domain} twist {e.twist}"
                     f"{' via ' + e.connect if e.connect else ''}{', a ' + e.model if e.model else ''}; start ({r.start[0]:g}, {r.start[1]:g}, "
                     f"{r.start[2]:g}) from {r.start_from}; {lim or 'no limits'}")
    return "\n".join(lines)
