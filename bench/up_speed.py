"""`swarm up` speed: launch, lock-step ticks per second, real-time round trip, CPU and RSS per robot.

    python bench/up_speed.py [--robots 7 19 37] [--duration 20] [--speed 1]

For each N it runs `swarm up` twice (lock-step, then real time at 50 Hz) as a user would, and
samples every child process with psutil while the run is under way. Figures:
  launch      seconds from the first process started to every liveliness token seen
  ticks/s     lock-step ticks per wall second over the run (world's run_wall_s, launch excluded)
  round trip  real time: world publishes a pose -> world receives the command computed from it
  robot CPU   mean CPU of one robot process during the lock-step run [% of a core] (the real-time
              run is not sampled: sampling ~150 threads 4 times a second would disturb it)
  robot RSS   mean and largest resident memory of a robot process [MiB]
  loop us     real time: CPU of a robot's loop thread per control period [us], the mean over robots
              (from their logs); bench/zenoh_floor.py measures the same for a loop that only moves
              the messages
Targets (issue 3, N = 37 on 2 cores): launch <= 5 s, >= 100 ticks/s, p99 <= 10 ms, <= 60 MiB.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(n: int, duration: float, mode: str, out: Path, speed: float = 1.0) -> tuple[dict, dict]:
    metrics = out / f"m-{mode}-{n}.json"
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--robots", str(n), "--duration", str(duration), "--mode", mode,
           "--listen", f"tcp/127.0.0.1:{free_port()}", "--fleet", f"bench{n}", "--metrics", str(metrics),
           "--log-dir", str(out / f"logs-{mode}-{n}"), "--no-viz", "--quiet"]
    if mode == "realtime":
        cmd += ["--speed", str(speed)]
    proc = subprocess.Popen(cmd)
    samples: dict[int, list] = {}
    done = threading.Event()

    def sample() -> None:
        parent = psutil.Process(proc.pid)
        while not done.wait(0.25):
            for c in parent.children(recursive=True):
                try:
                    if "robot" in c.cmdline():
                        samples.setdefault(c.pid, []).append((time.monotonic(), c.cpu_times(), c.memory_info().rss))
                except psutil.Error:
                    pass

    t = threading.Thread(target=sample, daemon=True)
    if mode == "lockstep":  # psutil's reads of ~150 threads would disturb the real-time round trip
        t.start()
    proc.wait(timeout=60 + 20 * duration)
    done.set()
    if t.is_alive():
        t.join()
    m = json.loads(metrics.read_text())
    cpu, rss = [], []
    for rows in samples.values():
        rss += [r for _, _, r in rows]
        if len(rows) >= 4:  # skip the first sample (start-up)
            (t0, c0, _), (t1, c1, _) = rows[1], rows[-1]
            cpu.append((c1.user + c1.system - c0.user - c0.system) / (t1 - t0))
    res = {"cpu_pct": 100 * sum(cpu) / max(1, len(cpu)), "rss_mean": sum(rss) / max(1, len(rss)) / 2**20,
           "rss_max": max(rss, default=0) / 2**20}
    return m, res


LOOP_CPU = re.compile(r"loop CPU (\d+) us a tick")


def loop_us(log_dir: Path) -> float:
    """Mean over the robots of their loop thread's CPU per tick, as each robot logs it at exit."""
    found = [float(m.group(1)) for f in log_dir.glob("robot-*.log") for m in LOOP_CPU.finditer(f.read_text())]
    return sum(found) / len(found) if found else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, nargs="+", default=[7, 19, 37])
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds per run (default 20)")
    ap.add_argument("--speed", type=float, default=1.0,
                    help="real-time runs: simulated seconds per wall second (default 1; 0.25 puts a quarter of "
                         "the load on the machine)")
    a = ap.parse_args()
    out = Path(tempfile.mkdtemp(prefix="swarm-bench-"))
    print(f"{os.cpu_count()} CPUs; runs of {a.duration:g} simulated s of paper-50hz (real time at speed {a.speed:g}); "
          f"logs in {out}")
    print(f"{'N':>4} {'launch s':>9} {'ticks/s':>8} {'rt median ms':>13} {'rt p99 ms':>10} {'robot CPU %':>12} "
          f"{'robot RSS MiB':>14} {'loop us':>8} {'converged':>10} {'collisions':>10}")
    for n in a.robots:
        ls, res = run(n, a.duration, "lockstep", out)
        rt, _ = run(n, a.duration, "realtime", out, a.speed)
        tps = ls["steps"] / ls["run_wall_s"]
        print(f"{n:>4} {ls['launch_s']:>9.2f} {tps:>8.1f} {rt.get('round_trip_ms_median', float('nan')):>13.2f} "
              f"{rt.get('round_trip_ms_p99', float('nan')):>10.2f} {res['cpu_pct']:>12.1f} "
              f"{res['rss_mean']:>6.1f}/{res['rss_max']:<7.1f} {loop_us(out / f'logs-realtime-{n}'):>8.0f} "
              f"{str(ls['converged_at_s']):>10} "
              f"{ls['collisions'] + rt['collisions']:>10}", flush=True)


if __name__ == "__main__":
    main()
