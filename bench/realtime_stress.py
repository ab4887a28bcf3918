"""Real time under stress: does any robot collide, strand or stall, whatever the load, latency, loss or deaths?

    python bench/realtime_stress.py                    # every cell, 3 runs each (about an hour on 2 cores)
    python bench/realtime_stress.py --cells base,hog2 --runs 1 --duration 60

Each cell changes one factor of the base (`swarm up --robots 19 --mode realtime`, speed 1, the built-in
paper-50hz, nothing else running) and runs it --runs times:

    base     the base
    n37      37 robots
    speed2   --speed 2
    hog1     one CPU hog beside the swarm (a busy Python process at the swarm's own priority: Linux's scheduler
             shares the cores by runnable thread, no cgroup; the bench says so)
    hog2     two CPU hogs
    delay01  every message 0.1-0.2 s late (a fault-bus delay rule: 5 periods plus 0-5 of jitter, class all)
    delay1   every message 1.0-1.2 s late (50 periods plus 0-10)
    loss10   10 % of every packet on the robots' links lost, each way (network namespaces, nftables or iptables;
             root), TCP's minimum retransmission timeout at 10 ms in every namespace (docs/deploy.md, Lossy links):
             zenoh's TCP sends them again, so it is delay too
    loss10d  the same with Linux's default minimum retransmission timeout (200 ms)
    kill3    robots 1, 3 and 5 get SIGKILL at t = 20 s (no fault table, no restart)
    cut      the even robots' namespace loses the router for 2 s at t = 20 s (root)

and prints, per cell: collisions (the goal is 0 in every run), runs converged and the median time, stranded
robots, the control round trip's p99 and how often the robots' safety rule held them back (medians over the
runs), the smallest robot distance, and the exit codes. --quota CORES puts the whole swarm in a cgroup (v1 cpu
controller, cfs quota) of that many cores instead (root). Not a test: it takes the machine for its whole run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.integration import netns  # noqa: E402
from swarm.launch.child import stop_group  # noqa: E402
from tests.integration.helpers import child_of, cpu_hogs, free_port, wait_for_ticks  # noqa: E402

SWARM = [sys.executable, "-m", "swarm.cli"]
CELLS = ("base", "n37", "speed2", "hog1", "hog2", "delay01", "delay1", "loss10", "loss10d", "kill3", "cut")
NAMESPACED = ("loss10", "loss10d", "cut")
RTO_MIN_MS = 10.0  # loss10's TCP minimum retransmission timeout, as docs/deploy.md asks of a lossy fleet
DELAYS = {"delay01": (5, 5), "delay1": (50, 10)}  # (periods, jitter)
KILLED = (1, 3, 5)
EVENT_AT_S = 20.0
CGROUP = Path("/sys/fs/cgroup/cpu/swarm-stress")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cells", default=",".join(CELLS), help=f"comma-separated, of: {', '.join(CELLS)}")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--robots", type=int, default=19, help="the base's robots (n37 takes 37)")
    ap.add_argument("--duration", type=float, default=120.0, help="simulated seconds a run")
    ap.add_argument("--quota", type=float, default=None, help="cores the swarm may use (a cgroup's cfs quota; root)")
    args = ap.parse_args()
    cells = [c.strip() for c in args.cells.split(",") if c.strip()]
    unknown = [c for c in cells if c not in CELLS]
    if unknown:
        ap.error(f"unknown cell(s) {', '.join(unknown)}: the cells are {', '.join(CELLS)}")
    print(f"machine: {platform.node()}, {os.cpu_count()} cores, {platform.python_implementation()} "
          f"{platform.python_version()}; load: " + (f"the swarm in a cgroup of {args.quota:g} cores" if args.quota
                                                      else "hogs are busy processes at the swarm's priority, no cgroup"))
    results = {}
    for cell in cells:
        why = _unavailable(cell, args)
        if why:
            print(f"{cell}: skipped ({why})", flush=True)
            continue
        runs = []
        for k in range(args.runs):
            t0 = time.monotonic()
            m, rc = run_cell(cell, args)
            runs.append((m, rc))
            print(f"{cell} run {k + 1}: exit {rc}, collisions {m.get('collisions')}, converged at "
                  f"{m.get('converged_at_s')}, stranded {m.get('stranded')}, p99 {_f(m.get('round_trip_ms_p99'))} ms, "
                  f"held {_pct(m.get('held_back'))}, min distance {_f(m.get('min_robot_distance_m'), 3)} m "
                  f"({time.monotonic() - t0:.0f} s)", flush=True)
        results[cell] = runs
    print()
    print("| cell | runs | collisions | converged (median s) | stranded | round trip p99 ms | held back | min distance m | exits |")
    print("|---|---|---|---|---|---|---|---|---|")
    for cell, runs in results.items():
        ms = [m for m, _ in runs]
        conv = [m["converged_at_s"] for m in ms if m.get("converged_at_s") is not None]
        p99 = [m["round_trip_ms_p99"] for m in ms if m.get("round_trip_ms_p99") is not None]
        held = [m["held_back"] for m in ms if m.get("held_back") is not None]
        dmin = [m["min_robot_distance_m"] for m in ms if m.get("min_robot_distance_m") is not None]
        print(f"| {cell} | {len(ms)} | {sum(m.get('collisions', 0) for m in ms)} | {len(conv)} of {len(ms)}"
              f"{f' ({statistics.median(conv):.1f})' if conv else ''} | {sum(len(m.get('stranded') or []) for m in ms)} | "
              f"{_f(statistics.median(p99)) if p99 else '-'} | {_pct(statistics.median(held)) if held else '-'} | "
              f"{_f(min(dmin), 3) if dmin else '-'} | {', '.join(str(rc) for _, rc in runs)} |")
    return 0


def _f(x, digits: int = 0) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _unavailable(cell: str, args) -> str | None:
    if cell in NAMESPACED or args.quota:
        if cell in NAMESPACED:
            why = netns.unavailable()
            if why:
                return why
            if netns.firewall() is None:
                return "needs nft or iptables"
        if args.quota and not CGROUP.parent.is_dir():
            return f"no cgroup v1 cpu controller at {CGROUP.parent}"
    return None


def run_cell(cell: str, args) -> tuple[dict, int]:
    """One run of a cell: its metrics and swarm up's (or the world's) exit code."""
    robots = 37 if cell == "n37" else args.robots
    speed = 2.0 if cell == "speed2" else 1.0
    tmp = Path(tempfile.mkdtemp(prefix=f"stress-{cell}-"))
    metrics = tmp / "metrics.json"
    common = ["--robots", str(robots), "--mode", "realtime", "--speed", f"{speed:g}", "--duration", f"{args.duration:g}",
              "--allow-violations"]
    if cell in NAMESPACED:
        return _in_namespaces(cell, tmp, robots, speed, args.duration), 0
    extra: list[str] = []
    if cell in DELAYS:
        ticks, jitter = DELAYS[cell]
        faults = tmp / "faults.toml"
        faults.write_text(f'[faults]\n[[faults.delay]]\nclass = "all"\nticks = {ticks}\njitter = {jitter}\n')
        extra = ["--faults", str(faults)]
    if cell == "kill3":
        extra = ["--restarts", "0"]
    cmd = [*SWARM, "up", *common, *extra, "--listen", f"tcp/127.0.0.1:{free_port()}", "--fleet", "stress",
           "--metrics", str(metrics), "--log-dir", str(tmp / "logs"), "--no-viz", "--quiet"]
    pre = _quota_prefix(args.quota)
    with cpu_hogs({"hog1": 1, "hog2": 2}.get(cell, 0)):
        proc = subprocess.Popen(pre + cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            if cell == "kill3":
                wait_for_ticks(cmd, "stress", int(EVENT_AT_S / 0.02), proc, timeout_s=300)
                for i in KILLED:
                    child_of(proc, "robot", i).kill()
            rc = proc.wait(timeout=args.duration / speed + 300)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(10)
    return (json.loads(metrics.read_text()) if metrics.exists() else {"failure": "no metrics"}), rc


def _quota_prefix(quota: float | None) -> list[str]:
    """A shell that moves itself into the quota cgroup and runs the command (its children inherit the group)."""
    if not quota:
        return []
    CGROUP.mkdir(exist_ok=True)
    (CGROUP / "cpu.cfs_period_us").write_text("100000")
    (CGROUP / "cpu.cfs_quota_us").write_text(str(int(quota * 100000)))
    return ["sh", "-c", f'echo $$ > {CGROUP}/cgroup.procs && exec "$@"', "sh"]


def _in_namespaces(cell: str, tmp: Path, robots: int, speed: float, duration: float) -> dict:
    """loss10, loss10d and cut: router, world and leader in a hub namespace, the robots in two others (even and odd ids),
    as tests/integration/test_netns.py runs them; loss10 (TCP's minimum retransmission timeout at RTO_MIN_MS) and
    loss10d (Linux's default) make both robot links lose 10 % of their packets for
    the whole run, cut drops everything on the even robots' link for 2 s at EVENT_AT_S."""
    tool = netns.firewall()
    metrics = tmp / "metrics.json"
    port = 7447
    scn = ["--scenario", "paper-50hz", "--robots", str(robots), "--duration", f"{duration:g}", "--mode", "realtime"]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    procs: list[subprocess.Popen] = []
    rto = RTO_MIN_MS if cell == "loss10" else None
    with netns.namespaces(watch=cell == "cut", rto_min_ms=rto) as (hub, a, b, a_if, b_if):
        def start(ns: str, *argv: str) -> subprocess.Popen:
            p = subprocess.Popen(["ip", "netns", "exec", ns, *SWARM, *argv], stdout=subprocess.DEVNULL,
                                 stderr=subprocess.DEVNULL, env=env, process_group=0)
            procs.append(p)
            return p

        if cell in ("loss10", "loss10d"):
            for ns, ifname in ((a, a_if), (b, b_if)):
                netns.lossy(ns, ifname, tool, 0.1, True)
        try:
            start(hub, "router", "--listen", f"tcp/0.0.0.0:{port}", "--fleet", "stress")
            local = ["--connect", f"tcp/127.0.0.1:{port}", "--fleet", "stress"]
            world = start(hub, "world", *scn, "--speed", f"{speed:g}", "--metrics", str(metrics), "--start-timeout",
                          "60", *local)
            start(hub, "leader", *scn, *local)
            for i in range(robots):
                ns, hub_ip = (a, "10.231.1.1") if i % 2 == 0 else (b, "10.231.2.1")
                start(ns, "robot", "--id", str(i), "--connect", f"tcp/{hub_ip}:{port}", "--fleet", "stress",
                      "--start-timeout", "60")
            if cell == "cut":
                wait_for_ticks(f"tcp/10.231.3.1:{port}", "stress", int(EVENT_AT_S / 0.02), world, timeout_s=300)
                netns.cut(a, a_if, tool, True)
                time.sleep(2.0)
                netns.cut(a, a_if, tool, False)
            world.wait(timeout=duration / speed + 300)
        finally:
            for p in procs:
                stop_group(p)
    return json.loads(metrics.read_text()) if metrics.exists() else {"failure": "no metrics"}


if __name__ == "__main__":
    sys.exit(main())
