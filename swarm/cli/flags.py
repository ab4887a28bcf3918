"""The `swarm` command line's shared pieces: the value types (a port, a probability, a pose...), the flag groups
several commands take (scenario, network, viewer, faults, ROS 2, run), and `swarm --version`. swarm.cli.parser
builds the parser from them with one module per group of commands (parser_runtime, parser_campaign)."""

from __future__ import annotations

import argparse
import math
import socket
import sys
from pathlib import Path

from swarm.launch.plan import VIZ_HOST

# --------------------------------------------------------------------------- swarm --version

DISTRIBUTION = "swarm"  # the distribution's name: [project] name in pyproject.toml
PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"  # in a source checkout


def version() -> str:
    """The installed distribution's version; not installed (run from a checkout), pyproject.toml's."""
    from importlib import metadata

    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return pyproject_version()


def pyproject_version(path: Path = PYPROJECT) -> str:
    """[project] version of the pyproject.toml at path, when it is this project's; else "unknown"."""
    import tomllib

    try:
        project = tomllib.loads(path.read_text(encoding="utf-8")).get("project")
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return "unknown"
    if not isinstance(project, dict) or project.get("name") != DISTRIBUTION or \
            not isinstance(project.get("version"), str):
        return "unknown"
    return project["version"]


class VersionAction(argparse.Action):
    """--version: print "swarm <version>" and exit 0. The version is looked up only then (not at each start
    of a process, which builds the parser)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        sys.stdout.write(f"{parser.prog} {version()}\n")
        sys.stdout.flush()
        parser.exit(0)


# --------------------------------------------------------------------------- argument types


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return value


def _record_hz(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0 (0: every step), got {text!r}")
    return value


def add_record_flags(g) -> None:
    g.add_argument("--record", type=Path, metavar="PATH.mcap",
                   help="record the run into an MCAP file (snapshots, reference, commands, statuses, events, "
                        "scenario, metrics; Foxglove opens it; swarm report and swarm replay read it)")
    g.add_argument("--record-hz", type=_record_hz, metavar="HZ",
                   help="with --record: snapshots per simulated second (default 20, rounded to whole control "
                        "steps: 25 at dt = 0.02; 0: every step)")


def int_at_least(minimum: int):
    """An argparse type: an integer >= minimum."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {text!r}")
        return value

    return parse


count_arg = int_at_least(1)
seed_arg = int_at_least(0)


