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
from pathlib import Path
from typing import Sequence

from swarm.cli.flags import (
    VersionAction,
    add_fault_flags,
    add_record_flags,
    add_scenario_flags,
    add_violation_flag,
    add_viz_flags,
    count_arg,
    int_at_least,
    positive_float,
    seed_arg,
    version,
)
from swarm.cli.flags import DISTRIBUTION as DISTRIBUTION
from swarm.cli.flags import PYPROJECT as PYPROJECT
from swarm.cli.flags import robot_id as robot_id
from swarm.cli.parser_campaign import add_campaign_parser
from swarm.cli.parser_runtime import add_runtime_parsers


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


GIVEN = "_given_once"  # the namespace's set of _StoreOnce flags met so far (left out of the parsed arguments)


class Parser(argparse.ArgumentParser):
    """argparse's parser with a short error: the reason and where the flags are listed, not the whole usage (19
    lines for swarm up) above it. Every subcommand's parser is one too (add_parser makes its parent's class)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n({self.prog} --help lists its flags)\n")

    def parse_known_args(self, args=None, namespace=None):
        parsed, rest = super().parse_known_args(args, namespace)
        vars(parsed).pop(GIVEN, None)  # _StoreOnce's bookkeeping
        return parsed, rest

    def parse_args(self, args=None, namespace=None):
        """argparse's, but a word left over is the subcommand's error (`swarm sim: error: unrecognized
        arguments: extra`), not the top parser's, which names no subcommand."""
        parsed, rest = self.parse_known_args(args, namespace)
        if rest:
            target: argparse.ArgumentParser = self
            for name in (getattr(parsed, "command", None), getattr(parsed, "action", None)):
                subs = [a for a in target._actions if isinstance(a, argparse._SubParsersAction)]
                if not subs or name not in subs[0].choices:
                    break
                target = subs[0].choices[name]
            target.error(f"unrecognized arguments: {' '.join(rest)}")
        return parsed


