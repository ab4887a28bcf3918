"""The launch plan of `swarm up`: a pure function of the options."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from swarm.launch.plan import RestartPolicy, UpOptions, make_plan


def opts(**kw):
    base = dict(robots=3, scenario_args=("--scenario", "paper-50hz", "--robots", "3"))
    base.update(kw)
    return UpOptions(**base)


@pytest.mark.unit
def test_plan_starts_router_world_leader_and_one_process_per_robot():
    plan = make_plan(opts(), python="py")
    names = [p.name for p in plan.processes]
    assert names == ["router", "world", "leader", "robot 0", "robot 1", "robot 2"]
    assert plan.endpoint == "tcp/127.0.0.1:7447"
    assert plan.router.argv == ("py", "-m", "swarm.cli", "router", "--listen", "tcp/127.0.0.1:7447")
    for p in plan.processes[1:]:
        a = list(p.argv)
        assert a[a.index("--connect") + 1] == "tcp/127.0.0.1:7447" and a[a.index("--fleet") + 1] == "default"
    assert plan.robots[2].argv[3:6] == ("robot", "--id", "2")
    assert "--scenario" not in plan.robots[0].argv  # robots take their slice from the world's queryable
    assert ("--scenario", "paper-50hz") == plan.world.argv[4:6] == plan.leader.argv[4:6]


@pytest.mark.unit
def test_processes_on_the_embedded_router_leave_the_ingress_checks_to_it():
    """Its own router drops oversized and wildcard puts as they come in (swarm.net.bus.size_limits,
    wildcard_guard), so the processes swarm up starts on it do not check them again; a router swarm up did not
    start may be somebody else's: there every process keeps its own checks."""
    from swarm.launch.plan import VizOptions

    zid = "c3" * 16
    own = make_plan(opts(router_zid=zid, viz=VizOptions()), python="py")
    assert own.router.argv[-2:] == ("--zid", zid) and "--router-checks" not in own.router.argv
    for p in own.processes[1:]:  # the viewer, the world, the leader, the robots
        a = list(p.argv)
        assert a[a.index("--router-checks") + 1] == zid, p.name
    joined = make_plan(opts(connect="tcp/10.0.0.5:7447", listen=None, router_zid=zid), python="py")
    assert not any("--router-checks" in p.argv for p in joined.processes)
    assert not any("--router-checks" in p.argv for p in make_plan(opts(), python="py").processes)


@pytest.mark.unit
def test_plan_is_pure_and_deterministic():
    assert make_plan(opts(), python="py") == make_plan(opts(), python="py")


@pytest.mark.unit
def test_connect_joins_an_existing_router_and_listen_any_is_reached_on_loopback():
    plan = make_plan(opts(connect="tcp/10.0.0.5:7447", listen=None), python="py")
    assert plan.router is None and plan.endpoint == "tcp/10.0.0.5:7447"
    plan = make_plan(opts(listen="tcp/0.0.0.0:7500"), python="py")
    assert plan.router.argv[-1] == "tcp/0.0.0.0:7500" and plan.endpoint == "tcp/127.0.0.1:7500"


@pytest.mark.unit
def test_options_reach_every_process():
    plan = make_plan(opts(fleet="blue", zenoh_config="/etc/z.json5", multicast=True, mode="realtime", speed=2.0,
                          metrics="/tmp/m.json", restart=RestartPolicy(5, 10.0)), python="py")
    for p in plan.processes:
        a = list(p.argv)
        assert "--multicast" in a and a[a.index("--zenoh-config") + 1] == "/etc/z.json5"
    w = list(plan.world.argv)
    assert w[w.index("--mode") + 1] == "realtime" and w[w.index("--speed") + 1] == "2.0"
    assert w[w.index("--metrics") + 1] == "/tmp/m.json"
    assert plan.restart == RestartPolicy(5, 10.0)
    assert "at most 5 times in 10 s" in plan.describe()


