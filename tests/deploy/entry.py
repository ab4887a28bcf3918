"""`swarm` for the real-fleet tests, with the hand-overs of docs/deploy.md wired in.

    python -m tests.deploy.entry up --inventory F ...         -> swarm.cli.up_inventory.cmd_up_inventory
    python -m tests.deploy.entry world --referee-only ...     -> swarm.cli.up_inventory.cmd_world_referee
    python -m tests.deploy.entry robot --id auto | --inventory F --id I | --claim-key K ...  -> cmd_robot_fleet
    python -m tests.deploy.entry world ...                    -> swarm world, with claims served beside it
    python -m tests.deploy.entry ANYTHING ELSE                -> swarm

Until `swarm up`, `swarm world` and `swarm robot` hand these cases over themselves (a few lines each;
`swarm robot` then parses `--id auto`, and the world serves claims), this entry point does it, through
swarm.cli.main (the same parser, errors and exit codes), so the tests run every command line exactly as
a user types it.
"""

from __future__ import annotations

import inspect
import sys

from swarm.cli import main as cli_main
from swarm.cli.parser import build_parser, robot_id

MODULE = "tests.deploy.entry"


def _parser():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices
    sub["up"].set_defaults(func=f"{MODULE}:up")
    sub["world"].set_defaults(func=f"{MODULE}:world")
    sub["robot"].set_defaults(func=f"{MODULE}:robot")
    sub["robot"]._option_string_actions["--id"].type = robot_id  # --id auto
    return parser


def up(args, started: float) -> int:
    if args.inventory is not None:
        from swarm.cli.up_inventory import cmd_up_inventory

        return cmd_up_inventory(args, started, module=MODULE)
    from swarm.cli.up import cmd_up

    return cmd_up(args, started)


def world(args, started: float) -> int:
    if args.referee_only or args.inventory is not None:
        from swarm.cli.up_inventory import cmd_world_referee

        return cmd_world_referee(args, started)
    from swarm.cli import world as world_cli

    if "ClaimServer" in inspect.getsource(world_cli):  # the world serves claims itself
        return world_cli.cmd_world(args, started)
    from swarm.cli.common import fleet_of, load_scenario, open_bus
    from world.claims import ClaimServer

    bus = open_bus(args, role="world")  # a second session of the world's, for the claims
    claims = ClaimServer(bus, fleet_of(args), load_scenario(args, quiet=True).n)
    claims.start()
    try:
        return world_cli.cmd_world(args, started)
    finally:
        claims.close()
        bus.close()


def robot(args, started: float) -> int:
    if args.inventory is not None or args.id is None or args.claim_key is not None:
        from swarm.cli.up_inventory import cmd_robot_fleet

        return cmd_robot_fleet(args, started)
    from swarm.cli.robot import cmd_robot

    return cmd_robot(args, started)


def main(argv=None) -> int:
    cli_main.build_parser = _parser
    return cli_main.main(argv)


if __name__ == "__main__":
    sys.exit(main())
