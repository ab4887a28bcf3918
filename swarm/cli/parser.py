"""The `swarm` command line: the argument parser (no command runs here; swarm.cli.main dispatches).

    swarm sim [--scenario paper|FILE.toml] [--robots N] [--seed S] [--duration T] [--dt DT]
              [--governor/--no-governor] [--metrics out.json] [--plots DIR] [--quiet]
              [--viz [--speed X] [--viz-host H] [--viz-port P] [--viz-rings]]
    swarm campaign [--scenario NAME|FILE] --seeds A-B [--drop P1,P2,...] [--faults FILE] [-j JOBS] -o DIR
    swarm scenario show NAME|FILE [--robots N] [--seed S]
    swarm scenario scale NAME|FILE --v-max V [--w-max W]
    swarm scenario check FILE...
    swarm up [--robots N] [--scenario ...] [--mode lockstep|realtime] [--rate HZ] [--metrics out.json] [--dry-run]
             [--no-viz | --viz-host H --viz-port P --viz-rings]
    swarm viz --connect ENDPOINT [--fleet NAME] [--scenario ...] [--viz-host H] [--viz-port P]
    swarm router | world | leader | robot --id I     (the processes `swarm up` starts; each runs alone
                                                     with --connect ENDPOINT, e.g. on another machine)
    swarm --version

Every subcommand and flag is in docs/cli.md, generated from this parser (python -m swarm.cli.reference).

Each subcommand's `func` names the module and function that runs it ("swarm.cli.up:cmd_up"), imported
only when that command runs: `swarm sim` never loads zenoh, a robot process never loads matplotlib.
"""

from __future__ import annotations

import argparse
import math
import socket
import sys
from pathlib import Path
from typing import Sequence

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


class _Version(argparse.Action):
    """--version: print "swarm <version>" and exit 0. The version is looked up only then (not at each start
    of a process, which builds the parser)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        sys.stdout.write(f"{parser.prog} {version()}\n")
        sys.stdout.flush()
        parser.exit(0)


# --------------------------------------------------------------------------- argument types


def _positive_float(text: str) -> float:
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


def _add_record_flags(g) -> None:
    g.add_argument("--record", type=Path, metavar="PATH.mcap",
                   help="record the run into an MCAP file (snapshots, reference, commands, statuses, events, "
                        "scenario, metrics; Foxglove opens it; swarm report and swarm replay read it)")
    g.add_argument("--record-hz", type=_record_hz, metavar="HZ",
                   help="with --record: snapshots per simulated second (default 20, rounded to whole control "
                        "steps: 25 at dt = 0.02; 0: every step)")


def _int_at_least(minimum: int):
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


_count = _int_at_least(1)
_seed = _int_at_least(0)


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


def _add_viz_flags(p: argparse.ArgumentParser, switch: str | None) -> None:
    """The viewer's flags; `switch` is "--viz" (sim: off unless asked), "--no-viz" (up: on unless
    refused) or None (viz: always on)."""
    g = p.add_argument_group("viewer (meshcat, in a browser)")
    if switch == "--viz":
        g.add_argument("--viz", action="store_true",
                       help="play the run in the browser viewer at --speed times real time; the viewer stays "
                            "up after the run until Ctrl-C")
        g.add_argument("--speed", type=_positive_float, metavar="X",
                       help="with --viz: simulated seconds per wall second (default 1)")
    elif switch == "--no-viz":
        g.add_argument("--no-viz", action="store_true", help="do not start the viewer")
    g.add_argument("--viz-host", type=_local_host, metavar="H",
                   help=f"where the viewer's web server listens (default {VIZ_HOST}: this machine only; "
                        "0.0.0.0: every interface)")
    g.add_argument("--viz-port", type=_port, metavar="P", help="the viewer's web port (default: a free one)")
    g.add_argument("--viz-rings", action="store_true", help="draw every robot's avoidance ring R")
    g.add_argument("--viz-timeout", type=_positive_float, metavar="S",
                   help="seconds the viewer's web server may take to start (default 60; a loaded machine can "
                        "need tens of seconds); past it a run goes on without the viewer and says how to attach "
                        "one later")


def _add_scenario_flags(p: argparse.ArgumentParser, default: str) -> None:
    g = p.add_argument_group("scenario (a flag beats the file, which beats the built-in default)")
    g.add_argument("--scenario", default=default, metavar="NAME|FILE",
                   help=f"built-in name (paper, paper-50hz, turtlebot3) or a TOML file (default: {default})")
    g.add_argument("--robots", type=_count, metavar="N",
                   help="number of robots (resizes built-in and generated scenarios)")
    g.add_argument("--seed", type=_seed, metavar="S", help="random seed for starts and slot assignment")
    g.add_argument("--duration", type=_positive_float, metavar="T", help="simulated seconds to run")
    g.add_argument("--dt", type=_positive_float, metavar="DT", help="control period [s]")
    g.add_argument("--governor", action=argparse.BooleanOptionalAction, default=None,
                   help="the discrete-time safety governor (default: the scenario's control.governor)")
    _add_fault_flags(g)


def _probability(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"a probability is in [0, 1], got {text!r}")
    return value


class _Once(argparse.Action):
    """A flag that may be given once: a second one would silently replace the first (a fault the user asked for
    would not happen), so it is refused."""

    def __call__(self, parser, namespace, values, option_string=None):
        if getattr(namespace, self.dest, None) is not None:
            parser.error(f"{option_string} given twice (the second would replace the first): give it once")
        setattr(namespace, self.dest, values)


class _Joined(argparse.Action):
    """A comma-list flag that may be repeated: `--kill 2@5 --kill 3@6` is `--kill 2@5,3@6`."""

    def __call__(self, parser, namespace, values, option_string=None):
        before = getattr(namespace, self.dest, None)
        setattr(namespace, self.dest, values if before is None else f"{before},{values}")


def _add_fault_flags(g) -> None:
    """Faults (docs/faults.md): a table of their own, and the two shorthands."""
    g.add_argument("--faults", metavar="FILE", action=_Once,
                   help="a TOML file holding a [faults] table: it replaces the scenario's (docs/faults.md)")
    g.add_argument("--drop", type=_probability, metavar="P", action=_Once,
                   help="lose every message (state, pose, cmd, ref) with probability P: one drop rule of class all")
    g.add_argument("--kill", metavar="ID@T,...", action=_Joined,
                   help="kill robot ID's process at T s (for example 2@15,5@15; repeatable): one kill rule a robot. "
                        "T at or after the run's end is refused here; in a --faults file it is only warned "
                        "about, since one file may serve runs of several durations")


def _add_optional_scenario_flags(p: argparse.ArgumentParser, otherwise: str) -> None:
    """The scenario flags of a process that can also learn its scenario from the running swarm."""
    g = p.add_argument_group(f"scenario (optional: without it {otherwise})")
    g.add_argument("--scenario", metavar="NAME|FILE", help="built-in name or TOML file (the same on every machine)")
    g.add_argument("--robots", type=_count, metavar="N", help="with --scenario: number of robots")
    g.add_argument("--seed", type=_seed, metavar="S", help="with --scenario: random seed")
    g.add_argument("--duration", type=_positive_float, metavar="T", help="with --scenario: simulated seconds")
    g.add_argument("--dt", type=_positive_float, metavar="DT", help="with --scenario: control period [s]")
    g.add_argument("--governor", action=argparse.BooleanOptionalAction, default=None,
                   help="with --scenario: the safety governor")
    _add_fault_flags(g)


def all_parsers(parser: argparse.ArgumentParser):
    """The parser and every subcommand's parser under it."""
    todo = [parser]
    while todo:
        p = todo.pop()
        yield p
        todo.extend(c for a in p._actions if isinstance(a, argparse._SubParsersAction) for c in a.choices.values())


