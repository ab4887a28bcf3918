"""`swarm robot --id I`: one robot's agent (agents.robot) on a zenoh session, serving run after run."""

from __future__ import annotations

import logging

from swarm.cli.parser import given
from swarm.cli.common import (CHILD_EXIT_AFTER_S, EXIT_INTERRUPTED, BadInput, Failure, StopEvent, fleet_of,
                              load_scenario, open_bus, setup_logging, Refused)
from swarm.core.clock import WALL
from swarm.process import die_with_parent

log = logging.getLogger("swarm")


def cmd_robot(args, started: float) -> int:
    if not hasattr(args, "id"):  # no --id: a robot's identity folder names it (docs/security.md)
        args.id = _id_of_secure_folder(args)
    if args.inventory is not None or args.id is None or args.claim_key is not None:
        from swarm.cli.up_inventory import cmd_robot_fleet

        return cmd_robot_fleet(args, started)
    from agents import robot
    from agents.control import LawFailure
    from agents.follow import NoAnswer, RunRefused

    die_with_parent()
    setup_logging()
    fleet = fleet_of(args)
    scn = load_scenario(args, quiet=True) if args.scenario is not None else None
    if scn is not None and args.id >= scn.n:
        raise BadInput(f"--id {args.id}: the scenario has {scn.n} robots (ids 0..{scn.n - 1})")
    if args.drive == "sim":
        for flag, value in (("--namespace", args.namespace), ("--initial-pose", args.initial_pose)):
            if value is not None:
                raise BadInput(f"{flag} needs --drive ros2")
        for flag in given(args, "ros_flavor", "twist", "domain", "rmw_zenoh_attachment", "robot_model", "distro"):
            raise BadInput(f"{flag} needs --drive ros2")
    elif args.mode == "lockstep":
        raise BadInput("--drive ros2 with --mode lockstep: a ROS 2 robot runs in real time only (odometry carries no "
                       "tick); give --mode realtime, or leave --mode out")
    elif args.distro is not None and (args.ros_flavor != "bridge" or args.twist != "auto"):
        from swarm.cli.up_inventory import DISTRO_ONLY

        raise BadInput(DISTRO_ONLY)
    make_drive = _ros2_drive(args) if args.drive == "ros2" else None
    with StopEvent(exit_after_s=CHILD_EXIT_AFTER_S) as stop:
        bus = open_bus(args, timeout_s=args.start_timeout, stop=stop, lean=True, role="robot", robot_id=args.id)
        log.info("robot %d: connected (fleet %s), waiting for a run", args.id, fleet)
        try:
            opts = robot.RobotOptions(scenario=scn, start_timeout=args.start_timeout,
                                      make_drive=None if make_drive is None else make_drive(bus),
                                      ref_timeout=args.ref_timeout, mode=args.mode, law_file=args.law_file)
            agents = robot.run_robot(bus, WALL, args.id, fleet, stop, opts)
        except LawFailure as e:  # the run's own law: EXIT_REFUSED, which swarm up does not restart (it ends the run)
            raise Refused(str(e)) from None
        except NoAnswer as e:
            if stop.is_set():
                return EXIT_INTERRUPTED
            raise Failure(str(e)) from None
        except RunRefused as e:
            raise BadInput(f"robot {args.id} refuses the run: {e}") from None
        except robot.DriveRefused as e:
            raise BadInput(f"robot {args.id}: {e}") from None
        except RuntimeError as e:  # a ROS 2 robot not found (swarm.drives.ros2.DiscoveryError)
            if type(e).__name__ == "DiscoveryError":
                raise Failure(f"robot {args.id}: {e}") from None
            raise
        finally:
            bus.close()
    log.info("robot %d: %d run%s served", args.id, len(agents), "" if len(agents) == 1 else "s")
    return EXIT_INTERRUPTED


def _ros2_drive(args):
    """make_drive for --drive ros2: a swarm.drives.ros2.Ros2Drive per run (bad input if the extra is missing)."""
    from swarm.core.inventory import model_limits

    try:
        from swarm.drives.ros2 import Ros2Drive
        from swarm.proto import ros2

        ros2.require()
    except ImportError as e:
        raise BadInput(f"--drive ros2: {e}") from None

    def factory(bus):
        def make(cfg, now):
            from agents.robot import DriveRefused

            if cfg.lockstep:
                raise DriveRefused("--drive ros2 runs in real time only (odometry carries no tick): the run is "
                                   "lock-step; start the world with --mode realtime")
            pose = args.initial_pose or (cfg.x, cfg.y, cfg.theta)
            return Ros2Drive(bus, namespace=args.namespace or f"robot{cfg.id}", now=now, flavor=args.ros_flavor,
                             twist=args.twist, domain=args.domain, initial_pose=pose,
                             attachment=args.rmw_zenoh_attachment, speed_limits=model_limits(args.robot_model),
                             distro=args.distro)

        return make

    return factory


def _id_of_secure_folder(args) -> int:
    """--id left out: the id in the certificate of --secure FOLDER (one robot's folder, copied to its machine);
    anything else is refused as argparse would refuse a missing --id."""
    if getattr(args, "secure", None) is None:
        raise BadInput("--id is required (or --secure FOLDER: the id is then its certificate's)")
    from swarm.net.secure import SecureError, robot_id_of

    try:
        rid = robot_id_of(args.secure)
    except (SecureError, OSError, ValueError) as e:
        raise BadInput(f"--secure {args.secure}: no robot certificate to take the id from ({e}); give --id") from None
    if rid is None:
        raise BadInput(f"--secure {args.secure}: not a robot's folder; give --id")
    return rid

