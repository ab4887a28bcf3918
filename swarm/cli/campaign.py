"""`swarm campaign`: `swarm sim` over a grid of seeds and drop probabilities, on every core.

    swarm campaign --scenario paper-50hz --seeds 0-9 --drop 0,0.1,0.3 -o out/
    swarm campaign --scenario my.toml --seeds 0-4 --faults kills.toml --drop 0,0.2 -j 2 -o out/

The grid is every p of --drop times every seed of --seeds. A run's seed sets run.seed, and with it the
faults' seed unless the faults name their own (swarm.core.scenario_file does that); p adds one drop rule
of class "all" to the faults of the scenario, or of --faults FILE, which replaces them (p = 0: no rule,
the baseline; --drop left out means --drop 0). Every grid point is resolved in this process first, so
bad input is refused (exit 2) before anything runs. The runs are Simulation(scenario).run() in a pool of
-j spawned workers, each compiled kernel loaded from the cache the parent filled.

Written into DIR (docs/faults.md, Campaigns):
- runs.csv: one row a run in grid order (drop, then seed): scenario, seed, drop, every metric (the
  "faults" object flattened as faults.dropped.state, ...), failure; the wall-clock columns last, named
  wallclock.*;
- summary.csv: one row per p (collided, converged, failed runs; medians and extremes over seeds);
- convergence.png, distance.png, error.png and index.html (swarm.view.campaign).
Apart from the wallclock.* columns, the same command writes the same files.

Exit code: 3 when a run failed a check of the metrics contract (a collision), naming the runs (0 with
--allow-violations); 1 when a run could not finish (a non-finite state); 130 interrupted (the files
then hold the runs done); else 0. A run that did not converge is reported, not a failure.
"""

from __future__ import annotations

import argparse
import csv
import multiprocessing as mp
import os
import queue
import shlex
import signal
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from swarm.cli import console
from swarm.cli.common import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, BadInput, StopEvent

EXIT_VIOLATIONS = 3
WALL_CLOCK = ("wall_s",)  # metric keys that differ from one run of the same command to the next


@dataclass(frozen=True)
class Point:
    """One run of the grid: its place in grid order, its seed and its drop probability (0: no rule)."""

    index: int
    seed: int
    drop: float


def grid(seeds: tuple[int, ...], drops: tuple[float, ...]) -> list[Point]:
    """Every (drop, seed) in grid order: drops as given, seeds as given within each."""
    return [Point(i, s, p) for i, (p, s) in enumerate((p, s) for p in drops for s in seeds)]


def overrides(args: argparse.Namespace, point: Point):
    """The scenario_file.Overrides of one run: the scenario flags, the point's seed and drop rule."""
    from swarm.core.scenario_file import Overrides

    return Overrides(robots=args.robots, seed=point.seed, duration=args.duration, dt=args.dt, governor=args.governor,
                     faults=None if args.faults is None else str(Path(args.faults).absolute()),
                     drop=point.drop if point.drop > 0 else None, kill=args.kill)


def replay_command(args: argparse.Namespace, point: Point) -> str:
    """The `swarm sim` command line that runs one grid point alone (the same metrics)."""
    out = ["swarm", "sim", "--scenario", args.scenario, "--seed", str(point.seed)]
    out += _scenario_flags(args)
    if point.drop > 0:
        out += ["--drop", repr(point.drop)]
    return shlex.join(out)


def campaign_command(args: argparse.Namespace) -> str:
    """This campaign's command line, every flag spelled out (for index.html)."""
    out = ["swarm", "campaign", "--scenario", args.scenario, "--seeds", _seeds_text(args.seeds),
           "--drop", ",".join(repr(p) for p in args.drop), *_scenario_flags(args), "-j", str(args.jobs),
           "-o", str(args.out)]
    if args.allow_violations:
        out.append("--allow-violations")
    return shlex.join(out)


def _scenario_flags(args: argparse.Namespace) -> list[str]:
    out = []
    for flag, value in (("--robots", args.robots), ("--duration", args.duration), ("--dt", args.dt)):
        if value is not None:
            out += [flag, repr(value) if isinstance(value, float) else str(value)]
    if args.governor is not None:
        out.append("--governor" if args.governor else "--no-governor")
    if args.faults is not None:
        out += ["--faults", str(args.faults)]
    if args.kill is not None:
        out += ["--kill", args.kill]
    return out


def _seeds_text(seeds: tuple[int, ...]) -> str:
    if len(seeds) > 1 and list(seeds) == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


# --------------------------------------------------------------------------- the workers