def value_options(parser: argparse.ArgumentParser) -> set[str]:
    """The option strings, in every subcommand, that take exactly one value."""
    return {s for p in all_parsers(parser) for a in p._actions if a.option_strings and a.nargs is None
            for s in a.option_strings}


def given_flags(argv: Sequence[str]) -> frozenset[str]:
    """The dests of the options argv gives explicitly, whatever their value (`--mode lockstep` too): the
    same parser with every default suppressed, so only what argv sets ends up in its namespace. For flags
    that a command ignores in some use and must refuse rather than drop (swarm up --inventory --mode)."""
    parser = build_parser()
    commands = set()
    for p in all_parsers(parser):
        p._defaults.clear()  # set_defaults(func=...): not an option
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                commands.add(action.dest)
            elif action.dest != "help":
                action.default = argparse.SUPPRESS
    return frozenset(vars(parser.parse_args(argv))) - commands


def given(args, *dests: str) -> list[str]:
    """Of `dests`, the flags the command line gave (as "--flag", in order); none when args did not come
    from swarm.cli.main (a caller in-process: nothing tells a given flag from its default)."""
    if not hasattr(args, "argv"):
        return []
    got = given_flags(args.argv)
    return [f"--{d.replace('_', '-')}" for d in dests if d in got]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarm",
        description="Decentralized formation control of differential-drive robots (Eclipse Zenoh, meshcat).",
        epilog="Exit codes: 0 done, 1 runtime failure, 2 bad input, 3 finished but a check failed (collisions, "
               "missed commands, lock-step overruns, robots lost; --allow-violations: 0), 130 interrupted. "
               "Docs: README.md and docs/ in the repository.",
    )
    parser.add_argument("--version", action=_Version, help="print swarm's version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    sim = sub.add_parser(
        "sim", help="run a scenario in one process, as fast as it can",
        description="Run a whole swarm in one process with the compiled simulator. The built-in 'paper' "
                    "scenario is the paper's 37-robot experiment at dt = 0.001 s; 'paper-50hz' is the same "
                    "at dt = 0.02 s with the safety governor on.",
        epilog="Examples: swarm sim --scenario paper --seed 3 --metrics m.json --plots fig2/ | "
               "swarm sim --viz --speed 2",
    )
    _add_scenario_flags(sim, "paper")
    out = sim.add_argument_group("output")
    out.add_argument("--metrics", type=Path, metavar="PATH", help="write the metrics JSON (its keys: docs/metrics.md)")
    out.add_argument("--plots", type=Path, metavar="DIR", help="write the panels of the paper's Fig. 2 as PNG")
    out.add_argument("--quiet", action="store_true", help="no progress bar and no summary table")
    _add_violation_flag(out)
    _add_record_flags(out)
    _add_viz_flags(sim, "--viz")
    sim.set_defaults(func="swarm.cli.sim:cmd_sim")

    scn = sub.add_parser("scenario", help="show or check scenario files",
                         description="Print a scenario as explicit TOML, or check files against the contract.")
    scn_sub = scn.add_subparsers(dest="action", metavar="ACTION", required=True)
    show = scn_sub.add_parser("show", help="print a scenario (built-in or file) as TOML with explicit lists",
                              description="Print the resolved scenario as a TOML file with explicit lists "
                                          "(offsets already assigned, so assignment = \"ordered\").")
    show.add_argument("source", metavar="NAME|FILE")
    show.add_argument("--robots", type=_count, metavar="N", help="resize a scenario made by generators")
    show.add_argument("--seed", type=_seed, metavar="S", help="the random seed (starts, slot assignment)")
    _add_fault_flags(show)
    show.set_defaults(func="swarm.cli.sim:cmd_scenario_show")
    scale = scn_sub.add_parser("scale", help="a scenario slowed down to fit a robot's speed limits, as TOML",
                               description="Print the scenario with the leader slowed down so that its every segment "
                                           "is within 0.8 of the robot's limits (the pre-flight's share): the same "
                                           "path, each segment's v and w times k and its duration over k, the run "
                                           "over k; control.v_max and w_max become the limits. k is said on stderr.",
                               epilog="example: swarm scenario scale paper-50hz --robots 7 --v-max 0.22 --w-max 2.84 "
                                      "> burger.toml")
    scale.add_argument("source", metavar="NAME|FILE")
    scale.add_argument("--v-max", type=_positive_float, required=True, metavar="V",
                       help="the robot's top speed [m/s] (a TurtleBot3 Burger: 0.22, Waffle: 0.26)")
    scale.add_argument("--w-max", type=_positive_float, metavar="W",
                       help="the robot's top turn rate [rad/s] (a TurtleBot3 Burger: 2.84, Waffle: 1.82)")
    scale.add_argument("--robots", type=_count, metavar="N", help="resize a scenario made by generators")
    scale.add_argument("--seed", type=_seed, metavar="S", help="the random seed (starts, slot assignment)")
    scale.set_defaults(func="swarm.cli.sim:cmd_scenario_scale")
    check = scn_sub.add_parser("check", help="check scenario files; exit 2 at the first bad one")
    check.add_argument("files", nargs="+", metavar="FILE")
    check.set_defaults(func="swarm.cli.sim:cmd_scenario_check")

    sec = sub.add_parser("secure", help="credentials for --secure: a CA, a certificate per process, the router's rules",
                         description="Make the credentials that --secure uses (docs/security.md).")
    sec_sub = sec.add_subparsers(dest="action", metavar="ACTION", required=True)
    sec_init = sec_sub.add_parser(
        "init", help="write a fleet directory: CA, certificates, zenoh configs, the router's access control",
        description="Write DIR: a certificate authority, a certificate for the router and for every role (launcher, "
                    "world, leader, viz, recorder, operator) and robot, and a zenoh config per identity with mutual "
                    "TLS; the router's carries the access control generated from the role table. Each robot's "
                    "files are in a folder of their own (DIR/robot-I), to copy to that robot's machine alone.",
        epilog="Examples: swarm secure init fleet/ --robots 7 | swarm secure init fleet/ --robots 12 --router-host "
               "192.168.1.10 | swarm secure init fleet/ --robots 8 --update --revoke 3")
    sec_init.add_argument("directory", type=Path, metavar="DIR")
    sec_init.add_argument("--robots", type=_count, required=True, metavar="N", help="robots 0..N-1 get a certificate")
    sec_init.add_argument("--fleet", metavar="NAME", help="the swarm's name, as given to --fleet (default: default)")
    sec_init.add_argument("--router-host", action="append", default=[], metavar="H",
                          help="a name or address other machines reach the router by (in its certificate; the router "
                               "then listens on every interface; robots, viewers and operators connect to the first); "
                               "repeatable")
    sec_init.add_argument("--port", type=_int_at_least(1), metavar="P", help="the router's TLS port (default 7447)")
    sec_init.add_argument("--extra-robot-keys", action="append", default=[], metavar="EXPR",
                          help="a key expression outside swarm/ that robot I may use (a ROS 2 drive's topics); "
                               "{id} stands for I, e.g. 'robot{id}/**'; repeatable")
    how = sec_init.add_mutually_exclusive_group()
    how.add_argument("--force", action="store_true", help="DIR is not empty: replace its credentials (a new CA)")
    how.add_argument("--update", action="store_true",
                     help="keep DIR's CA and certificates: add robots up to N, apply --revoke, rewrite the configs")
    sec_init.add_argument("--revoke", action="append", type=_int_at_least(0), default=[], metavar="I",
                          help="with --update: robot I loses its folder and the router denies it; repeatable")
    sec_init.set_defaults(func="swarm.cli.secure:cmd_secure_init")
    _add_runtime_parsers(sub)
    _add_campaign_parser(sub)
    return parser


