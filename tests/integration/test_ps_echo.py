"""`swarm ps` and `swarm echo` against real processes on a real router: two fleets on one router listed with
their pids, a served key asked and a put one followed, and the same under --secure with the operator's
identity. Every process in its own process group, stopped by PID on the way out."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from swarm.launch.child import stop_group
from tests.integration.helpers import free_port, wait_until

pytestmark = pytest.mark.integration

CLI = [sys.executable, "-m", "swarm.cli"]


@pytest.fixture
def started():
    procs: list[subprocess.Popen] = []

    def start(*args: str) -> subprocess.Popen:
        p = subprocess.Popen(CLI + list(args), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             process_group=0)
        procs.append(p)
        return p

    yield start
    for p in procs:
        stop_group(p)


def _ps(*args: str) -> list[dict]:
    out = subprocess.run(CLI + ["ps", "--json", "--wait", "2", *args], capture_output=True, text=True, timeout=60)
    rows = json.loads(out.stdout)
    assert out.returncode == (0 if rows else 1), out.stderr  # 1: no process answered
    return rows


def _listed(rows: list[dict]) -> set[tuple]:
    return {(r["fleet"], r["role"], r["id"], r["pid"]) for r in rows}


def test_ps_lists_two_fleets_on_one_router_with_pids_and_echo_asks_and_follows(started):
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    router = started("router", "--listen", ep, "--fleet", "psa")
    a0 = started("robot", "--id", "0", "--fleet", "psa", "--connect", ep, "--start-timeout", "120")
    b1 = started("robot", "--id", "1", "--fleet", "psb", "--connect", ep, "--start-timeout", "120")
    want = {("psa", "router", 0, router.pid), ("psa", "robot", 0, a0.pid), ("psb", "robot", 1, b1.pid)}
    rows: list[dict] = []

    def listed() -> bool:
        rows[:] = _ps("--connect", ep)
        return want <= _listed(rows)

    wait_until(listed, 60, "swarm ps to list the router and both robots")
    assert all(r["host"] and r["started"] > 0 for r in rows) and {r["fleet"] for r in rows} == {"psa", "psb"}
    assert _listed(_ps("--connect", ep, "--fleet", "psb")) == {("psb", "robot", 1, b1.pid)}
    text = subprocess.run(CLI + ["ps", "--connect", ep], capture_output=True, text=True, timeout=60).stdout
    assert text.splitlines()[0].split() == ["FLEET", "ROLE", "ID", "HOST", "PID", "AGE", "RUN"]
    assert f"3 processes in 2 fleets (psa, psb) on {ep}" in text
    none = subprocess.run(CLI + ["ps", "--connect", ep, "--fleet", "psc"], capture_output=True, text=True, timeout=60)
    assert none.returncode == 1 and none.stdout == f"swarm ps: no swarm process on {ep} in fleet psc\n"

    # a served key: asked once, each reply decoded
    out = subprocess.run(CLI + ["echo", "proc/robot/*", "--fleet", "psa", "--connect", ep, "--timeout", "5"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    (line,) = out.stdout.splitlines()
    assert line.startswith("swarm/psa/proc/robot/0 proc {") and json.loads(line.split(" proc ", 1)[1])["pid"] == a0.pid
    # a put key: followed until --count; the operator's emergency stop, decoded with its reason
    echo = subprocess.Popen(CLI + ["echo", "estop", "--fleet", "psb", "--connect", ep, "--count", "1", "--timeout", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, process_group=0)
    try:
        subprocess.run(CLI + ["stop", "--fleet", "psb", "--connect", ep, "--reason", "ps test", "--repeat-s", "3"],
                       capture_output=True, text=True, timeout=60, check=True)
        got, err = echo.communicate(timeout=60)
    finally:
        if echo.poll() is None:
            os.killpg(echo.pid, signal.SIGKILL)
            echo.wait(5)
    assert echo.returncode == 0, err
    (line,) = got.splitlines()
    assert line.startswith("swarm/psb/estop estop {") and '"reason": "ps test"' in line and '"engaged": true' in line
    # nothing there: said, exit 1
    out = subprocess.run(CLI + ["echo", "leader/ref", "--fleet", "psc", "--connect", ep, "--timeout", "0.5"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "nothing on swarm/psc/leader/ref within 0.5 s" in out.stdout
    assert "no process of fleet psc is live there" in out.stdout
    # a fleet that runs, on a quiet key: said so (not "is a swarm running?")
    out = subprocess.run(CLI + ["echo", "leader/ref", "--fleet", "psa", "--connect", ep, "--timeout", "0.5"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "fleet psa has 2 live processes" in out.stdout, out.stdout


def test_ps_and_echo_under_secure_with_the_operators_identity(started, tmp_path):
    port = free_port()
    d = tmp_path / "fleet"
    subprocess.run(CLI + ["secure", "init", str(d), "--robots", "2", "--fleet", "pss", "--port", str(port)],
                   capture_output=True, text=True, timeout=120, check=True)
    router = started("router", "--secure", str(d), "--fleet", "pss")
    r1 = started("robot", "--id", "1", "--secure", str(d), "--fleet", "pss", "--start-timeout", "120")
    want = {("pss", "router", 0, router.pid), ("pss", "robot", 1, r1.pid)}
    wait_until(lambda: want <= _listed(_ps("--secure", str(d), "--fleet", "pss")), 60,
               "swarm ps --secure to list the router and robot 1")
    out = subprocess.run(CLI + ["echo", "proc/*/*", "--secure", str(d), "--fleet", "pss", "--timeout", "5"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert sorted(line.split()[0] for line in out.stdout.splitlines()) == ["swarm/pss/proc/robot/1",
                                                                         "swarm/pss/proc/router/0"]
    out = subprocess.run(CLI + ["ps", "--secure", str(d)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "give --fleet" in out.stderr