def run_point(task: tuple[int, str, object]) -> tuple[int, dict | None, str | None]:
    """One run: (index, metrics, None), or (index, None, why) when it could not finish."""
    from swarm.core import scenario_file
    from swarm.core.scenario import ScenarioError
    from swarm.core.sim import Simulation, SimulationError

    index, source, ov = task
    try:
        scn = scenario_file.load(source, ov, progress=scenario_file.silent)
        return index, Simulation(scn).run().metrics, None
    except (SimulationError, ScenarioError) as e:
        return index, None, str(e)
    except Exception as e:  # anything else ends this run, not the campaign: it is reported with the run
        return index, None, f"{type(e).__name__}: {e}"


def _worker(tasks, results) -> None:
    """A worker process: runs tasks until it takes None, saying which run it starts. Ctrl-C is the
    parent's: it stops the workers itself (no traceback from every worker)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while True:
        task = tasks.get()
        if task is None:
            return
        results.put(("start", task[0], os.getpid()))
        results.put(("done", *run_point(task)))


def _run_all(tasks: list, jobs: int, results: dict, stop, show) -> bool:
    """Run every task in `jobs` spawned worker processes, filling results[index] = (metrics, why);
    show() after each result and at least every 0.25 s. A worker that dies takes its run with it (the
    run is reported failed with the exit code) and is replaced. Returns True when stopped early (stop
    set): the workers are then terminated. Every worker this starts has ended when it returns."""
    ctx = mp.get_context("spawn")
    todo, done = ctx.Queue(), ctx.Queue()
    for t in tasks:
        todo.put(t)
    for _ in range(jobs):
        todo.put(None)  # one end mark a worker; a worker that dies leaves its mark to its replacement
    procs = []
    running: dict[int, int] = {}  # worker pid -> the index of the run it does

    def start() -> None:
        p = ctx.Process(target=_worker, args=(todo, done), daemon=True, name="swarm-campaign-worker")
        p.start()
        procs.append(p)

    try:
        for _ in range(jobs):
            start()
        while len(results) < len(tasks):
            if stop.is_set():
                return True
            try:
                msg = done.get(timeout=0.25)
            except queue.Empty:
                for p in list(procs):
                    if p.exitcode not in (None, 0):
                        procs.remove(p)
                        index = running.pop(p.pid, None)
                        if index is not None:
                            results[index] = (None, f"its worker process died (exit code {p.exitcode})")
                        start()
                show()
                continue
            if msg[0] == "start":
                running[msg[2]] = msg[1]
                continue
            _, index, m, why = msg
            results[index] = (m, why)
            running = {pid: i for pid, i in running.items() if i != index}
            show()
        return False
    finally:
        for p in procs:
            if p.is_alive():
                p.terminate()
        for p in procs:
            p.join(10)
        todo.close()
        done.close()
        todo.cancel_join_thread()
        done.cancel_join_thread()


# --------------------------------------------------------------------------- rows


def flatten(m: dict, prefix: str = "") -> dict:
    """Nested objects as dotted keys: {"faults": {"dropped": {"state": 3}}} -> {"faults.dropped.state": 3}."""
    out = {}
    for k, v in m.items():
        if isinstance(v, dict):
            out.update(flatten(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def run_row(name: str, point: Point, metrics: dict | None, failure: str | None) -> dict:
    """A row of runs.csv as a dict: the grid values, every metric (flattened), the failure (None: finished)."""
    row = {"scenario": name, "seed": point.seed, "drop": point.drop}
    for k, v in flatten(metrics or {}).items():
        if k not in row:
            row[k] = v
    row["failure"] = failure
    return row


def columns(rows: list[dict]) -> list[str]:
    """runs.csv's columns: the union of the rows' keys, each new key right after the one before it in the
    first row that has it (a run without faults has no faults.* keys), the wall-clock keys last."""
    cols: list[str] = []
    for row in rows:
        prev = None
        for k in row:
            if k not in cols:
                cols.insert(cols.index(prev) + 1 if prev is not None else 0, k)
            prev = k
    wall = [k for k in cols if k in WALL_CLOCK]
    return [k for k in cols if k not in WALL_CLOCK] + [f"wallclock.{k}" for k in wall]


def _wall_named(row: dict) -> dict:
    return {(f"wallclock.{k}" if k in WALL_CLOCK else k): v for k, v in row.items()}


def _median(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return float(statistics.median(values)) if values else None


def _least(values: list):
    values = [v for v in values if v is not None]
    return min(values) if values else None


def _most(values: list):
    values = [v for v in values if v is not None]
    return max(values) if values else None


SUMMARY_COLUMNS = (
    "scenario", "drop", "runs", "collided_runs", "collisions", "converged_runs", "not_converged_runs",
    "failed_runs", "converged_at_s_median", "converged_at_s_min", "converged_at_s_max", "min_robot_distance_m_min",
    "min_robot_distance_m_median", "min_obstacle_distance_m_min", "final_position_error_max_m_median",
    "final_position_error_max_m_max", "final_orientation_error_max_rad_median", "last_freeze_end_s_max",
    "messages_dropped_median", "robots_alive_at_end_min", "wallclock.wall_s_median", "wallclock.wall_s_total",
)


def summary(rows: list[dict]) -> list[dict]:
    """summary.csv's rows: one per drop probability, in grid order (SUMMARY_COLUMNS)."""
    out = []
    drops = list(dict.fromkeys(r["drop"] for r in rows))
    for p in drops:
        rs = [r for r in rows if r["drop"] == p]
        done = [r for r in rs if r["failure"] is None]
        col = lambda key: [r.get(key) for r in done]  # noqa: E731
        out.append({
            "scenario": rs[0]["scenario"], "drop": p, "runs": len(rs),
            "collided_runs": sum(1 for r in done if r["collisions"]),
            "collisions": sum(r["collisions"] for r in done),
            "converged_runs": sum(1 for r in done if r["converged_at_s"] is not None),
            "not_converged_runs": sum(1 for r in done if r["converged_at_s"] is None),
            "failed_runs": len(rs) - len(done),
            "converged_at_s_median": _median(col("converged_at_s")),
            "converged_at_s_min": _least(col("converged_at_s")),
            "converged_at_s_max": _most(col("converged_at_s")),
            "min_robot_distance_m_min": _least(col("min_robot_distance_m")),
            "min_robot_distance_m_median": _median(col("min_robot_distance_m")),
            "min_obstacle_distance_m_min": _least(col("min_obstacle_distance_m")),
            "final_position_error_max_m_median": _median(col("final_position_error_max_m")),
            "final_position_error_max_m_max": _most(col("final_position_error_max_m")),
            "final_orientation_error_max_rad_median": _median(col("final_orientation_error_max_rad")),
            "last_freeze_end_s_max": _most(col("last_freeze_end_s")),
            "messages_dropped_median": _median(col("messages_dropped")),
            "robots_alive_at_end_min": _least(col("robots_alive_at_end")),
            "wallclock.wall_s_median": _median(col("wall_s")),
            "wallclock.wall_s_total": sum(v for v in col("wall_s") if v is not None),
        })
    return out


