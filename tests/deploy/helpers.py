"""Helpers of the real-fleet tests: a scenario that converges in half a minute, inventories, and
processes started by PID (the swarm's commands, the simulated fleet)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from swarm.core import scenario_file
from swarm.core.scenario_file import to_toml
from tests.integration.helpers import wait_until  # noqa: F401  (for the deploy tests)

ROOT = Path(__file__).resolve().parents[2]
ENTRY = [sys.executable, "-m", "swarm.cli"]
FLEET_SIM = [sys.executable, "-m", "tests.deploy.fleet_sim"]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), *sys.path])}


def small_turtlebot3(path: Path, duration: float = 50.0) -> Path:
    """The built-in turtlebot3 formation (7 robots, r 0.22, R 0.6, v_max 0.22, w_max 2.84, 20 Hz) with
    each robot 0.5-0.8 m behind its slot, no obstacle, arena.bounds [-3, 9, -3, 6] (the slots stay inside
    for 50 s): it converges at about 30 s (swarm sim: 29.85 s)."""
    scn = scenario_file.load("turtlebot3", progress=scenario_file.silent)
    rng = np.random.default_rng(1)
    poses = np.zeros((scn.n, 3))
    poses[:, :2] = scn.offsets + np.array([-0.6, -0.5]) + rng.uniform(-0.1, 0.1, (scn.n, 2))
    poses[:, 2] = rng.uniform(-0.5, 0.5, scn.n)
    small = scn.replace(poses=poses, obstacles=np.zeros((0, 4)), duration=duration, bounds=(-3.0, 9.0, -3.0, 6.0))
    path.write_text(to_toml(small))
    return path


def inventory_text(n: int, connect: str | None, fleet: str = "lab", flavor: str = "rmw_zenoh", **rows) -> str:
    """An inventory of robots 0..n-1; rows={"r3": {"v_max": 0.1}} adds keys to robot 3's table."""
    lines = [f'fleet = "{fleet}"']
    for i in range(n):
        lines += ["", "[[robot]]", f"id = {i}", f'flavor = "{flavor}"']
        if connect:
            lines.append(f'connect = "{connect}"')
        for k, v in rows.get(f"r{i}", {}).items():
            lines.append(f"{k} = {v!r}".replace("'", '"'))
    return "\n".join(lines) + "\n"


class Procs:
    """Processes a test starts, each in its own process group with its output in a log file;
    stop() ends them by PID (SIGTERM, then SIGKILL) and waits for them."""

    def __init__(self, tmp_path: Path) -> None:
        self.tmp_path = tmp_path
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, name: str, argv: list[str], cwd: Path | None = None, env: dict | None = None) -> subprocess.Popen:
        with open(self.tmp_path / f"{name}.log", "wb") as log:
            p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                 process_group=0, cwd=cwd or ROOT, env=env or ENV)
        self.procs[name] = p
        return p

    def log(self, name: str) -> str:
        return (self.tmp_path / f"{name}.log").read_text(errors="replace")

    def logs(self, *names: str, tail: int = 3000) -> str:
        return "\n".join(f"--- {n}\n{self.log(n)[-tail:]}" for n in (names or self.procs))

    def stop(self, name: str, sig: int = signal.SIGTERM, timeout_s: float = 10.0) -> int | None:
        p = self.procs[name]
        if p.poll() is None:
            try:
                os.killpg(p.pid, sig)
            except ProcessLookupError:
                pass
        try:
            return p.wait(timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            return p.wait(5.0)

    def stop_all(self) -> None:
        for name in list(self.procs):
            self.stop(name)

