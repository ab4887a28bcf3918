"""`swarm up` speed: launch, lock-step ticks per second, real-time round trip, CPU and RSS per robot.

    python bench/up_speed.py [--robots 7 19 37] [--duration 20] [--speed 1] [--rounds 3] [--floor]

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
  process us  real time: CPU of a robot's whole process (zenoh's threads too) per control period while its
              loop ran [us], the mean over robots (from their logs): what the loop figure cannot hide by
              moving work to another thread; the floor's beside it ("floor proc us")
  steal %     the share of this machine's CPU its host took during swarm's two runs (a VM's steal time,
              from /proc/stat): where it is high, the figures are the host's, not swarm's
  robots ran  "compiled" (the C message loops and law, swarm/proto/_wire.c and swarm/core/_law.c) or
              "Python": set SWARM_PURE_PYTHON=1 to measure the Python back to back
--floor runs bench/zenoh_floor.py (lock-step, lock-step with swarm's wait rule: "floor wait t/s", and real
time) after each round's two runs, so that swarm and its floor are measured back to back; --rounds 3 prints
the median of each column too (the README's figures).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarm.cli.console import cpu_counters, steal_pct  # noqa: E402


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
PROCESS_CPU = re.compile(r"process CPU (\d+) us a tick")


def logged_us(log_dir: Path, figure: re.Pattern) -> float:
    """Mean over the robots of a CPU figure per tick each logs at exit: LOOP_CPU (its loop thread's) or
    PROCESS_CPU (its whole process's)."""
    found = [float(m.group(1)) for f in log_dir.glob("robot-*.log") for m in figure.finditer(f.read_text())]
    return sum(found) / len(found) if found else float("nan")


RUNS_WITH = re.compile(r"law (compiled|Python), message loops (compiled|Python)")


def runs_with(log_dir: Path) -> str:
    """What the robots ran, from their logs: 'compiled', 'Python', or 'law X, codec Y' (SWARM_PURE_PYTHON, or
    a machine where setup.py found no compiler)."""
    seen = {m.groups() for f in log_dir.glob("robot-*.log") for m in RUNS_WITH.finditer(f.read_text())}
    if len(seen) != 1:
        return "mixed" if seen else "unknown"
    law, codec = seen.pop()
    return law if law == codec else f"law {law}, codec {codec}"


FLOOR_TICKS = re.compile(r"([\d.]+) ticks/s")
FLOOR_RT = re.compile(r"round trip median ([\d.]+) ms, p99 ([\d.]+) ms")
FLOOR_LOOP = re.compile(r"loop thread (\d+) us of CPU")
FLOOR_PROCESS = re.compile(r"the whole robot process (\d+) us")


def floor(n: int, duration: float) -> dict:
    """bench/zenoh_floor.py at N robots: lock-step ticks/s without and with swarm's wait rule (--wait), and the
    real-time round trip median and p99 [ms] and loop us."""
    me = Path(__file__).resolve().parent / "zenoh_floor.py"
    out = {"ticks": math.nan, "wait_ticks": math.nan, "median": math.nan, "p99": math.nan, "loop": math.nan,
           "process": math.nan}
    for mode, extra in (("lockstep", []), ("lockstep", ["--wait"]), ("realtime", [])):
        done = subprocess.run([sys.executable, str(me), "--robots", str(n), "--duration", str(duration), "--mode", mode,
                               *extra], capture_output=True, text=True, timeout=120 + 10 * duration)
        text = done.stdout
        if done.returncode != 0:  # said, and left out of the medians (nan), never taken for a figure
            print(f"bench/zenoh_floor.py --mode {mode} {' '.join(extra)} failed (exit {done.returncode}): "
                  f"{done.stderr.strip()[-400:]}", file=sys.stderr)
            continue
        if mode == "lockstep":
            out["wait_ticks" if extra else "ticks"] = float(FLOOR_TICKS.search(text).group(1))
        else:
            m = FLOOR_RT.search(text)
            out["median"], out["p99"] = float(m.group(1)), float(m.group(2))
            out["loop"] = float(FLOOR_LOOP.search(text).group(1))
            out["process"] = float(FLOOR_PROCESS.search(text).group(1))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, nargs="+", default=[7, 19, 37])
    ap.add_argument("--duration", type=float, default=20.0, help="simulated seconds per run (default 20)")
    ap.add_argument("--speed", type=float, default=1.0,
                    help="real-time runs: simulated seconds per wall second (default 1; 0.25 puts a quarter of "
                         "the load on the machine)")
    ap.add_argument("--rounds", type=int, default=1, help="rounds per N; with more than one, the medians too")
    ap.add_argument("--floor", action="store_true",
                    help="each round also runs bench/zenoh_floor.py (both modes, and lock-step with the wait rule) "
                         "right after swarm's runs")
    a = ap.parse_args()
    if a.rounds < 1:
        ap.error("--rounds must be at least 1")
    out = Path(tempfile.mkdtemp(prefix="swarm-bench-"))
    print(f"{os.cpu_count()} CPUs; runs of {a.duration:g} simulated s of paper-50hz (real time at speed {a.speed:g}); "
          f"logs in {out}")
    cols = ("launch s", "ticks/s", "rt median ms", "rt p99 ms", "robot CPU %", "RSS mean", "RSS max", "loop us",
            "process us")
    fcols = ("floor ticks/s", "floor wait t/s", "floor median", "floor p99", "floor loop us", "floor proc us") \
        if a.floor else ()
    print(f"{'N':>4} {'round':>5} " + " ".join(f"{c:>13}" for c in cols + fcols + ("steal %",)) +
          f" {'converged':>10} {'collisions':>10}  robots ran")
    for n in a.robots:
        rows = []
        for r in range(a.rounds):
            (out / f"r{r}").mkdir(exist_ok=True)
            c0 = cpu_counters()
            ls, res = run(n, a.duration, "lockstep", out / f"r{r}")
            rt, _ = run(n, a.duration, "realtime", out / f"r{r}", a.speed)
            stolen = steal_pct(c0, cpu_counters())
            stolen = math.nan if stolen is None else stolen
            row = [ls["launch_s"], ls["steps"] / ls["run_wall_s"], rt.get("round_trip_ms_median", float("nan")),
                   rt.get("round_trip_ms_p99", float("nan")), res["cpu_pct"], res["rss_mean"], res["rss_max"],
                   logged_us(out / f"r{r}" / f"logs-realtime-{n}", LOOP_CPU),
                   logged_us(out / f"r{r}" / f"logs-realtime-{n}", PROCESS_CPU)]
            if a.floor:
                f = floor(n, a.duration)
                row += [f["ticks"], f["wait_ticks"], f["median"], f["p99"], f["loop"], f["process"]]
            rows.append(row)
            row.append(stolen)
            print(f"{n:>4} {r + 1:>5} " + " ".join(f"{v:>13.2f}" for v in row) +
                  f" {str(ls['converged_at_s']):>10} {ls['collisions'] + rt['collisions']:>10}"
                  f"  {runs_with(out / f'r{r}' / f'logs-realtime-{n}')}", flush=True)
        if a.rounds > 1:
            med = [statistics.median(v for v in col if not math.isnan(v)) if any(not math.isnan(v) for v in col)
                   else math.nan for col in zip(*rows)]
            print(f"{n:>4} {'med':>5} " + " ".join(f"{v:>13.2f}" for v in med), flush=True)


if __name__ == "__main__":
    main()