def _text(v) -> str:
    """A CSV cell: empty for None, true/false, floats as Python writes them (they read back exactly)."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def write_csv(path: Path, cols: list[str] | tuple[str, ...], rows: list[dict]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(cols)
        for r in rows:
            w.writerow([_text(r.get(c)) for c in cols])
    tmp.replace(path)


# --------------------------------------------------------------------------- the command


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise BadInput(f"-o {out}: exists and is not a directory")
    if not out.exists() and not out.parent.is_dir():
        raise BadInput(f"-o {out}: directory {out.parent} does not exist")


def _resolve_grid(args: argparse.Namespace, points: list[Point]):
    """Load every seed (at the first p) and every p (at the first seed): every file, flag, seed and drop
    rule is checked before a run starts (ScenarioError: exit 2). Returns those scenarios (the first
    point's first) and the advisories about them, each once."""
    from swarm.core import scenario_file

    first = points[0]
    checks = [Point(first.index, s, first.drop) for s in args.seeds]
    checks += [Point(first.index, first.seed, p) for p in args.drop[1:]]
    scns = [scenario_file.load(args.scenario, overrides(args, pt), progress=scenario_file.silent) for pt in checks]
    notes = []
    for scn in scns:
        notes += [n for n in scenario_file.advisories(scn) if n not in notes]
    return scns, notes


def _warm_kernels(scns, quiet: bool) -> None:
    """Compile (or load) every kernel the runs need here, once, so the workers load it from the cache
    instead of each compiling it: the plain kernel, and the fault kernel when a run has faults."""
    from swarm.core import jit
    from swarm.core.sim import Simulation

    cache = jit.cache_dir()
    if not quiet and not (cache.is_dir() and any(cache.rglob("*.nbi"))):
        print("compiling the simulation kernel (first run after install only, ~5-10 s)...", file=sys.stderr)
    kinds = {}
    for scn in scns:
        kinds.setdefault(bool(scn.faults), scn)
    for scn in kinds.values():
        Simulation(scn).advance(1)


def cmd_campaign(args: argparse.Namespace, started: float) -> int:
    if args.drop is None:
        args.drop = (0.0,)
    if args.jobs is None:
        args.jobs = os.cpu_count() or 1
    _check_out(args.out)
    points = grid(args.seeds, args.drop)
    scns, notes = _resolve_grid(args, points)
    for n in notes:
        print(f"swarm campaign: warning: {n}", file=sys.stderr)
    args.out.mkdir(exist_ok=True)
    _warm_kernels(scns, args.quiet)
    scn = scns[0]
    jobs = max(1, min(args.jobs, len(points)))
    results: dict[int, tuple[dict | None, str | None]] = {}
    status = console.StatusLine(enabled=not args.quiet, log_every=5.0)
    t0 = time.perf_counter()

    def show() -> None:
        done = len(results)
        spent = time.perf_counter() - t0
        eta = "-" if not done else f"{spent / done * (len(points) - done):.0f} s"
        bad = sum(1 for m, _ in results.values() if m is not None and m["collisions"])
        stuck = sum(1 for m, _ in results.values() if m is not None and m["converged_at_s"] is None)
        status.update(f"{console.bar(done / len(points))} {done}/{len(points)} runs on {jobs} workers  "
                      f"{spent:.0f} s, ETA {eta}  collided {bad}  not converged {stuck}", force=done == len(points))

    tasks = [(pt.index, args.scenario, overrides(args, pt)) for pt in points]
    with StopEvent() as stop:
        interrupted = _run_all(tasks, jobs, results, stop, show)
    status.close()
    return _report(args, scn, points, results, interrupted)


def _report(args, scn, points: list[Point], results: dict, interrupted: bool) -> int:
    from swarm.core.metrics import violations
    from swarm.view.campaign import Bodies, Flagged, write_index, write_plots

    rows, flagged, violated, failed, stuck = [], [], [], [], []
    for pt in points:
        if pt.index not in results:
            continue
        m, why = results[pt.index]
        row = run_row(scn.name, pt, m, why)
        rows.append(row)
        label = f"seed {pt.seed} drop {pt.drop:g}"
        if why is not None:
            failed.append(f"{label} ({why})")
            flagged.append(Flagged(row, f"failed: {why}", replay_command(args, pt)))
            continue
        v = violations(m)
        if v:
            violated.append(f"{label} ({', '.join(v)})")
        if m["converged_at_s"] is None:
            stuck.append(label)
        why_text = "; ".join(([f"collided: {', '.join(v)}"] if v else [])
                             + (["did not converge"] if m["converged_at_s"] is None else []))
        if why_text:
            flagged.append(Flagged(row, why_text, replay_command(args, pt)))
    out = args.out
    notes = [f"interrupted: {len(rows)} of {len(points)} runs done; the files hold those"] if interrupted else []
    if rows:
        cols = columns(rows)
        write_csv(out / "runs.csv", cols, [_wall_named(r) for r in rows])
        summ = summary(rows)
        write_csv(out / "summary.csv", SUMMARY_COLUMNS, summ)
        finished = [r for r in rows if r["failure"] is None]
        obstacle_r = float(scn.obstacles[:, 2].min()) if len(scn.obstacles) else None
        plots = write_plots(finished, out, Bodies(scn.r, obstacle_r, scn.duration),
                            f"{scn.name}, {scn.n} robots, {len(args.seeds)} seed{'s' if len(args.seeds) != 1 else ''}"
                            ) if finished else []
        write_index(out, campaign_command(args), SUMMARY_COLUMNS, summ, flagged, plots, notes)
    if not args.quiet and rows:
        print(_table(summary(rows)))
    print(f"campaign: {len(rows)} runs of {len(points)} in {args.out}/ (runs.csv, summary.csv, index.html)"
          if rows else "campaign: no run finished; nothing written")
    if stuck:
        print(f"campaign: {len(stuck)} run{'s' if len(stuck) != 1 else ''} did not converge by the end (reported, "
              f"not a failure): {', '.join(stuck)}")
    if failed:
        print(f"swarm campaign: {len(failed)} run{'s' if len(failed) != 1 else ''} could not finish: "
              f"{'; '.join(failed)}", file=sys.stderr)
    if violated:
        print(f"swarm campaign: {len(violated)} run{'s' if len(violated) != 1 else ''} failed a check: "
              f"{'; '.join(violated)}", file=sys.stderr)
    if interrupted:
        print(f"swarm campaign: interrupted after {len(rows)} of {len(points)} runs; the files hold those",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    if failed:
        return EXIT_FAILURE
    if violated and not args.allow_violations:
        return EXIT_VIOLATIONS
    return EXIT_OK


def _table(summ: list[dict]) -> str:
    """The summary for the terminal: one line per drop probability."""
    fmt = console.fmt
    head = ("drop", "runs", "collided", "converged", "median conv. [s]", "min robot dist [m]", "min obstacle dist [m]")
    lines = [head]
    for s in summ:
        lines.append((f"{s['drop']:g}", str(s["runs"]), str(s["collided_runs"]), str(s["converged_runs"]),
                      fmt(s["converged_at_s_median"], digits=4), fmt(s["min_robot_distance_m_min"], digits=4),
                      fmt(s["min_obstacle_distance_m_min"], digits=4)))
    widths = [max(len(line[i]) for line in lines) for i in range(len(head))]
    return "\n".join("  ".join(c.rjust(w) for c, w in zip(line, widths)) for line in lines)
