"""Parity at full size: lock-step `swarm up` against `swarm sim`, every robot's pose at every step.

    python bench/up_parity.py [--robots 37] [--duration 120] [--seed 0]

Runs `swarm up --robots N --trace t.npz` (real processes: router, world, leader, N robots) and
`swarm sim --scenario paper-50hz` in this process with the same N, seed and duration, then prints
the largest pose difference over all steps and robots and the metrics of both side by side.
The requirement is a difference of at most 1e-9 at every step; the exit code is 1 if
it is not met. tests/integration/test_up.py checks the same with N = 7 in CI; this is the
N = 37 check, about 3 minutes on 2 cores for the paper's 120 s.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from swarm.core import scenario_file
from swarm.core.scenario_file import Overrides
from swarm.core.sim import Simulation

KEYS = ("converged_at_s", "collisions", "min_robot_distance_m", "min_obstacle_distance_m",
        "final_position_error_max_m", "final_orientation_error_max_rad", "last_freeze_end_s")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--duration", type=float, default=120.0, help="simulated seconds (default 120, the paper's)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="swarm-parity-"))
    trace, metrics = out / "trace.npz", out / "metrics.json"
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--robots", str(a.robots), "--seed", str(a.seed),
           "--duration", str(a.duration), "--listen", f"tcp/127.0.0.1:{free_port()}", "--fleet", "parity",
           "--trace", str(trace), "--metrics", str(metrics), "--log-dir", str(out / "logs"), "--no-viz", "--quiet"]
    print(f"swarm up: {a.robots} robots, {a.duration:g} s of paper-50hz, seed {a.seed} (logs in {out}) ...",
          flush=True)
    t0 = time.perf_counter()
    rc = subprocess.run(cmd, timeout=120 + 10 * a.duration).returncode
    up_s = time.perf_counter() - t0
    if rc != 0:
        print(f"swarm up failed with exit code {rc}; see {out / 'logs'}")
        return 1
    scn = scenario_file.load("paper-50hz", Overrides(robots=a.robots, duration=a.duration, seed=a.seed))
    t0 = time.perf_counter()
    sim = Simulation(scn, record_period=scn.dt).run()
    sim_s = time.perf_counter() - t0
    q_up = np.load(trace)["q"]
    q_sim = sim.recording.q
    if q_up.shape != q_sim.shape:
        print(f"different shapes: swarm up {q_up.shape}, swarm sim {q_sim.shape}")
        return 1
    diff = np.abs(q_up - q_sim).max(axis=(1, 2))
    m_up = json.loads(metrics.read_text())
    print(f"steps compared: {len(diff)} x {a.robots} robots; largest pose difference {diff.max():.3g} "
          f"(first step above 1e-9: {int(np.argmax(diff > 1e-9)) if (diff > 1e-9).any() else 'none'})")
    print(f"wall: swarm up {up_s:.1f} s, swarm sim {sim_s:.1f} s; "
          f"lock-step {m_up['steps'] / m_up['run_wall_s']:.1f} ticks/s, {m_up['cmd_misses']} missed commands")
    print(f"{'metric':<34} {'swarm up':>14} {'swarm sim':>14}")
    for k in KEYS:
        print(f"{k:<34} {str(m_up[k]):>14.14} {str(sim.metrics[k]):>14.14}")
    same = all(m_up[k] == sim.metrics[k] for k in KEYS)
    ok = diff.max() <= 1e-9 and same
    print("PASS" if ok else "FAIL", "(poses within 1e-9 at every step, equal metrics)" if ok else "")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