def _port(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port in 0..65535 (0: a free one), got {text!r}")
    return value


def _local_host(text: str) -> str:
    """An argparse type: a host name or address of this machine (where a server can listen)."""
    try:
        infos = socket.getaddrinfo(text, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (socket.gaierror, UnicodeError) as e:
        raise argparse.ArgumentTypeError(f"unknown host {text!r} ({getattr(e, 'strerror', None) or e})") from None
    last: OSError | None = None
    for family, kind, proto, _, addr in infos:
        try:
            with socket.socket(family, kind, proto) as s:
                s.bind(addr)
            return text
        except OSError as e:
            last = e
    raise argparse.ArgumentTypeError(f"{text!r} is not an address of this machine "
                                     f"({last.strerror if last else 'no address'})")


def add_viz_flags(p: argparse.ArgumentParser, switch: str | None) -> None:
    """The viewer's flags; `switch` is "--viz" (sim: off unless asked), "--no-viz" (up: on unless
    refused) or None (viz: always on)."""
    g = p.add_argument_group("viewer (meshcat, in a browser)")
    if switch == "--viz":
        g.add_argument("--viz", action="store_true",
                       help="play the run in the browser viewer at --speed times real time; the viewer stays "
                            "up after the run until Ctrl-C")
        g.add_argument("--speed", type=positive_float, metavar="X",
                       help="with --viz: simulated seconds per wall second (default 1)")
    elif switch == "--no-viz":
        g.add_argument("--no-viz", action="store_true", help="do not start the viewer")
    g.add_argument("--viz-host", type=_local_host, metavar="H",
                   help=f"where the viewer's web server listens (default {VIZ_HOST}: this machine only; "
                        "0.0.0.0: every interface)")
    g.add_argument("--viz-port", type=_port, metavar="P", help="the viewer's web port (default: a free one)")
    g.add_argument("--viz-rings", action="store_true", help="draw every robot's avoidance ring R")
    g.add_argument("--viz-timeout", type=positive_float, metavar="S",
                   help="seconds the viewer's web server may take to start (default 60; a loaded machine can "
                        "need tens of seconds); past it a run goes on without the viewer and says how to attach "
                        "one later")


def add_scenario_flags(p: argparse.ArgumentParser, default: str) -> None:
    g = p.add_argument_group("scenario (a flag beats the file, which beats the built-in default)")
    g.add_argument("--scenario", default=default, metavar="NAME|FILE",
                   help=f"built-in name (paper, paper-50hz, turtlebot3) or a TOML file (default: {default})")
    g.add_argument("--robots", type=count_arg, metavar="N",
                   help="number of robots (resizes built-in and generated scenarios; default: the scenario's, 37 "
                        "for paper)")
    g.add_argument("--seed", type=seed_arg, metavar="S",
                   help="random seed for starts and slot assignment (default: the scenario's run.seed, 0 for the "
                        "built-ins)")
    g.add_argument("--duration", type=positive_float, metavar="T",
                   help="simulated seconds to run (default: the scenario's run.duration, 120 for paper)")
    g.add_argument("--dt", type=positive_float, metavar="DT",
                   help="control period [s] (default: the scenario's run.dt, 0.001 for paper, 0.02 for paper-50hz)")
    g.add_argument("--governor", action=argparse.BooleanOptionalAction, default=None,
                   help="the discrete-time safety governor (default: the scenario's control.governor)")
    add_fault_flags(g)


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"a probability is in [0, 1], got {text!r}")
    return value


class Joined(argparse.Action):
    """A comma-list flag that may be repeated: `--kill 2@5 --kill 3@6` is `--kill 2@5,3@6`."""

    def __call__(self, parser, namespace, values, option_string=None):
        before = getattr(namespace, self.dest, None)
        setattr(namespace, self.dest, values if before is None else f"{before},{values}")


def add_fault_flags(g) -> None:
    """Faults (docs/faults.md): a table of their own, and the two shorthands."""
    g.add_argument("--faults", metavar="FILE",
                   help="a TOML file holding a [faults] table: it replaces the scenario's (docs/faults.md)")
    g.add_argument("--drop", type=_probability, metavar="P",
                   help="lose every message (state, pose, cmd, ref) with probability P: one drop rule of class all")
    g.add_argument("--kill", metavar="ID@T,...", action=Joined,
                   help="kill robot ID's process at T s (for example 2@15,5@15; repeatable): one kill rule a robot. "
                        "T at or after the run's end is refused here; in a --faults file it is only warned "
                        "about, since one file may serve runs of several durations")


def add_optional_scenario_flags(p: argparse.ArgumentParser, otherwise: str) -> None:
    """The scenario flags of a process that can also learn its scenario from the running swarm."""
    g = p.add_argument_group(f"scenario (optional: without it {otherwise})")
    g.add_argument("--scenario", metavar="NAME|FILE", help="built-in name or TOML file (the same on every machine)")
    g.add_argument("--robots", type=count_arg, metavar="N", help="with --scenario: number of robots")
    g.add_argument("--seed", type=seed_arg, metavar="S", help="with --scenario: random seed")
    g.add_argument("--duration", type=positive_float, metavar="T", help="with --scenario: simulated seconds")
    g.add_argument("--dt", type=positive_float, metavar="DT", help="with --scenario: control period [s]")
    g.add_argument("--governor", action=argparse.BooleanOptionalAction, default=None,
                   help="with --scenario: the safety governor")
    add_fault_flags(g)


def initial_pose_arg(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected x,y,theta (three finite numbers: m, m, rad), got {text!r}")
    return values


def robot_pose_arg(text: str) -> tuple[int, tuple[float, float, float]]:
    """I:X,Y,THETA: robot I's start [m, m, rad]."""
    head, sep, tail = text.partition(":")
    try:
        i = int(head)
    except ValueError:
        i = -1
    if not sep or i < 0:
        raise argparse.ArgumentTypeError(f"expected I:X,Y,THETA (a robot id, then three numbers), got {text!r}")
    return i, initial_pose_arg(tail)


def robot_id(text: str) -> int | None:
    """--id: a robot id (an integer >= 0), or "auto" (None): claim the lowest free one from the world."""
    if text == "auto":
        return None
    return int_at_least(0)(text)


def add_fleet_flags(g, robot: bool = False) -> None:
    """A real fleet's flags (docs/deploy.md): the inventory, the pre-flight, the robots' starts."""
    g.add_argument("--inventory", metavar="FILE",
                   help="the fleet's inventory (TOML): which robot is which, its drive, ROS 2 topics, endpoint, start "
                        "and limits" + ("; --id I takes row I" if robot else ""))
    if not robot:
        g.add_argument("--no-preflight", action="store_true",
                       help="with --inventory: skip the pre-flight (odometry fresh, starts apart, inside the arena and "
                            "outside obstacles, the leader within 0.8 of every robot's limits)")
        g.add_argument("--initial-pose", type=robot_pose_arg, action="append", metavar="I:X,Y,THETA",
                       help="with --inventory: robot I stands at X,Y,THETA (beats the inventory and the scenario); "
                            "repeatable")


def _domain(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if not 0 <= value <= 232:
        raise argparse.ArgumentTypeError(f"a ROS domain id is in 0..232, got {text!r}")
    return value


def add_ros2_flags(g, world: bool | str = False) -> None:
    """The ROS 2 wire's flags (world=True: the simulated fleet of swarm world; "up": swarm up's, which also starts
    the robots; "robot": a robot's drive)."""
    if world is not True:
        g.add_argument("--ros-flavor", choices=("rmw_zenoh", "bridge"), default="rmw_zenoh",
                       help="how the robot speaks ROS 2 over zenoh: rmw_zenoh (ROS 2 nodes on rmw_zenoh_cpp, keys "
                            "found from their liveliness tokens) or bridge (zenoh-bridge-ros2dds); default rmw_zenoh")
    if world == "robot":
        g.add_argument("--twist", choices=("auto", "plain", "stamped"), default="auto",
                       help="cmd_vel as geometry_msgs/Twist (plain: TurtleBot3 on Humble) or TwistStamped (stamped: "
                            "TurtleBot3 on Jazzy); auto (default): the type the robot subscribes (rmw_zenoh: its "
                            "liveliness token; bridge: the route its zenoh-bridge-ros2dds announces; plain when it "
                            "announces none); a given type the robot does not take is refused, naming the right one")
    else:
        g.add_argument("--twist", choices=("plain", "stamped"), default="plain",
                       help="cmd_vel as geometry_msgs/Twist (plain: TurtleBot3 on Humble) or TwistStamped (stamped: "
                            "TurtleBot3 on Jazzy); default plain")
    g.add_argument("--domain", type=_domain, default=0, metavar="D", help="the ROS domain id (default 0)")
    if world == "robot":
        g.add_argument("--distro", choices=("jazzy", "humble", "rolling"),
                       help="the robot's ROS 2 distribution, for what its drive cannot learn from the robot: behind a "
                            "bridge that announces no route, --twist auto commands TwistStamped on jazzy and rolling "
                            "(a TurtleBot3's default there) and Twist on humble (without --distro: Twist)")
        g.add_argument("--robot-model", choices=("burger", "waffle", "waffle_pi"), metavar="MODEL",
                       help="the robot's model: burger, waffle or waffle_pi (ROBOTIS's TurtleBot3 limits: 0.22 m/s and "
                            "2.84 rad/s, 0.26 m/s and 1.82 rad/s): the run's v_max and w_max are tightened to them, "
                            "so the law, its governor and every command keep to what the robot can do")
        g.add_argument("--rmw-zenoh-attachment", choices=("auto", "v1", "v2"), default="auto",
                       help="rmw_zenoh flavour: the form of the attachment commands carry: v2 (33 bytes: rmw_zenoh "
                            "Rolling >= 0.6.0, Jazzy >= 0.2.4, Humble >= 0.1.2), v1 (named fields: the releases "
                            "before), or auto (default): the form of the robot's own odometry")
    else:
        g.add_argument("--distro", choices=("jazzy", "humble", "rolling"), default="jazzy",
                       help="the simulated robots' ROS 2 distribution: jazzy (RIHS01 type hashes in keys and tokens, "
                            "default), rolling (the same) or humble (TypeHashNotSupported)")
        g.add_argument("--rmw-zenoh-attachment", choices=("v1", "v2"), default="v2",
                       help="the simulated robots' rmw_zenoh release: v2 (the 33-byte attachment, default) or v1 (named "
                            "fields, releases before Rolling 0.6.0, Jazzy 0.2.4, Humble 0.1.2); a command in the other "
                            "form is dropped, as that release does" + ("; the robots find the form by themselves"
                                                                      if world == "up" else ""))


def zenoh_id(s: str) -> str:
    """A zenoh id as zenoh writes it: 1 to 32 lower-case hex digits, not 0, no leading 0."""
    if not (1 <= len(s) <= 32) or any(c not in "0123456789abcdef" for c in s) or s[0] == "0":
        raise argparse.ArgumentTypeError(f"not a zenoh id: {s!r} (1 to 32 lower-case hex digits, the first not 0)")
    return s


def add_net_flags(p: argparse.ArgumentParser, listen: bool = False, connect_help: str | None = None,
                  starts: bool = False, started: bool = False, router: bool = False) -> None:
    """The flags of a command on the bus: --log-level, and zenoh's (--listen when it may run a router, --connect,
    --fleet, --zenoh-config, --secure). starts: it starts the other processes (swarm up). started: a process
    swarm up starts (--router-checks). router: swarm router (--zid)."""
    p.add_argument("--log-level", choices=("debug", "info", "warning", "error"), metavar="LEVEL",
                   help="what the process logs on stderr: debug, info (default), warning or error" +
                        ("; passed to every process it starts (their logs are in its log folder)" if starts else ""))
    g = p.add_argument_group("network (zenoh)")
    if listen:
        g.add_argument("--listen", action="append", metavar="ENDPOINT",
                       help="where the router listens (default tcp/127.0.0.1:7447; tcp/0.0.0.0:7447 "
                            "accepts other machines); repeatable")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=connect_help or "the router to connect to (default tcp/127.0.0.1:7447)")
    g.add_argument("--fleet", default="default", metavar="NAME",
                   help="the swarm's name: key prefix swarm/NAME, so several swarms share a router (default: default)")
    g.add_argument("--zenoh-config", metavar="FILE",
                   help="a zenoh JSON5 config file (TLS, authentication); our settings are applied on top")
    g.add_argument("--secure", metavar="DIR",
                   help="the fleet's certificates and access control (a directory of `swarm secure init`, or one "
                        "identity's folder): mutual TLS, each process with its role (docs/security.md)")
    g.add_argument("--multicast", action="store_true", help="turn multicast scouting on (off by default)")
    if started:
        g.add_argument("--router-checks", type=zenoh_id, metavar="ZID",
                       help="leave zenoh's ingress checks to the router whose zenoh id is ZID (a swarm router started "
                            "with --zid ZID): it drops payloads beyond the codec's size limits and puts on key "
                            "expressions with wildcards as they come in, so this session does not check them again "
                            "(zenoh's CPU for each message received). Checked as the session opens: on any other "
                            "router this process keeps its checks. swarm up gives it to the processes it starts on "
                            "its own router")
    if router:
        g.add_argument("--zid", type=zenoh_id, metavar="ZID",
                       help="this router's zenoh id (hex, up to 32 digits; default: a random one): processes given "
                            "--router-checks ZID leave their ingress checks to it")


def add_run_flags(p: argparse.ArgumentParser, up: bool = False) -> None:
    g = p.add_argument_group("run")
    if p.prog.endswith(" robot"):  # a robot takes the mode of the world's run
        g.add_argument("--mode", choices=("lockstep", "realtime"), default=None,
                       help="the run's mode is the world's (swarm world --mode); given, this robot refuses a run of "
                            "the other mode (exit 2)")
    else:
        g.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                       help="lockstep: the world owns the clock, deterministic, equal to swarm sim (default); "
                            "realtime: every process on its own clock")
    g.add_argument("--rate", type=positive_float, metavar="HZ",
                   help="control rate (sets dt = 1/HZ; the built-in paper-50hz runs at 50 Hz)")
    if up or p.prog.endswith("world"):
        g.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                       help="real time only: simulated seconds per wall second (default 1; lock-step "
                            "runs as fast as the robots answer)")
        g.add_argument("--watchdog", type=positive_float, default=0.5, metavar="S",
                       help="stop a robot whose newest command is older than S seconds (default 0.5)")
        g.add_argument("--tick-timeout", type=positive_float, default=1.0, metavar="S",
                       help="lock-step: wall seconds to wait for a tick's commands before counting misses "
                            "(default 1)")
        g.add_argument("--lost-timeout", type=positive_float, default=10.0, metavar="S",
                       help="how long the leader, or every robot at once, may be away before the run ends with a "
                            "failure (lock-step holds its tick meanwhile; default 10)")
        g.add_argument("--metrics", type=Path, metavar="PATH", help="write the metrics JSON (its keys: docs/metrics.md); swarm up always writes it to the log directory too")
        g.add_argument("--trace", type=Path, metavar="PATH.npz",
                       help="write every robot's pose at every sample (numpy .npz: q[k, i] = x, y, theta; t[k] its simulated "
                            "time, which in real time may skip periods the world fell behind on)")
        add_violation_flag(g)
        if up:
            add_record_flags(g)
    g.add_argument("--start-timeout", type=positive_float, default=60.0, metavar="S",
                   help="seconds the start may go without one more process alive (default 60); robots start "
                        "in waves of 8 a core" if up else "seconds to wait for the other processes at start "
                        "(default 60)")


