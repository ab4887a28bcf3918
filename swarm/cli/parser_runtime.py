"""The parsers of the runtime commands: up, router, world, leader, robot, preflight, stop, ps, echo, viz, replay,
report (swarm.cli.parser puts them in the `swarm` parser)."""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm.cli.flags import (
    add_fleet_flags,
    add_net_flags,
    add_optional_scenario_flags,
    add_ros2_flags,
    add_run_flags,
    add_scenario_flags,
    add_viz_flags,
    initial_pose_arg,
    int_at_least,
    positive_float,
    robot_pose_arg,
    robot_id,
)


def add_runtime_parsers(sub) -> None:
    up = sub.add_parser(
        "up", help="run the swarm: one process per robot over zenoh, plus router, world and leader",
        description="Start an embedded zenoh router (or join one with --connect), the world, the leader "
                    "and one process per robot, each in its own process group; wait until all are alive; "
                    "run with a live status line and the browser viewer (it prints the URL); write the "
                    "metrics; stop everything on the way out (also on Ctrl-C and SIGTERM). Without "
                    "--scenario it runs the built-in paper-50hz scenario (dt = 0.02 s, governor on).",
        epilog="Examples: swarm up --robots 37 | swarm up --robots 7 --mode realtime --speed 2 | "
               "swarm up --listen tcp/0.0.0.0:7447 (robots on other machines: docs/runtime.md, \"Running across machines\")")
    add_scenario_flags(up, "paper-50hz")
    add_run_flags(up, up=True)
    add_net_flags(up, listen=True, connect_help="join the router at ENDPOINT instead of starting one", starts=True)
    g = up.add_argument_group("drive")
    g.add_argument("--drive", choices=("sim", "ros2"), default="sim",
                   help="ros2: the world simulates a ROS 2 fleet (cmd_vel and odometry in CDR on ROS 2 keys) and every "
                        "agent drives its robot through them, as on real robots; needs --mode realtime")
    add_ros2_flags(g, world="up")
    g = up.add_argument_group("launcher")
    g.add_argument("--dry-run", action="store_true", help="print the launch plan and exit")
    g.add_argument("--restarts", type=int_at_least(0), default=3, metavar="N",
                   help="restart a failed robot process at most N times per window (default 3)")
    g.add_argument("--restart-window", type=positive_float, default=60.0, metavar="S",
                   help="the restart policy's window in seconds (default 60)")
    g.add_argument("--log-dir", metavar="DIR", help="where the processes' logs go, never pruned (default: a new folder in the temp dir; "
                        "swarm up keeps your 10 newest of each fleet there)")
    g.add_argument("--quiet", action="store_true", help="no status line and no summary")
    add_fleet_flags(up.add_argument_group("real robots (no simulated world: the referee watches their odometry)"))
    add_viz_flags(up, "--no-viz")
    up.set_defaults(func="swarm.cli.up:cmd_up")

    router = sub.add_parser("router", help="a zenoh router (what swarm up embeds)",
                            description="Run a zenoh router in this process. Routers on several machines "
                                        "connect to each other with --connect.")
    add_net_flags(router, listen=True, connect_help="another router to connect to (across machines)", router=True)
    router.set_defaults(func="swarm.cli.router:cmd_router")

    world = sub.add_parser("world", help="the simulated world: kinematics, obstacles, clock, metrics",
                           description="Simulate every robot (exact arcs), serve the obstacles and each robot's "
                                       "configuration, own the clock in lock-step, referee the run.")
    add_scenario_flags(world, "paper-50hz")
    add_run_flags(world)
    add_net_flags(world, started=True)
    g = world.add_argument_group("simulated ROS 2 fleet (real time)")
    g.add_argument("--ros2-sim", choices=("rmw_zenoh", "bridge"), metavar="FLAVOR",
                   help="the simulated robots speak ROS 2: each takes cmd_vel and gives odometry (its own frame, zero "
                        "at its start) on the ROS 2 keys of FLAVOR (rmw_zenoh or bridge), in CDR; needs --mode realtime")
    add_ros2_flags(g, world=True)
    world.add_argument("--process-faults", choices=("played", "signals"), default="played",
                       help="lock-step with kill or hang faults: 'played' (default), each robot's process idles "
                            "through its dead or hung ticks; 'signals', a supervisor really kills (SIGKILL) and "
                            "stops (SIGSTOP) them, and the world waits for a restarted or resumed robot before "
                            "its return tick (what swarm up does)")
    g = world.add_argument_group("real robots")
    g.add_argument("--referee-only", action="store_true",
                   help="no physics: serve the run to real robots (with --inventory) and referee it from their "
                        "odometry (the robots' states): metrics, snapshots, progress as in simulation; real time")
    add_fleet_flags(g)
    world.set_defaults(func="swarm.cli.world:cmd_world")

    leader = sub.add_parser("leader", help="publish the leader's reference",
                            description="Publish the virtual leader's reference from the scenario's segments.")
    add_scenario_flags(leader, "paper-50hz")
    add_run_flags(leader)
    add_net_flags(leader, started=True)
    leader.set_defaults(func="swarm.cli.leader:cmd_leader")

    robot = sub.add_parser("robot", help="one robot's agent (its decentralized controller)",
                           description="Run robot ID's controller. It takes its slice of the scenario from "
                                       "--scenario FILE (the same file on every machine) or, without it, from "
                                       "the world's configuration queryable.")
    robot.add_argument("--id", type=robot_id, default=argparse.SUPPRESS, metavar="I|auto",
                       help="the robot's id (0-based), or auto: the lowest free one, claimed from the world; "
                            "required, but with --secure FOLDER it defaults to the id of the folder's certificate")
    add_optional_scenario_flags(robot, "the world's configuration is used")
    robot.add_argument("--law-file", metavar="FILE.py",
                       help="this machine's copy of the run's control law (control.law = \"FILE.py:NAME\"), when "
                            "it is not at the path the run names; its sha256 must be the run's (docs/control.md)")
    add_run_flags(robot)
    add_net_flags(robot, started=True)
    g = robot.add_argument_group("drive (where the agent meets its robot; real time)")
    g.add_argument("--drive", choices=("sim", "ros2"), default="sim",
                   help="sim: the simulated world's pose and cmd keys (default); ros2: a ROS 2 robot (odometry in, "
                        "cmd_vel out), needs --mode realtime")
    add_ros2_flags(g, world="robot")
    g.add_argument("--namespace", metavar="NS", help="with --drive ros2: the robot's ROS namespace (default robot<ID>)")
    g.add_argument("--initial-pose", type=initial_pose_arg, metavar="X,Y,THETA",
                   help="with --drive ros2: the robot's start in the swarm's frame (default: the scenario's start); "
                        "the odometry frame is anchored there on its first message")
    g.add_argument("--ref-timeout", type=positive_float, default=2.5, metavar="S",
                   help="stop the robot when the reference has been extrapolated for longer than S (default 2.5)")
    g = robot.add_argument_group("a real fleet, or ids handed out by the world")
    add_fleet_flags(g, robot=True)
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
    pre.add_argument("--initial-pose", type=robot_pose_arg, action="append", metavar="I:X,Y,THETA",
                     help="robot I stands at X,Y,THETA (beats the inventory and the scenario); repeatable")
    pre.add_argument("--odom-timeout", type=positive_float, default=10.0, metavar="S",
                     help="seconds to wait for every robot's ROS 2 side and first odometry (default 10)")
    pre.add_argument("--start-timeout", type=positive_float, default=10.0, metavar="S",
                     help="seconds to wait for the router given with --connect (default 10)")
    pre.add_argument("--odom-window", type=positive_float, default=1.5, metavar="S",
                     help="seconds of odometry watched for gaps (default 1.5)")
    add_scenario_flags(pre, "paper-50hz")
    add_net_flags(pre)
    pre.set_defaults(func="swarm.cli.preflight:cmd_preflight")

    stop = sub.add_parser("stop", help="emergency stop: every robot of the fleet holds zero velocity (latched)",
                          description="Put the emergency stop on the fleet's estop key: every drive halts its robot "
                                      "within one control period and holds it until `swarm stop --release`. Robots "
                                      "started after the stop do not know of it: stop them again.",
                          epilog="Example: swarm stop --fleet lab --connect tcp/192.168.1.10:7447 --reason 'person in "
                                 "the arena'")
    stop.add_argument("--release", action="store_true", help="release the emergency stop (robots move again)")
    stop.add_argument("--reason", default="", metavar="TEXT", help="why (logged by every robot)")
    stop.add_argument("--repeat-s", type=positive_float, default=1.0, metavar="S",
                      help="keep saying it for S seconds (default 1), for robots whose link hiccups")
    add_net_flags(stop)
    stop.set_defaults(func="swarm.cli.stop:cmd_stop")

    ps = sub.add_parser("ps", help="the swarms on a router and their live processes (role, id, host, pid, age, run)",
                        description="List every swarm process on --connect's router: one line per liveliness "
                                    "token (router, swarm up, world, leader, robots, viewers) or robot process "
                                    "waiting for a run, with what the process says of itself (host, pid, age, the "
                                    "run it is in). Every fleet on the router, or only --fleet's. Under --secure it "
                                    "uses the fleet's operator identity. Exit 1 when no process answered (a script "
                                    "can wait for a fleet: until swarm ps --fleet NAME; do sleep 1; done).",
                        epilog="Example: swarm ps --connect tcp/192.168.1.10:7447")
    ps.add_argument("--wait", type=positive_float, default=2.0, metavar="S",
                    help="wait at most S seconds for the processes to answer (default 2)")
    ps.add_argument("--json", action="store_true", help="print the listing as JSON (one object per process)")
    add_net_flags(ps)
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
    echo.add_argument("--timeout", type=positive_float, metavar="S", help="exit after S seconds (exit 1 if nothing "
                                                                            "came)")
    add_net_flags(echo)
    echo.set_defaults(func="swarm.cli.echo:cmd_echo")

    viz = sub.add_parser("viz", help="watch a running swarm in a browser (meshcat)",
                         description="Start a meshcat web server, print its URL, and draw the swarm of --fleet "
                                     "on --connect's router: robots coloured by state, obstacles, the leader and "
                                     "the formation's slots, trails. It only listens: it never slows the swarm. "
                                     "Without --scenario it asks the world for the obstacles and the slots.",
                         epilog="Example: swarm viz --connect tcp/192.168.1.10:7447 --viz-host 0.0.0.0 --viz-port 7000")
    add_optional_scenario_flags(viz, "the world's queryables are used")
    add_viz_flags(viz, None)
    viz.add_argument("--server-log", type=Path, metavar="PATH",
                     help="append the meshcat server's own log (connections) to PATH (default: discarded)")
    viz.add_argument("--start-timeout", type=positive_float, default=60.0, metavar="S",
                     help="seconds to wait for the router at start (default 60)")
    add_net_flags(viz, started=True)
    viz.set_defaults(func="swarm.cli.viz:cmd_viz")

    replay = sub.add_parser("replay", help="play a recording (swarm sim/up --record) in the browser viewer",
                            description="Play the snapshots of an MCAP recording in the viewer at --speed times "
                                        "real time (the recorded poses exactly, at most 30 frames a second), "
                                        "then keep the viewer up until Ctrl-C.",
                            epilog="Example: swarm replay run.mcap --speed 4")
    replay.add_argument("recording", type=Path, metavar="FILE.mcap")
    replay.add_argument("--speed", type=positive_float, default=1.0, metavar="X",
                        help="simulated seconds per wall second (default 1)")
    w = replay.add_mutually_exclusive_group()
    w.add_argument("--wait", action="store_true",
                   help="start when a browser opens the viewer's URL (the default when the output is a terminal)")
    w.add_argument("--no-wait", action="store_true", help="start at once (the default in scripts)")
    replay.add_argument("--exit", action="store_true", help="exit when the replay ends instead of waiting for Ctrl-C")
    add_viz_flags(replay, None)
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
