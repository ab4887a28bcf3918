"""`swarm up --inventory`'s launch plan (swarm.launch.inventory_plan, pure) and its --dry-run."""

from __future__ import annotations

import subprocess

import pytest

from swarm.launch.inventory_plan import NO_RESTARTS, FleetUpOptions, make_fleet_plan
from swarm.launch.plan import VizOptions
from tests.deploy.helpers import ENTRY, ENV, ROOT, inventory_text


@pytest.mark.unit
def test_the_plan():
    o = FleetUpOptions(inventory="/etc/fleet.toml", robots=3,
                       scenario_args=("--scenario", "turtlebot3", "--robots", "3"),
                       robot_endpoints=("tcp/10.0.0.1:7447", "tcp/10.0.0.2:7447"), initial_poses=("1:0.5,0.5,0.0",),
                       fleet="lab", listen="tcp/0.0.0.0:7447", metrics="/tmp/m.json", viz=VizOptions(port=7000))
    plan = make_fleet_plan(o, python="py")
    assert [p.name for p in plan.processes] == ["router", "viz", "world", "leader", "robot 0", "robot 1", "robot 2"]
    assert plan.endpoint == "tcp/127.0.0.1:7447" and plan.restart == NO_RESTARTS and plan.restart.max_restarts == 0
    assert plan.router.argv == ("py", "-m", "swarm.cli", "router", "--listen", "tcp/0.0.0.0:7447", "--fleet", "lab",
                                "--connect", "tcp/10.0.0.1:7447", "--connect", "tcp/10.0.0.2:7447")
    w = plan.world.argv
    assert w[3:8] == ("world", "--referee-only", "--inventory", "/etc/fleet.toml", "--no-preflight")
    assert ("--initial-pose", "1:0.5,0.5,0.0") == w[w.index("--initial-pose"):w.index("--initial-pose") + 2]
    assert w[w.index("--mode") + 1] == "realtime" and w[w.index("--metrics") + 1] == "/tmp/m.json"
    r1 = plan.robots[1].argv
    assert r1[3:8] == ("robot", "--inventory", "/etc/fleet.toml", "--id", "1")
    assert r1[r1.index("--connect") + 1] == "tcp/127.0.0.1:7447" and "--scenario" not in r1  # the world's config
    assert plan.leader.argv[3:7] == ("leader", "--scenario", "turtlebot3", "--robots")
    joined = make_fleet_plan(FleetUpOptions(inventory="f", robots=1, scenario_args=(), connect="tcp/hub:7447",
                                            listen=None), module="swarm.cli")
    assert joined.router is None and joined.endpoint == "tcp/hub:7447" and joined.world.argv[2] == "swarm.cli"


@pytest.mark.integration
def test_dry_run_prints_the_plan_the_fleet_and_the_static_preflight(tmp_path):
    inv = tmp_path / "fleet.toml"
    inv.write_text(inventory_text(7, "tcp/192.168.1.20:7447", r3={"v_max": 0.15}))
    out = subprocess.run([*ENTRY, "up", "--inventory", str(inv), "--scenario", "turtlebot3", "--dry-run",
                          "--initial-pose", "2:1.0,-4.0,0.0"], capture_output=True, text=True, timeout=60, cwd=ROOT,
                         env=ENV)
    # the plan and every check are printed; the failed pre-flight is the exit code too, as it is without --dry-run
    assert out.returncode == 1 and "pre-flight failed" in out.stderr, out.stderr
    text = out.stdout
    assert "--connect tcp/192.168.1.20:7447" in text and "world --referee-only" in text
    assert "robot 2: ros2 rmw_zenoh /robot2 domain 0 twist plain via tcp/192.168.1.20:7447; start (1, -4, 0) from " \
           "--initial-pose" in text
    assert "robot 3: leader.segments[0] moves at |v| = 0.15 m/s, more than 0.8 x v_max = 0.12 m/s" in text
    assert "pre-flight FAILED" in text
    bad = subprocess.run([*ENTRY, "up", "--inventory", str(inv), "--scenario", "turtlebot3", "--robots", "5",
                          "--dry-run"], capture_output=True, text=True, timeout=60, cwd=ROOT, env=ENV)
    assert bad.returncode == 2 and "robot[5].id: robot 5 is not in scenario 'turtlebot3' (5 robots" in bad.stderr


@pytest.mark.unit
def test_flags_that_mean_nothing_with_a_real_fleet_are_refused_not_dropped(tmp_path, capsys):
    """--drive, --ros-flavor, --twist, --domain, --restarts, --restart-window, --tick-timeout and --mode lockstep
    were accepted with --inventory and silently ignored; a given flag is refused, its value whatever it is
    (--twist plain is the default, and still not what the inventory's rows are told)."""
    from swarm.cli.main import main

    inv = tmp_path / "fleet.toml"
    inv.write_text(inventory_text(7, "tcp/192.168.1.20:7447"))
    base = ["up", "--inventory", str(inv), "--scenario", "turtlebot3", "--dry-run"]
    for extra, said in [(["--drive", "sim"], "--drive with --inventory: each robot's drive comes from its inventory"),
                        (["--ros-flavor", "bridge"], "--ros-flavor with --inventory"),
                        (["--twist", "plain"], "--twist with --inventory"), (["--domain", "3"], "--domain with"),
                        (["--restarts", "2"], "--restarts with --inventory: a real fleet's processes are never"),
                        (["--restart-window", "9"], "--restart-window with"),
                        (["--tick-timeout", "2"], "--tick-timeout with"),
                        (["--mode", "lockstep"], "--mode lockstep with --inventory: real robots keep real time")]:
        assert main(base + extra) == 2, extra
        assert said in capsys.readouterr().err, extra
    assert main(base + ["--mode", "realtime"]) == 0  # what happens anyway: said, not refused
    capsys.readouterr()
    # the simulated world and a robot: flags of another use
    for argv, said in [(["world", "--initial-pose", "1:0,0,0"], "--initial-pose needs --inventory"),
                       (["world", "--no-preflight"], "--no-preflight needs --inventory"),
                       (["world", "--twist", "stamped"], "--twist needs --ros2-sim"),
                       (["world", "--domain", "1"], "--domain needs --ros2-sim"),
                       (["robot", "--id", "1", "--drive", "ros2", "--mode", "lockstep"],
                        "--drive ros2 with --mode lockstep: a ROS 2 robot runs in real time only")]:
        assert main(argv) == 2, argv
        assert said in capsys.readouterr().err, argv


@pytest.mark.unit
def test_given_flags_are_the_explicit_ones_whatever_their_value():
    from swarm.cli.parser import given_flags

    assert given_flags(["up", "--mode", "lockstep", "--robots", "3"]) == {"mode", "robots"}
    assert given_flags(["up"]) == frozenset()
    assert given_flags(["robot", "--id", "2", "--drive", "sim", "--kill", "1@2", "--kill", "2@3"]) >= {"id", "drive",
                                                                                                        "kill"}


@pytest.mark.unit
def test_help_names_every_built_in_scenario():
    from swarm.cli.parser import build_parser
    from swarm.core.scenario_file import BUILTINS

    text = build_parser()._subparsers._group_actions[0].choices["up"].format_help()
    assert f"built-in name ({', '.join(BUILTINS)})" in " ".join(text.split())
