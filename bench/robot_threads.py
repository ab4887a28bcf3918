"""Where a robot process's CPU goes by thread, and how often each thread wakes, in a real `swarm up` run.

    python bench/robot_threads.py [--robots 37] [--duration 30] [--mode lockstep|realtime] [--window 10]

Starts `swarm up --no-viz` (its own port and fleet), waits --window/2 s past the launch, then reads
/proc/PID/task/*/{stat,status} of one robot process (the middle id) at the start and end of a --window s
window: each thread's CPU and its voluntary context switches (its wake-ups: the loop thread is the
process's main thread, zenoh's are app-0 and app-1). With the run's ticks per second (lock-step: from
its metrics) it prints the CPU and wake-ups a tick. docs/performance.md compares
them with a floor robot's (bench/zenoh_floor.py).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil


def threads(pid: int) -> dict[str, tuple[float, int]]:
    """Thread name -> (CPU [s], voluntary context switches) of every thread of pid (same names summed)."""
    out: dict[str, tuple[float, int]] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
            name = stat[stat.index("(") + 1:stat.rindex(")")]
            f = stat[stat.rindex(")") + 2:].split()
            cpu = (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
            vol = next(int(line.split()[1]) for line in (task / "status").read_text().splitlines()
                       if line.startswith("voluntary_ctxt_switches"))
        except (OSError, ValueError, StopIteration):
            continue  # the thread ended meanwhile
        c, v = out.get(name, (0.0, 0))
        out[name] = (c + cpu, v + vol)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=37)
    ap.add_argument("--duration", type=float, default=30.0, help="simulated seconds of the run (default 30)")
    ap.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    ap.add_argument("--window", type=float, default=10.0, help="wall seconds sampled (default 10)")
    a = ap.parse_args()
    if a.robots < 1 or a.duration <= 0 or a.window <= 0:
        ap.error("--robots, --duration and --window must be positive")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    tmp = Path(tempfile.mkdtemp(prefix="robot-threads-"))
    metrics = tmp / "metrics.json"
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--robots", str(a.robots), "--duration", str(a.duration),
           "--mode", a.mode, "--listen", f"tcp/127.0.0.1:{port}", "--fleet", f"threads{port}", "--metrics",
           str(metrics), "--log-dir", str(tmp / "logs"), "--no-viz", "--quiet"]
    proc = subprocess.Popen(cmd, start_new_session=True)
    me = a.robots // 2
    try:
        pid, end = None, time.monotonic() + 120
        while pid is None and time.monotonic() < end and proc.poll() is None:
            for c in psutil.Process(proc.pid).children(recursive=True):
                try:
                    argv = c.cmdline()
                except psutil.Error:
                    continue
                if "robot" in argv and "--id" in argv and argv[argv.index("--id") + 1] == str(me):
                    pid = c.pid
            time.sleep(0.2)
        if pid is None:
            sys.exit("robot_threads: robot process not found (did swarm up start?)")
        while not any(f.name.startswith("robot-") for f in (tmp / "logs").glob("*")) and time.monotonic() < end:
            time.sleep(0.2)
        time.sleep(5.0 + a.window / 2)  # past the launch and the start barrier
        t0, before = time.monotonic(), threads(pid)
        time.sleep(a.window)
        wall, after = time.monotonic() - t0, threads(pid)
        proc.wait(timeout=600 + 20 * a.duration)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 9)
            proc.wait(timeout=10)
    m = json.loads(metrics.read_text())
    rate = m["steps"] / m["run_wall_s"] if a.mode == "lockstep" else 1.0 / m["dt"]
    ticks = rate * wall
    what = "tick" if a.mode == "lockstep" else "period"
    print(f"robot {me} of {a.robots}, {a.mode}, {wall:.1f} s window at {rate:.1f} {what}s/s "
          f"(the host took {m.get('host_steal_pct')} % of the CPU over the run):")
    for name in sorted(after):
        if name not in before:
            continue
        cpu, vol = after[name][0] - before[name][0], after[name][1] - before[name][1]
        if cpu <= 0 and vol <= 0:
            continue
        print(f"  {name:<16} CPU {1e6 * cpu / ticks:7.0f} us a {what}, {vol / ticks:5.2f} wake-ups a {what}"
              + (f", {1e6 * cpu / vol:5.0f} us a wake-up" if vol else ""))


if __name__ == "__main__":
    main()