def _initial_pose(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected x,y,theta (three finite numbers: m, m, rad), got {text!r}")
    return values


def _robot_pose(text: str) -> tuple[int, tuple[float, float, float]]:
    """I:X,Y,THETA: robot I's start [m, m, rad]."""
    head, sep, tail = text.partition(":")
    try:
        i = int(head)
    except ValueError:
        i = -1
    if not sep or i < 0:
        raise argparse.ArgumentTypeError(f"expected I:X,Y,THETA (a robot id, then three numbers), got {text!r}")
    return i, _initial_pose(tail)


def robot_id(text: str) -> int | None:
    """--id: a robot id (an integer >= 0), or "auto" (None): claim the lowest free one from the world."""
    if text == "auto":
        return None
    return _int_at_least(0)(text)


def _add_fleet_flags(g, robot: bool = False) -> None:
    """A real fleet's flags (docs/deploy.md): the inventory, the pre-flight, the robots' starts."""
    g.add_argument("--inventory", metavar="FILE",
                   help="the fleet's inventory (TOML): which robot is which, its drive, ROS 2 topics, endpoint, start "
                        "and limits" + ("; --id I takes row I" if robot else ""))
    if not robot:
        g.add_argument("--no-preflight", action="store_true",
                       help="with --inventory: skip the pre-flight (odometry fresh, starts apart, inside the arena and "
                            "outside obstacles, the leader within 0.8 of every robot's limits)")
        g.add_argument("--initial-pose", type=_robot_pose, action="append", metavar="I:X,Y,THETA",
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


def _add_ros2_flags(g, world: bool | str = False) -> None:
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


def _add_net_flags(p: argparse.ArgumentParser, listen: bool = False, connect_help: str | None = None) -> None:
    p.add_argument("--log-level", choices=("debug", "info", "warning", "error"), metavar="LEVEL",
                   help="what the process logs on stderr: debug, info (default), warning or error; swarm up passes "
                        "it to every process it starts (their logs are in its log folder)")
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


def _add_run_flags(p: argparse.ArgumentParser, up: bool = False) -> None:
    g = p.add_argument_group("run")
    if p.prog.endswith(" robot"):  # a robot takes the mode of the world's run
        g.add_argument("--mode", choices=("lockstep", "realtime"), default=None,
                       help="the run's mode is the world's (swarm world --mode); given, this robot refuses a run of "
                            "the other mode (exit 2)")
    else:
        g.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep",
                       help="lockstep: the world owns the clock, deterministic, equal to swarm sim (default); "
                            "realtime: every process on its own clock")
    g.add_argument("--rate", type=_positive_float, metavar="HZ",
                   help="control rate (sets dt = 1/HZ; the built-in paper-50hz runs at 50 Hz)")
    if up or p.prog.endswith("world"):
        g.add_argument("--speed", type=_positive_float, default=1.0, metavar="X",
                       help="real time only: simulated seconds per wall second (default 1; lock-step "
                            "runs as fast as the robots answer)")
        g.add_argument("--watchdog", type=_positive_float, default=0.5, metavar="S",
                       help="stop a robot whose newest command is older than S seconds (default 0.5)")
        g.add_argument("--tick-timeout", type=_positive_float, default=1.0, metavar="S",
                       help="lock-step: wall seconds to wait for a tick's commands before counting misses "
                            "(default 1)")
        g.add_argument("--lost-timeout", type=_positive_float, default=10.0, metavar="S",
                       help="how long the leader, or every robot at once, may be away before the run ends with a "
                            "failure (lock-step holds its tick meanwhile; default 10)")
        g.add_argument("--metrics", type=Path, metavar="PATH", help="write the metrics JSON (its keys: docs/metrics.md); swarm up always writes it to the log directory too")
        g.add_argument("--trace", type=Path, metavar="PATH.npz",
                       help="write every robot's pose at every sample (numpy .npz: q[k, i] = x, y, theta; t[k] its simulated "
                            "time, which in real time may skip periods the world fell behind on)")
        _add_violation_flag(g)
        if up:
            _add_record_flags(g)
    g.add_argument("--start-timeout", type=_positive_float, default=60.0, metavar="S",
                   help="seconds the start may go without one more process alive (default 60); robots start "
                        "in waves of 8 a core" if up else "seconds to wait for the other processes at start "
                        "(default 60)")


def _add_violation_flag(g) -> None:
    g.add_argument("--allow-violations", action="store_true",
                   help="exit 0 even when a check failed (collisions, missed commands, lock-step overruns, robots "
                        "lost); without it such a run exits 3")


def _add_runtime_parsers(sub) -> None:
    up = sub.add_parser(
        "up", help="run the swarm: one process per robot over zenoh, plus router, world and leader",
        description="Start an embedded zenoh router (or join one with --connect), the world, the leader "
                    "and one process per robot, each in its own process group; wait until all are alive; "
                    "run with a live status line and the browser viewer (it prints the URL); write the "
                    "metrics; stop everything on the way out (also on Ctrl-C and SIGTERM). Without "
                    "--scenario it runs the built-in paper-50hz scenario (dt = 0.02 s, governor on).",
        epilog="Examples: swarm up --robots 37 | swarm up --robots 7 --mode realtime --speed 2 | "
               "swarm up --listen tcp/0.0.0.0:7447 (robots on other machines: docs/runtime.md, \"Running across machines\")")
    _add_scenario_flags(up, "paper-50hz")
    _add_run_flags(up, up=True)
    _add_net_flags(up, listen=True, connect_help="join the router at ENDPOINT instead of starting one")
    g = up.add_argument_group("drive")
    g.add_argument("--drive", choices=("sim", "ros2"), default="sim",
                   help="ros2: the world simulates a ROS 2 fleet (cmd_vel and odometry in CDR on ROS 2 keys) and every "
                        "agent drives its robot through them, as on real robots; needs --mode realtime")
    _add_ros2_flags(g, world="up")
    g = up.add_argument_group("launcher")
    g.add_argument("--dry-run", action="store_true", help="print the launch plan and exit")
    g.add_argument("--restarts", type=_int_at_least(0), default=3, metavar="N",
                   help="restart a failed robot process at most N times per window (default 3)")
    g.add_argument("--restart-window", type=_positive_float, default=60.0, metavar="S",
                   help="the restart policy's window in seconds (default 60)")
    g.add_argument("--log-dir", metavar="DIR", help="where the processes' logs go, never pruned (default: a new folder in the temp dir; "
                        "swarm up keeps your 10 newest of each fleet there)")
    g.add_argument("--quiet", action="store_true", help="no status line and no summary")
    _add_fleet_flags(up.add_argument_group("real robots (no simulated world: the referee watches their odometry)"))
    _add_viz_flags(up, "--no-viz")
    up.set_defaults(func="swarm.cli.up:cmd_up")

    router = sub.add_parser("router", help="a zenoh router (what swarm up embeds)",
                            description="Run a zenoh router in this process. Routers on several machines "
                                        "connect to each other with --connect.")
    _add_net_flags(router, listen=True, connect_help="another router to connect to (across machines)")
    router.set_defaults(func="swarm.cli.router:cmd_router")

    world = sub.add_parser("world", help="the simulated world: kinematics, obstacles, clock, metrics",
                           description="Simulate every robot (exact arcs), serve the obstacles and each robot's "
                                       "configuration, own the clock in lock-step, referee the run.")
    _add_scenario_flags(world, "paper-50hz")
    _add_run_flags(world)
    _add_net_flags(world)
    g = world.add_argument_group("simulated ROS 2 fleet (real time)")
    g.add_argument("--ros2-sim", choices=("rmw_zenoh", "bridge"), metavar="FLAVOR",
                   help="the simulated robots speak ROS 2: each takes cmd_vel and gives odometry (its own frame, zero "
                        "at its start) on the ROS 2 keys of FLAVOR (rmw_zenoh or bridge), in CDR; needs --mode realtime")
    _add_ros2_flags(g, world=True)
    world.add_argument("--process-faults", choices=("played", "signals"), default="played",
                       help="lock-step with kill or hang faults: 'played' (default), each robot's process idles "
                            "through its dead or hung ticks; 'signals', a supervisor really kills (SIGKILL) and "
                            "stops (SIGSTOP) them, and the world waits for a restarted or resumed robot before "
                            "its return tick (what swarm up does)")
    g = world.add_argument_group("real robots")
    g.add_argument("--referee-only", action="store_true",
                   help="no physics: serve the run to real robots (with --inventory) and referee it from their "
                        "odometry (the robots' states): metrics, snapshots, progress as in simulation; real time")
    _add_fleet_flags(g)
    world.set_defaults(func="swarm.cli.world:cmd_world")

    leader = sub.add_parser("leader", help="publish the leader's reference",
                            description="Publish the virtual leader's reference from the scenario's segments.")
    _add_scenario_flags(leader, "paper-50hz")
    _add_run_flags(leader)
    _add_net_flags(leader)
    leader.set_defaults(func="swarm.cli.leader:cmd_leader")

    robot = sub.add_parser("robot", help="one robot's agent (its decentralized controller)",
                           description="Run robot ID's controller. It takes its slice of the scenario from "
                                       "--scenario FILE (the same file on every machine) or, without it, from "
                                       "the world's configuration queryable.")
    robot.add_argument("--id", type=robot_id, default=argparse.SUPPRESS, metavar="I|auto",
                       help="the robot's id (0-based), or auto: the lowest free one, claimed from the world; "
                            "required, but with --secure FOLDER it defaults to the id of the folder's certificate")
    _add_optional_scenario_flags(robot, "the world's configuration is used")
    _add_run_flags(robot)
    _add_net_flags(robot)
    g = robot.add_argument_group("drive (where the agent meets its robot; real time)")
    g.add_argument("--drive", choices=("sim", "ros2"), default="sim",
                   help="sim: the simulated world's pose and cmd keys (default); ros2: a ROS 2 robot (odometry in, "
                        "cmd_vel out), needs --mode realtime")
    _add_ros2_flags(g, world="robot")
    g.add_argument("--namespace", metavar="NS", help="with --drive ros2: the robot's ROS namespace (default robot<ID>)")
    g.add_argument("--initial-pose", type=_initial_pose, metavar="X,Y,THETA",
                   help="with --drive ros2: the robot's start in the swarm's frame (default: the scenario's start); "
                        "the odometry frame is anchored there on its first message")
    g.add_argument("--ref-timeout", type=_positive_float, default=2.5, metavar="S",
                   help="stop the robot when the reference has been extrapolated for longer than S (default 2.5)")
    g = robot.add_argument_group("a real fleet, or ids handed out by the world")
    _add_fleet_flags(g, robot=True)
    g.add_argument("--claim-key", metavar="KEY",
                   help="with --id auto: who claims (letters, digits, '_', '.', '-'; @hostname: this machine's host "
                        "name): the same key gets the same id back, so a restarted container comes back as itself "
                        "(default: a new key, a new id)")
    robot.set_defaults(func="swarm.cli.robot:cmd_robot")

    pre = sub.add_parser(
        "preflight", help="check a real fleet before it moves: odometry, starts, arena, limits (exit 1 on a failure)",
        description="Check a real fleet against a scenario without moving anything: every robot's ROS 2 side answers "
                    "and its odometry is fresh; starts at least r apart, outside every obstacle and inside "
                    "arena.bounds; every leader segment within 0.8 of every robot's limits (|v| <= 0.8 v_max, |w| "
                    "<= 0.8 w_max) and v_max >= control.vt. Each failure names the robot and the reason. swarm up "
                    "--inventory and swarm world --referee-only run it at the start of every run.",
        epilog="Example: swarm preflight --inventory fleet.toml --scenario turtlebot3 --connect tcp/192.168.1.10:7447")
    pre.add_argument("--inventory", required=True, metavar="FILE", help="the fleet's inventory (TOML)")
    pre.add_argument("--initial-pose", type=_robot_pose, action="append", metavar="I:X,Y,THETA",
                     help="robot I stands at X,Y,THETA (beats the inventory and the scenario); repeatable")
    pre.add_argument("--odom-timeout", type=_positive_float, default=10.0, metavar="S",
                     help="seconds to wait for every robot's ROS 2 side and first odometry (default 10)")
    pre.add_argument("--start-timeout", type=_positive_float, default=10.0, metavar="S",
                     help="seconds to wait for the router given with --connect (default 10)")
    pre.add_argument("--odom-window", type=_positive_float, default=1.5, metavar="S",
                     help="seconds of odometry watched for gaps (default 1.5)")
    _add_scenario_flags(pre, "paper-50hz")
    _add_net_flags(pre)
    pre.set_defaults(func="swarm.cli.preflight:cmd_preflight")

    stop = sub.add_parser("stop", help="emergency stop: every robot of the fleet holds zero velocity (latched)",
                          description="Put the emergency stop on the fleet's estop key: every drive halts its robot "
                                      "within one control period and holds it until `swarm stop --release`. Robots "
                                      "started after the stop do not know of it: stop them again.",
                          epilog="Example: swarm stop --fleet lab --connect tcp/192.168.1.10:7447 --reason 'person in "
                                 "the arena'")
    stop.add_argument("--release", action="store_true", help="release the emergency stop (robots move again)")
    stop.add_argument("--reason", default="", metavar="TEXT", help="why (logged by every robot)")
    stop.add_argument("--repeat-s", type=_positive_float, default=1.0, metavar="S",
                      help="keep saying it for S seconds (default 1), for robots whose link hiccups")
    _add_net_flags(stop)
    stop.set_defaults(func="swarm.cli.stop:cmd_stop")

    ps = sub.add_parser("ps", help="the swarms on a router and their live processes (role, id, host, pid, age, run)",
                        description="List every swarm process on --connect's router: one line per liveliness "
                                    "token (router, swarm up, world, leader, robots, viewers) or robot process "
                                    "waiting for a run, with what the process says of itself (host, pid, age, the "
                                    "run it is in). Every fleet on the router, or only --fleet's. Under --secure it "
                                    "uses the fleet's operator identity.",
                        epilog="Example: swarm ps --connect tcp/192.168.1.10:7447")
    ps.add_argument("--wait", type=_positive_float, default=2.0, metavar="S",
                    help="wait at most S seconds for the processes to answer (default 2)")
    ps.add_argument("--json", action="store_true", help="print the listing as JSON (one object per process)")
    _add_net_flags(ps)
    ps.set_defaults(func="swarm.cli.ps:cmd_ps", fleet=None)

    echo = sub.add_parser("echo", help="print the swarm's messages on a key, decoded (like ros2 topic echo)",
                          description="Subscribe to KEY (under swarm/FLEET/, or a full key expression starting with "
                                      "swarm/) and print each message decoded, one line each: the key, the kind, "
                                      "the fields as JSON. A message that does not decode is printed with the "
                                      "reason. Keys that are served, not put (obstacles, config, claim, proc), are "
                                      "asked once. Exit 1 when nothing came.",
                          epilog="Examples: swarm echo 'cell/**' --count 5; swarm echo robot/3/pose; "
                                 "swarm echo leader/ref --timeout 2; swarm echo 'proc/*/*'")
    echo.add_argument("key", metavar="KEY", help="e.g. robot/3/pose, robot/*/status, cell/**, leader/ref, "
                                                   "world/progress, estop")
    echo.add_argument("--count", type=int, metavar="N", help="exit after N messages")
    echo.add_argument("--timeout", type=_positive_float, metavar="S", help="exit after S seconds (exit 1 if nothing "
                                                                            "came)")
    _add_net_flags(echo)
    echo.set_defaults(func="swarm.cli.echo:cmd_echo")

    viz = sub.add_parser("viz", help="watch a running swarm in a browser (meshcat)",
                         description="Start a meshcat web server, print its URL, and draw the swarm of --fleet "
                                     "on --connect's router: robots coloured by state, obstacles, the leader and "
                                     "the formation's slots, trails. It only listens: it never slows the swarm. "
                                     "Without --scenario it asks the world for the obstacles and the slots.",
                         epilog="Example: swarm viz --connect tcp/192.168.1.10:7447 --viz-host 0.0.0.0 --viz-port 7000")
    _add_optional_scenario_flags(viz, "the world's queryables are used")
    _add_viz_flags(viz, None)
    viz.add_argument("--server-log", type=Path, metavar="PATH",
                     help="append the meshcat server's own log (connections) to PATH (default: discarded)")
    viz.add_argument("--start-timeout", type=_positive_float, default=60.0, metavar="S",
                     help="seconds to wait for the router at start (default 60)")
    _add_net_flags(viz)
    viz.set_defaults(func="swarm.cli.viz:cmd_viz")

    replay = sub.add_parser("replay", help="play a recording (swarm sim/up --record) in the browser viewer",
                            description="Play the snapshots of an MCAP recording in the viewer at --speed times "
                                        "real time (the recorded poses exactly, at most 30 frames a second), "
                                        "then keep the viewer up until Ctrl-C.",
                            epilog="Example: swarm replay run.mcap --speed 4")
    replay.add_argument("recording", type=Path, metavar="FILE.mcap")
    replay.add_argument("--speed", type=_positive_float, default=1.0, metavar="X",
                        help="simulated seconds per wall second (default 1)")
    w = replay.add_mutually_exclusive_group()
    w.add_argument("--wait", action="store_true",
                   help="start when a browser opens the viewer's URL (the default when the output is a terminal)")
    w.add_argument("--no-wait", action="store_true", help="start at once (the default in scripts)")
    replay.add_argument("--exit", action="store_true", help="exit when the replay ends instead of waiting for Ctrl-C")
    _add_viz_flags(replay, None)
    replay.set_defaults(func="swarm.cli.playback:cmd_replay")

    report = sub.add_parser("report", help="write the Fig. 2 panels and an HTML summary of a recording",
                            description="Read an MCAP recording and write into DIR the panels of the paper's "
                                        "Fig. 2 (the code of swarm sim --plots, on the recorded samples), "
                                        "scenario.toml, metrics.json and index.html, a one-page summary.",
                            epilog="Example: swarm report run.mcap -o report/ && xdg-open report/index.html")
    report.add_argument("recording", type=Path, metavar="FILE.mcap")
    report.add_argument("-o", "--out", type=Path, required=True, metavar="DIR", help="the directory to write")
    report.set_defaults(func="swarm.cli.playback:cmd_report")


# --------------------------------------------------------------------------- swarm campaign

MAX_CAMPAIGN_RUNS = 100_000  # seeds x drop probabilities


def _seed_list(text: str) -> tuple[int, ...]:
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


def _drop_list(text: str) -> tuple[float, ...]:
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


def _add_campaign_parser(sub) -> None:
    c = sub.add_parser(
        "campaign", help="swarm sim over a grid of seeds and drop probabilities, on every core: CSV, plots, a page; "
                         "--up N: its first N runs again as lock-step swarm up, each held equal to its simulation",
        description="Run swarm sim for every seed of --seeds and every probability of --drop, in -j worker "
                    "processes, with a progress bar and an ETA. A seed sets run.seed and the faults' seed with it "
                    "(unless the faults set one); each p adds one drop rule of class all to the faults of the "
                    "scenario or of --faults FILE (0: none). Writes DIR/runs.csv (one row a run), DIR/summary.csv "
                    "(one row per p), DIR/campaign.json (its flags), convergence.png, distance.png, error.png and "
                    "DIR/index.html. The same command writes the same rows (the wallclock.* columns aside). Exit 3 "
                    "when a run collided (it names the runs); a run that did not converge is reported, not a failure. "
                    "With --up N, the first N rows of runs.csv then run again, one at a time, as lock-step swarm up "
                    "(--trace, the same scenario, seed, drop and faults), each compared with swarm sim tick for "
                    "tick, bit for bit, and on its metrics: one line a row, DIR/up.csv, exit 3 when one differs or "
                    "its swarm up failed. --up N --from DIR does that for a campaign already run "
                    "(docs/faults.md, Campaigns).",
        epilog="Examples: swarm campaign --scenario paper-50hz --seeds 0-9 --drop 0,0.1,0.3 -o out/ | "
               "swarm campaign --scenario paper-50hz --seeds 0-9 --faults kills.toml -j 2 -o kills/ | "
               "swarm campaign --seeds 0-1 --drop 0.3,0 --kill 7@15 -o out/ --up 2 | "
               "swarm campaign --up 4 --from out/")
    g = c.add_argument_group("the grid")
    g.add_argument("--scenario", metavar="NAME|FILE",
                   help="built-in name (paper, paper-50hz, turtlebot3) or a TOML file (default: paper-50hz)")
    g.add_argument("--seeds", type=_seed_list, metavar="A-B",
                   help="the seeds: A-B (both included), A, or a comma list of those (e.g. 0-9); required "
                        "unless --from")
    g.add_argument("--drop", type=_drop_list, metavar="P1,P2,...", action=_Once,
                   help="drop probabilities: each adds one drop rule of class all (every message) to the faults; "
                        "0: no rule (default: 0 only)")
    g = c.add_argument_group("every run (a flag beats the scenario file, which beats the built-in default)")
    g.add_argument("--robots", type=_count, metavar="N", help="number of robots (resizes built-in and generated scenarios)")
    g.add_argument("--duration", type=_positive_float, metavar="T", help="simulated seconds to run")
    g.add_argument("--dt", type=_positive_float, metavar="DT", help="control period [s]")
    g.add_argument("--governor", action=argparse.BooleanOptionalAction, default=None,
                   help="the discrete-time safety governor (default: the scenario's control.governor)")
    g.add_argument("--faults", metavar="FILE", action=_Once,
                   help="a TOML file holding a [faults] table: it replaces the scenario's in every run; the --drop "
                        "rule is added to it")
    g.add_argument("--kill", metavar="ID@T,...", action=_Joined,
                   help="kill robot ID's process at T s in every run (e.g. 2@15,5@15; repeatable)")
    g = c.add_argument_group("output")
    g.add_argument("-o", "--out", type=Path, metavar="DIR",
                   help="the directory to write (made if missing; its files of a campaign are replaced); required "
                        "unless --from")
    g.add_argument("-j", "--jobs", type=_count, metavar="JOBS", help="worker processes (default: every core)")
    g.add_argument("--quiet", action="store_true", help="no progress bar and no summary table")
    _add_violation_flag(g)
    g = c.add_argument_group("the distributed runtime against the simulator (lock-step swarm up)")
    g.add_argument("--up", type=_count, metavar="N",
                   help="then run the first N rows of runs.csv again as lock-step swarm up, one at a time (each "
                        "bounded by a timeout from its size; logs in DIR/up/row-K/), and compare each with swarm "
                        "sim: every robot's pose at every tick, bit for bit, and the metrics; writes DIR/up.csv; "
                        "exit 3 when one differs or fails")
    g.add_argument("--from", dest="from_dir", type=Path, metavar="DIR",
                   help="with --up N: check a campaign already run in DIR (its campaign.json and runs.csv) instead "
                        "of running a grid; no grid flag, -o or -j with it")
    c.set_defaults(func="swarm.cli.campaign:cmd_campaign")
