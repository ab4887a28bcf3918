"""The acceptance tables of the paper experiment, written to docs/results.md.

    python bench/paper_table.py                 # seeds 0-9 tables + jam rate over 100 seeds
    python bench/paper_table.py --jam-seeds 20  # a quicker jam estimate

For `paper` (dt = 0.001 s, governor off) and `paper-50hz` (dt = 0.02 s, governor on),
one row per seed 0-9 with the metrics of docs/metrics.md, then the jam rate: the
share of seeds (0 .. J-1) not converged by the end of the 120 s run. Runs are spread
over the machine's cores (spawned processes, each with the compiled kernel).
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time
from pathlib import Path

from results_doc import write_section


def run_one(job: tuple[str, int]) -> dict:
    from swarm.core import scenario_file as sf
    from swarm.core.sim import Simulation

    name, seed = job
    m = Simulation(sf.load(name, sf.Overrides(seed=seed))).run().metrics
    m["scenario"] = name
    return m


def fmt(x, digits=3) -> str:
    if x is None:
        return "—"
    if isinstance(x, float):
        return f"{x:.{digits}g}" if abs(x) < 1e-3 and x != 0 else f"{x:.{digits}f}".rstrip("0").rstrip(".")
    return str(x)


def seed_table(rows: list[dict], conv_limit: float, check_errors: bool) -> list[str]:
    out = ["| seed | converged at [s] | final position error [m] | final orientation error [rad] "
           "| min robot distance [m] | min obstacle distance [m] | collisions | last freeze end [s] | pass |",
           "|---:|---:|---:|---:|---:|---:|---:|---:|:---:|"]
    for m in rows:
        conv = m["converged_at_s"]
        ok = m["collisions"] == 0 and conv is not None and conv <= conv_limit
        if check_errors:
            ok = ok and m["final_position_error_max_m"] < 1e-9 and m["final_orientation_error_max_rad"] < 1e-9
            ok = ok and m["min_robot_distance_m"] > 0.4
        out.append(f"| {m['seed']} | {fmt(conv, 2)} | {m['final_position_error_max_m']:.2e} "
                   f"| {m['final_orientation_error_max_rad']:.2e} | {fmt(m['min_robot_distance_m'])} "
                   f"| {fmt(m['min_obstacle_distance_m'])} | {m['collisions']} | {fmt(m['last_freeze_end_s'], 1)} "
                   f"| {'yes' if ok else 'no'} |")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--jam-seeds", type=int, default=100, help="seeds for the jam rate (default 100)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent.parent / "docs" / "results.md")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args()

    from swarm.core import kernel  # noqa: F401  compile once before spawning workers

    started = time.perf_counter()
    jobs = [(name, s) for name in ("paper", "paper-50hz") for s in range(max(10, args.jam_seeds))]
    results: dict[tuple[str, int], dict] = {}
    with mp.get_context("spawn").Pool(args.jobs) as pool:
        for i, m in enumerate(pool.imap_unordered(run_one, jobs), 1):
            results[(m["scenario"], m["seed"])] = m
            print(f"\r{i}/{len(jobs)} runs", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    wall = time.perf_counter() - started

    lines = ["## The paper experiment", "",
             "Written by `python bench/paper_table.py`. Metrics as in docs/metrics.md; "
             "errors are against the live leader reference at t = 120 s.", ""]
    for name, limit, errs, text in (
        ("paper", 60.0, True, "dt = 0.001 s, governor off. Pass: no collision, smallest robot distance > 0.4 m, "
                              "converged by 60 s, final errors < 1e-9 (acceptance: at least 9 of 10)."),
        ("paper-50hz", 90.0, False, "dt = 0.02 s, safety governor on. Pass: no collision, converged by 90 s "
                                    "(acceptance: at least 9 of 10)."),
    ):
        rows = [results[(name, s)] for s in range(10)]
        passed = sum(1 for line in seed_table(rows, limit, errs)[2:] if line.endswith("yes |"))
        lines += [f"### `{name}`, seeds 0-9", "", text, "", *seed_table(rows, limit, errs), "",
                  f"{passed} of 10 pass.", ""]
    lines += [f"### Jam rate over seeds 0-{args.jam_seeds - 1}", "",
              "A run jams when it has not converged by the end of the 120 s run (a robot trapped inside the "
              "moving formation stays frozen: the paper's rare saddle points).", "",
              "| scenario | runs | not converged by 120 s | jam rate | collisions (runs with any) | "
              "median converged at [s] | worst min robot distance [m] |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name in ("paper", "paper-50hz"):
        rows = [results[(name, s)] for s in range(args.jam_seeds)]
        jams = [m["seed"] for m in rows if m["converged_at_s"] is None]
        coll = sum(1 for m in rows if m["collisions"])
        conv = sorted(m["converged_at_s"] for m in rows if m["converged_at_s"] is not None)
        med = conv[len(conv) // 2] if conv else None
        worst = min(m["min_robot_distance_m"] for m in rows)
        lines.append(f"| `{name}` | {len(rows)} | {len(jams)}{' (seeds ' + ', '.join(map(str, jams)) + ')' if jams else ''}"
                     f" | {100 * len(jams) / len(rows):.0f} % | {coll} | {fmt(med, 2)} | {fmt(worst)} |")
    lines += ["", f"{len(jobs)} runs in {wall:.0f} s of wall time on {args.jobs} processes "
                  f"({os.cpu_count()} cpus).", ""]
    write_section("paper", "\n".join(lines), args.out)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