def add_violation_flag(g) -> None:
    g.add_argument("--allow-violations", action="store_true",
                   help="exit 0 even when a check failed (collisions, missed commands, lock-step overruns, robots "
                        "lost); without it such a run exits 3")


MAX_CAMPAIGN_RUNS = 100_000  # seeds x drop probabilities


def seed_list(text: str) -> tuple[int, ...]:
    """--seeds: A-B (A to B, both included), A, or a comma list of those; each seed an integer >= 0."""
    seeds: list[int] = []
    for item in text.split(","):
        a, dash, b = item.strip().partition("-")
        try:
            lo = int(a)
            hi = int(b) if dash else lo
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item.strip()!r} is not a seed or a range A-B of seeds "
                                             "(integers >= 0, e.g. 0-9 or 3)") from None
        if lo < 0 or hi < lo:
            raise argparse.ArgumentTypeError(f"{item.strip()!r}: a range A-B needs 0 <= A <= B")
        if hi - lo + 1 + len(seeds) > MAX_CAMPAIGN_RUNS:
            raise argparse.ArgumentTypeError(f"more than {MAX_CAMPAIGN_RUNS} seeds")
        for s in range(lo, hi + 1):
            if s in seeds:
                raise argparse.ArgumentTypeError(f"seed {s} is given twice")
            seeds.append(s)
    return tuple(seeds)


def drop_list(text: str) -> tuple[float, ...]:
    """--drop: probabilities P1,P2,... in [0, 1], each once (0: no drop rule)."""
    drops: list[float] = []
    for item in text.split(","):
        try:
            p = _probability(item.strip())
        except argparse.ArgumentTypeError as e:
            raise argparse.ArgumentTypeError(f"{item.strip()!r}: {e}") from None
        if p in drops:
            raise argparse.ArgumentTypeError(f"{item.strip()!r}: the probability {p:g} is given twice")
        drops.append(p)
    return tuple(drops)
