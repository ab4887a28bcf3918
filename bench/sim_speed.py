"""Speed and memory of the in-process simulator (`swarm sim`).

    python bench/sim_speed.py            # all cases (two or three minutes)
    python bench/sim_speed.py --quick    # shorter runs for the large swarms
    python bench/sim_speed.py --write    # and write its section of docs/results.md

Prints, per case: wall time of the run, simulated seconds per wall second, nanoseconds a robot-step, the
threads the kernel ran on (swarm.core.sim: the parallel kernel from 256 robots), peak RSS of the process,
and the slope of log(wall time per simulated second) against log(N). Each case runs in a fresh subprocess
(so peak memory is its own), the scaling rows and the whole runs twice (the faster counts: this VM's
speed drifts). The first row runs with an empty kernel cache to show what compiling costs and what the
cache saves.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time

from results_doc import machine, write_section

CASE = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from swarm.core import scenario_file as sf
from swarm.core.sim import Simulation
name, n, duration = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
scn = sf.load(name, sf.Overrides(robots=n, duration=duration, seed=0))
t1 = time.perf_counter()
sim = Simulation(scn)
t2 = time.perf_counter()
m = sim.run().metrics
t3 = time.perf_counter()
print(json.dumps({"import_and_load_s": t1 - t0, "setup_s": t2 - t1, "run_s": t3 - t2, "total_s": t3 - t0,
                  "threads": int(sim.scratch[0].shape[0]), "steps": int(m["steps"]) + 1, "dt": scn.dt,
                  "builds": int(sim.iacc[sim.k.I_BUILDS]),
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "sim_s": m["duration_s"], "converged_at_s": m["converged_at_s"], "collisions": m["collisions"]}))
"""


def run_case(name: str, n: int, duration: float, env: dict | None = None) -> dict:
    out = subprocess.run([sys.executable, "-c", CASE, name, str(n), str(duration)], capture_output=True, text=True,
                         env=env, check=True, timeout=1800)
    return json.loads(out.stdout.strip().splitlines()[-1])


def best_case(name: str, n: int, duration: float, runs: int = 2) -> dict:
    return min((run_case(name, n, duration) for _ in range(runs)), key=lambda r: r["run_s"])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="10 s runs for N >= 100 instead of 20 s")
    ap.add_argument("--write", action="store_true", help="write the figures to docs/results.md (section sim-speed)")
    args = ap.parse_args()
    big = 10.0 if args.quick else 20.0
    out: list[str] = []

    def say(line: str = "") -> None:
        print(line)
        out.append(line)

    say(f"machine: {machine()}")
    with tempfile.TemporaryDirectory() as cache:
        cold = run_case("paper", 37, 120.0, env={**os.environ, "SWARM_CACHE_DIR": cache})
    best = best_case("paper", 37, 120.0)
    say("")
    say("37-robot paper run (120 s simulated, dt = 0.001 s, 120 000 steps):")
    say("")
    say("| | run | whole command |")
    say("|---|---:|---:|")
    say(f"| first run (empty cache) | {cold['run_s']:.2f} s | {cold['total_s']:.2f} s |")
    say(f"| cached kernel | {best['run_s']:.2f} s | {best['total_s']:.2f} s |")
    say("")
    say(f"Compiling once: {cold['total_s'] - best['total_s']:.1f} s, saved by the cache on every later run.")

    # The scaling rows all simulate the same first `big` seconds (the crowded part of a run:
    # every robot still moving through the barrier), so the slope compares like with like.
    rows = []
    for n in (37, 100, 300, 1000):
        r = best_case("paper", n, big)
        rows.append((n, r["run_s"] / r["sim_s"], r))
    say("")
    say(f"The first {big:g} simulated s of the scaled paper run (dt = 0.001 s: every robot still crossing the "
        "barrier, the most crowded part):")
    say("")
    say("| N | sim s | wall s | sim s / wall s | us a step | ns a robot-step | threads | steps a list build | "
        "peak RSS |")
    say("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n, per_s, r in rows:
        us = 1e6 * r["run_s"] / r["steps"]
        say(f"| {n} | {r['sim_s']:.1f} | {r['run_s']:.2f} | {1 / per_s:.1f} | {us:.1f} | {1e3 * us / n:.0f} | "
            f"{r['threads']} | {r['steps'] / max(1, r['builds']):.0f} | {r['peak_rss_mib']:.0f} MiB |")
    xs = [math.log(n) for n, _, _ in rows]
    ys = [math.log(per_s) for _, per_s, _ in rows]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
    say("")
    say(f"Slope of log(wall time) against log(N), N = 37..1000 (equal {big:g} s runs): {slope:.2f}.")

    say("")
    say("Whole runs of 1000 robots (120 simulated s):")
    say("")
    say("| scenario | dt | wall s | sim s / wall s | ns a robot-step | threads | steps a list build | converged at | "
        "collisions |")
    say("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name in ("paper", "paper-50hz"):
        r = best_case(name, 1000, 120.0)
        ns = 1e9 * r["run_s"] / r["steps"] / 1000
        conv = "-" if r["converged_at_s"] is None else f"{r['converged_at_s']:g} s"
        say(f"| {name} | {r['dt']:g} s | {r['run_s']:.2f} | {r['sim_s'] / r['run_s']:.1f} | {ns:.0f} | "
            f"{r['threads']} | {r['steps'] / max(1, r['builds']):.0f} | {conv} | {r['collisions']} |")
    if args.write:
        write_section("sim-speed", "\n".join(["## The simulator's speed", "",
                                               "Written by `python bench/sim_speed.py --write`.", "", *out]))
        print("\nwritten: docs/results.md (section sim-speed)")
    return 0


if __name__ == "__main__":
    t = time.perf_counter()
    rc = main()
    print(f"(benchmark took {time.perf_counter() - t:.0f} s)")
    sys.exit(rc)
