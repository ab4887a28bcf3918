"""Across "machines": router, world and leader in one network namespace, the robots in two others,
joined by veth links this test creates (root and `ip netns` needed; skipped with the reason otherwise)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import uuid

import numpy as np
import pytest

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation

pytestmark = pytest.mark.integration

N = 7
DURATION = 50.0
PORT = 7447


def _sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True, timeout=30)


def _netns_unavailable() -> str | None:
    if os.geteuid() != 0:
        return "needs root to create network namespaces"
    if shutil.which("ip") is None:
        return "needs the `ip` tool (iproute2)"
    probe = f"swp{uuid.uuid4().hex[:6]}"
    try:
        _sh("ip", "netns", "add", probe)
    except (subprocess.CalledProcessError, OSError) as e:
        return f"cannot create a network namespace here: {e}"
    _sh("ip", "netns", "del", probe)
    return None


@pytest.fixture
def namespaces():
    why = _netns_unavailable()
    if why:
        pytest.skip(why)
    tag = uuid.uuid4().hex[:5]
    hub, a, b = f"sw{tag}h", f"sw{tag}a", f"sw{tag}b"
    made = []
    try:
        for ns in (hub, a, b):
            _sh("ip", "netns", "add", ns)
            made.append(ns)
            _sh("ip", "-n", ns, "link", "set", "lo", "up")
        for ns, net, (h_if, r_if) in ((a, "10.231.1", (f"h{tag}a", f"r{tag}a")), (b, "10.231.2", (f"h{tag}b", f"r{tag}b"))):
            _sh("ip", "link", "add", h_if, "netns", hub, "type", "veth", "peer", "name", r_if, "netns", ns)
            _sh("ip", "-n", hub, "addr", "add", f"{net}.1/24", "dev", h_if)
            _sh("ip", "-n", ns, "addr", "add", f"{net}.2/24", "dev", r_if)
            _sh("ip", "-n", hub, "link", "set", h_if, "up")
            _sh("ip", "-n", ns, "link", "set", r_if, "up")
        yield hub, a, b
    finally:
        for ns in made:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=30)


def test_robots_in_two_namespaces_converge_through_a_router_in_a_third(namespaces, tmp_path):
    hub, a, b = namespaces
    swarm = [sys.executable, "-m", "swarm.cli"]
    scn_args = ["--scenario", "paper-50hz", "--robots", str(N), "--duration", str(DURATION)]
    metrics = tmp_path / "metrics.json"
    trace = tmp_path / "trace.npz"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    procs: list[subprocess.Popen] = []

    def start(ns: str, *args: str, name: str) -> subprocess.Popen:
        log = open(tmp_path / f"{name}.log", "wb")
        p = subprocess.Popen(["ip", "netns", "exec", ns, *swarm, *args], stdout=log, stderr=subprocess.STDOUT,
                             env=env, process_group=0)
        procs.append(p)
        return p

    try:
        start(hub, "router", "--listen", f"tcp/0.0.0.0:{PORT}", "--fleet", "ns", name="router")
        local = ["--connect", f"tcp/127.0.0.1:{PORT}", "--fleet", "ns"]
        world = start(hub, "world", *scn_args, "--metrics", str(metrics), "--trace", str(trace),
                      "--start-timeout", "60", *local, name="world")
        start(hub, "leader", *scn_args, *local, name="leader")
        for i in range(N):
            ns, hub_ip = (a, "10.231.1.1") if i % 2 == 0 else (b, "10.231.2.1")
            start(ns, "robot", "--id", str(i), "--connect", f"tcp/{hub_ip}:{PORT}", "--fleet", "ns",
                  "--start-timeout", "60", name=f"robot{i}")
        rc = world.wait(timeout=240)
        logs = "".join((tmp_path / f).read_text(errors="replace")[-2000:] for f in ("world.log", "robot0.log"))
        assert rc == 0, logs
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, 15)
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, 9)
                p.wait(5)
    m = json.loads(metrics.read_text())
    assert m["converged_at_s"] is not None and m["collisions"] == 0 and m["cmd_misses"] == 0
    # and it is still the very same run as the in-process simulator
    scn = scenario_file.load("paper-50hz", Overrides(robots=N, duration=DURATION))
    sim = Simulation(scn, record_period=scn.dt).run()
    assert np.abs(np.load(trace)["q"] - sim.recording.q).max() <= 1e-9
    assert m["converged_at_s"] == sim.metrics["converged_at_s"]
