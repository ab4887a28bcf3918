"""What `swarm up` takes to start N robot processes: launch time and memory a process, as N grows.

    python bench/launch_scale.py [--robots 7,100,200] [--duration 300]

For each N it starts a lock-step `swarm up --robots N --no-viz` on a free loopback port, waits for the line
"all ... processes alive after X s" (robots start in waves, swarm.launch.capacity.Waves), then reads each of its
processes' own memory (Private_Dirty of /proc/PID/smaps_rollup) and how much MemAvailable (/proc/meminfo) went
down since before the start, and stops the run with Ctrl-C (SIGINT). Figures:
  launch       the seconds `swarm up` reports, from the first process started to every liveliness token seen
  robot MiB    a robot process's own memory (median over the robots)
  router MiB, world MiB   the same for the router and the world
  taken MiB    how much less memory the machine had available with the swarm up, a process (the whole cost:
               private memory, page tables, the kernel's share), the figure swarm.launch.capacity.ROBOT_MIB uses
Linux only. Lock-step waits for its robots, so the figures do not depend on how fast the run goes.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ALIVE = re.compile(r"all (\d+) processes alive after ([0-9.]+) s")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def available_mib() -> float:
    with open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no MemAvailable in /proc/meminfo")


def private_mib(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/smaps_rollup") as f:
            for line in f:
                if line.startswith("Private_Dirty:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def role_of(pid: int) -> str | None:
    """`robot`, `router`, `world`, `leader` from a child's command line (python -m swarm.cli ROLE ...)."""
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    words = [a.decode(errors="replace") for a in argv]
    if "swarm.cli" in words:
        i = words.index("swarm.cli")
        return words[i + 1] if i + 1 < len(words) else None
    return None


def children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(d.name))
    return out


def measure(n: int, duration: float) -> dict:
    before = available_mib()
    log_dir = Path(tempfile.mkdtemp(prefix=f"launch-{n}-"))
    cmd = [sys.executable, "-m", "swarm.cli", "up", "--robots", str(n), "--no-viz", "--duration", str(duration),
           "--listen", f"tcp/127.0.0.1:{free_port()}", "--fleet", f"scale{n}", "--log-dir", str(log_dir),
           "--start-timeout", "120"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    launch = None
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            m = ALIVE.search(line)
            if m:
                launch = float(m.group(2))
                break
        if launch is None:
            return {"n": n, "failed": f"swarm up ended before every process was alive (logs in {log_dir})"}
        time.sleep(2.0)  # let the first ticks allocate what a running process holds
        taken = before - available_mib()
        by_role: dict[str, list[float]] = {}
        for pid in children(proc.pid):
            role, mib = role_of(pid), private_mib(pid)
            if role is not None and mib is not None:
                by_role.setdefault(role, []).append(mib)
        procs = sum(len(v) for v in by_role.values()) + 1  # and the launcher
        return {"n": n, "launch_s": launch, "robot_mib": statistics.median(by_role.get("robot", [0.0])),
                "router_mib": max(by_role.get("router", [0.0])), "world_mib": max(by_role.get("world", [0.0])),
                "taken_mib": taken / procs, "procs": procs}
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robots", default="7,100,200", help="comma-separated robot counts")
    p.add_argument("--duration", type=float, default=300.0, help="simulated s a run may last (it is stopped once "
                                                                 "measured)")
    args = p.parse_args()
    print(f"{'N':>5} {'launch s':>9} {'robot MiB':>10} {'router MiB':>11} {'world MiB':>10} {'taken MiB a process':>20}")
    for n in (int(x) for x in args.robots.split(",")):
        r = measure(n, args.duration)
        if "failed" in r:
            print(f"{n:>5} {r['failed']}")
            continue
        print(f"{n:>5} {r['launch_s']:>9.2f} {r['robot_mib']:>10.1f} {r['router_mib']:>11.1f} {r['world_mib']:>10.1f} "
              f"{r['taken_mib']:>20.1f}")


if __name__ == "__main__":
    main()