class _StoreOnce(argparse._StoreAction):
    """A flag with a value that may be given once: `--seed 1 --seed 2` is refused, not the first dropped."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = namespace.__dict__.setdefault(GIVEN, set())
        if self.dest in given:
            parser.error(f"{option_string} given twice (the second would replace the first): give it once")
        given.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="swarm",
        description="Decentralized formation control of differential-drive robots (Eclipse Zenoh, meshcat).",
        epilog="Exit codes: 0 done, 1 runtime failure, 2 bad input, 3 finished but a check failed (collisions, "
               "missed commands, lock-step overruns, robots lost; --allow-violations: 0), 4 swarm robot refused "
               "its run (its law failed), 130 interrupted. "
               "Docs: README.md and docs/ in the repository.",
    )
    parser.add_argument("--version", action=VersionAction, help="print swarm's version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    sim = sub.add_parser(
        "sim", help="run a scenario in one process, as fast as it can",
        description="Run a whole swarm in one process with the compiled simulator. The built-in 'paper' "
                    "scenario is the paper's 37-robot experiment at dt = 0.001 s; 'paper-50hz' is the same "
                    "at dt = 0.02 s with the safety governor on.",
        epilog="Examples: swarm sim --scenario paper --seed 3 --metrics m.json --plots fig2/ | "
               "swarm sim --viz --speed 2",
    )
    add_scenario_flags(sim, "paper")
    out = sim.add_argument_group("output")
    out.add_argument("--metrics", type=Path, metavar="PATH", help="write the metrics JSON (its keys: docs/metrics.md)")
    out.add_argument("--plots", type=Path, metavar="DIR", help="write the panels of the paper's Fig. 2 as PNG")
    out.add_argument("--trace", type=Path, metavar="PATH.npz",
                     help="write every robot's pose at every step (numpy .npz: q[k, i] = x, y, theta, t[k], dt), as "
                          "swarm up --trace does: a lock-step run of the same scenario equals it element for element")
    out.add_argument("--quiet", action="store_true", help="no progress bar and no summary table")
    add_violation_flag(out)
    add_record_flags(out)
    sim.add_argument("--python-law", action="store_true",
                     help="run a law of your own (control.law) as plain Python instead of compiling it with numba: "
                          "for a law numba cannot compile; far slower, and says how much")
    sim.add_argument("--threads", type=count_arg, metavar="T",
                     help="threads of the paper's kernel without faults (default: every core from 256 robots, else "
                          "1); every count gives the same bits")
    add_viz_flags(sim, "--viz")
    sim.set_defaults(func="swarm.cli.sim:cmd_sim")

    scn = sub.add_parser("scenario", help="show or check scenario files",
                         description="Print a scenario as explicit TOML, or check files against the contract.")
    scn_sub = scn.add_subparsers(dest="action", metavar="ACTION", required=True)
    show = scn_sub.add_parser("show", help="print a scenario (built-in or file) as TOML with explicit lists",
                              description="Print the resolved scenario as a TOML file with explicit lists "
                                          "(offsets already assigned, so assignment = \"ordered\").")
    show.add_argument("source", metavar="NAME|FILE")
    show.add_argument("--robots", type=count_arg, metavar="N", help="resize a scenario made by generators")
    show.add_argument("--seed", type=seed_arg, metavar="S", help="the random seed (starts, slot assignment)")
    add_fault_flags(show)
    show.set_defaults(func="swarm.cli.sim:cmd_scenario_show")
    scale = scn_sub.add_parser("scale", help="a scenario slowed down to fit a robot's speed limits, as TOML",
                               description="Print the scenario with the leader slowed down so that its every segment "
                                           "is within 0.8 of the robot's limits (the pre-flight's share): the same "
                                           "path, each segment's v and w times k and its duration over k, the run "
                                           "over k; control.v_max and w_max become the limits. k is said on stderr.",
                               epilog="example: swarm scenario scale paper-50hz --robots 7 --v-max 0.22 --w-max 2.84 "
                                      "> burger.toml")
    scale.add_argument("source", metavar="NAME|FILE")
    scale.add_argument("--v-max", type=positive_float, required=True, metavar="V",
                       help="the robot's top speed [m/s] (a TurtleBot3 Burger: 0.22, Waffle: 0.26)")
    scale.add_argument("--w-max", type=positive_float, metavar="W",
                       help="the robot's top turn rate [rad/s] (a TurtleBot3 Burger: 2.84, Waffle: 1.82)")
    scale.add_argument("--robots", type=count_arg, metavar="N", help="resize a scenario made by generators")
    scale.add_argument("--seed", type=seed_arg, metavar="S", help="the random seed (starts, slot assignment)")
    scale.set_defaults(func="swarm.cli.sim:cmd_scenario_scale")
    check = scn_sub.add_parser("check", help="check scenario files; exit 2 at the first bad one",
                               description="Check scenario files against the contract (docs/scenarios.md). A file "
                                           "with a law of its own (control.law) has it loaded and called on random "
                                           "inputs, compiled by numba and as plain Python: an exception, a result "
                                           "that is not two finite numbers or a compiled result that differs from "
                                           "the Python one is refused, named (docs/control.md).")
    check.add_argument("files", nargs="+", metavar="FILE")
    check.add_argument("--python-law", action="store_true",
                       help="test-call a law of your own as plain Python only (for a law numba cannot compile, "
                            "run with swarm sim --python-law)")
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
    sec_init.add_argument("--robots", type=count_arg, required=True, metavar="N", help="robots 0..N-1 get a certificate")
    sec_init.add_argument("--fleet", metavar="NAME", help="the swarm's name, as given to --fleet (default: default)")
    sec_init.add_argument("--router-host", action="append", default=[], metavar="H",
                          help="a name or address other machines reach the router by (in its certificate; the router "
                               "then listens on every interface; robots, viewers and operators connect to the first); "
                               "repeatable")
    sec_init.add_argument("--port", type=int_at_least(1), metavar="P", help="the router's TLS port (default 7447)")
    sec_init.add_argument("--extra-robot-keys", action="append", default=[], metavar="EXPR",
                          help="a key expression outside swarm/ that robot I may use (a ROS 2 drive's topics); "
                               "{id} stands for I, e.g. 'robot{id}/**'; repeatable")
    how = sec_init.add_mutually_exclusive_group()
    how.add_argument("--force", action="store_true", help="DIR is not empty: replace its credentials (a new CA)")
    how.add_argument("--update", action="store_true",
                     help="keep DIR's CA and certificates: add robots up to N, apply --revoke, rewrite the configs")
    sec_init.add_argument("--revoke", action="append", type=int_at_least(0), default=[], metavar="I",
                          help="with --update: robot I loses its folder and the router denies it; repeatable")
    sec_init.set_defaults(func="swarm.cli.secure:cmd_secure_init")
    add_runtime_parsers(sub)
    add_campaign_parser(sub)
    for p in all_parsers(parser):  # every plain flag with a value: given once
        for action in p._actions:
            if type(action) is argparse._StoreAction and action.option_strings:
                action.__class__ = _StoreOnce
    return parser