@pytest.mark.integration
def test_dry_run_prints_the_plan_and_starts_nothing():
    out = subprocess.run([sys.executable, "-m", "swarm.cli", "up", "--robots", "4", "--dry-run", "--fleet", "x"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "4 robots" in out.stdout and out.stdout.count(" robot --id ") == 4


@pytest.mark.integration
def test_speed_in_lockstep_is_refused():
    base = [sys.executable, "-m", "swarm.cli", "up", "--robots", "2", "--dry-run", "--speed", "3"]
    out = subprocess.run(base, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--speed 3: lock-step runs as fast as the robots answer" in out.stderr
    out = subprocess.run(base + ["--mode", "realtime"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "--speed" not in out.stderr


@pytest.mark.unit
def test_the_viewer_is_a_viz_process_right_after_the_router():
    from swarm.launch.plan import VizOptions

    plan = make_plan(opts(viz=VizOptions(host="0.0.0.0", port=7000, rings=True, server_log="/tmp/v.log")),
                     python="py")
    assert [p.name for p in plan.processes][:3] == ["router", "viz", "world"]
    a = list(plan.viz.argv)
    assert a[3] == "viz" and plan.viz.role == "viz"  # not "robot": never restarted
    assert a[a.index("--viz-host") + 1] == "0.0.0.0" and a[a.index("--viz-port") + 1] == "7000"
    assert "--viz-rings" in a and a[a.index("--server-log") + 1] == "/tmp/v.log"
    assert a[a.index("--connect") + 1] == plan.endpoint and a[a.index("--fleet") + 1] == "default"
    assert ("--scenario", "paper-50hz") == plan.viz.argv[4:6]  # exact leader and slots, no queries needed
    assert make_plan(opts(), python="py").viz is None


@pytest.mark.integration
def test_dry_run_shows_the_viewer_unless_no_viz():
    base = [sys.executable, "-m", "swarm.cli", "up", "--robots", "2", "--dry-run", "--viz-port", "7123"]
    out = subprocess.run(base, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    viz = [line for line in out.stdout.splitlines() if line.strip().startswith("viz ")]
    assert len(viz) == 1 and "--viz-host 127.0.0.1 --viz-port 7123" in viz[0]
    out = subprocess.run(base[:-2] + ["--no-viz"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and " viz " not in out.stdout


@pytest.mark.integration
def test_compile_project_leaves_bytecode_the_children_use(tmp_path):
    """The launcher compiles the project once; a child that may not write bytecode still reads it."""
    import shutil

    for pkg in ("swarm", "agents", "world"):  # a copy of the sources, so the test owns its __pycache__
        shutil.copytree(Path(__file__).resolve().parents[2] / pkg, tmp_path / pkg,
                        ignore=shutil.ignore_patterns("__pycache__"))
    env = {**os.environ, "PYTHONPATH": str(tmp_path), "PYTHONDONTWRITEBYTECODE": "1"}
    run = [sys.executable, "-c", "from swarm.launch import supervisor; supervisor.compile_project(); print(supervisor.__file__)"]
    out = subprocess.run(run, env=env, capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert Path(out.stdout.strip()) == tmp_path / "swarm" / "launch" / "supervisor.py"  # the copy, not the checkout
    pycs = {p.relative_to(tmp_path).parts[0] for p in tmp_path.rglob("__pycache__/*.pyc")}
    assert pycs == {"swarm", "agents", "world"}
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*.pyc")}
    out = subprocess.run([sys.executable, "-v", "-c", "import agents.robot"], env=env, capture_output=True,
                         text=True, timeout=60, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert f"matches {tmp_path / 'agents' / 'robot.py'}" in out.stderr  # imported from its .pyc
    assert {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*.pyc")} == stamps


@pytest.mark.integration
def test_a_stopped_child_whose_shutdown_hangs_exits_anyway():
    """StopEvent(exit_after_s): after the stop signal, a process stuck in its clean shutdown (here: a
    wait that never ends) still exits, with 130, so a SIGKILLed launcher leaves nothing behind."""
    code = ("import os, signal, threading; from swarm.cli.common import StopEvent\n"
            "with StopEvent(exit_after_s=0.5) as stop:\n"
            "    os.kill(os.getpid(), signal.SIGTERM)\n"
            "    assert stop.wait(5)\n"
            "    threading.Event().wait()  # a shutdown that never ends\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    assert out.returncode == 130, out.stderr
    assert "clean shutdown took more than 0.5 s" in out.stderr


@pytest.mark.integration
def test_stop_event_survives_a_storm_of_signals():
    """The handler takes no lock: signals arriving while the main thread waits on the event, or while an
    earlier handler runs, must neither deadlock nor break the process (a leader once hung that way)."""
    code = ("import os, signal, threading, time\nfrom swarm.cli.common import StopEvent\n"
            "with StopEvent(hard_second=False) as stop:\n"
            "    def storm():\n"
            "        for _ in range(300):\n"
            "            os.kill(os.getpid(), signal.SIGTERM)\n"
            "            time.sleep(0.0005)\n"
            "    th = threading.Thread(target=storm)\n"
            "    th.start()\n"
            "    while th.is_alive():\n"
            "        stop.wait(0.0005)\n"
            "    th.join()\n"
            "    assert stop.wait(5)\n"
            "print('ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr[-2000:]
