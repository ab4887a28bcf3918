"""The files of a campaign: its grid, runs.csv, summary.csv and campaign.json (what `swarm campaign` writes
and what `swarm campaign --up --from DIR` reads back). Pure of processes: the rows as dicts, the CSV text.

    points = grid(seeds=(0, 1), drops=(0.0, 0.3))          # grid order: by drop, then by seed
    row = run_row("paper-50hz", points[0], metrics, None)   # a runs.csv row: the metrics flattened
    write_csv(out / "runs.csv", columns(rows), [wall_named(r) for r in rows])
    write_campaign_json(args, out, command)                 # the flags, files as absolute paths
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import statistics
from dataclasses import dataclass
from pathlib import Path

from swarm.cli.common import BadInput

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
    out += scenario_flags(args)
    if point.drop > 0:
        out += ["--drop", repr(point.drop)]
    return shlex.join(out)


def campaign_command(args: argparse.Namespace) -> str:
    """This campaign's command line, every flag spelled out (for index.html)."""
    cluster = getattr(args, "cluster", None)  # where the runs ran: a Dask cluster's address, else -j processes
    out = ["swarm", "campaign", "--scenario", args.scenario, "--seeds", _seeds_text(args.seeds),
           "--drop", ",".join(repr(p) for p in args.drop), *scenario_flags(args),
           *(["--cluster", cluster] if cluster is not None else ["-j", str(args.jobs)]), "-o", str(args.out)]
    if args.allow_violations:
        out.append("--allow-violations")
    return shlex.join(out)


def scenario_flags(args: argparse.Namespace) -> list[str]:
    """The flags every run of the campaign shares, as `swarm sim` and `swarm up` take them."""
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


def wall_named(row: dict) -> dict:
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


def cell(v) -> str:
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
            w.writerow([cell(r.get(c)) for c in cols])
    tmp.replace(path)


# --------------------------------------------------------------------------- campaign.json

CAMPAIGN_JSON = "campaign.json"  # the campaign's flags, written beside runs.csv (what --from reads)
FLAGS = ("scenario", "seeds", "drop", "robots", "duration", "dt", "governor", "faults", "kill")


def scenario_source(source: str) -> str:
    """A built-in name as it is, a file as its absolute path (so that --from works from any directory)."""
    from swarm.core.scenario_file import BUILTINS

    return source if source in BUILTINS else str(Path(source).absolute())


def write_campaign_json(args: argparse.Namespace, out: Path, command: str) -> None:
    """DIR/campaign.json: the flags every run of the campaign was resolved with (files as absolute paths)."""
    doc = {"v": 1, "command": command, "scenario": scenario_source(args.scenario), "seeds": list(args.seeds),
           "drop": list(args.drop), "robots": args.robots, "duration": args.duration, "dt": args.dt,
           "governor": args.governor, "faults": None if args.faults is None else str(Path(args.faults).absolute()),
           "kill": args.kill}
    tmp = out / (CAMPAIGN_JSON + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    tmp.replace(out / CAMPAIGN_JSON)


def read_campaign(d: Path) -> tuple[argparse.Namespace, list[dict]]:
    """--from DIR: the campaign's flags (DIR/campaign.json) and its runs.csv rows (cells as text).
    BadInput naming the file and what is wrong."""
    if not d.is_dir():
        raise BadInput(f"--from {d}: no such directory")
    path = d / CAMPAIGN_JSON
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise BadInput(f"--from {d}: {CAMPAIGN_JSON} is missing: not a campaign directory (swarm campaign -o DIR "
                       "writes it beside runs.csv)") from None
    except (OSError, ValueError) as e:
        raise BadInput(f"--from {d}: {CAMPAIGN_JSON}: not readable JSON ({e})") from None
    missing = [k for k in FLAGS if k not in doc] if isinstance(doc, dict) else list(FLAGS)
    if missing or doc.get("v") != 1:
        raise BadInput(f"{path}: not a campaign file of version 1" + (f" (missing: {', '.join(missing)})"
                                                                        if missing else ""))
    args = argparse.Namespace(**{k: doc[k] for k in FLAGS})
    args.seeds, args.drop = tuple(args.seeds), tuple(float(p) for p in args.drop)
    runs = d / "runs.csv"
    try:
        with runs.open(newline="", encoding="utf-8") as f:
            rows = list(csv.DictReader(f))
    except FileNotFoundError:
        raise BadInput(f"--from {d}: runs.csv is missing (the campaign wrote no run)") from None
    for i, r in enumerate(rows, 1):
        for col in ("seed", "drop", "failure"):
            if r.get(col) is None:
                raise BadInput(f"{runs}: row {i}: no column {col!r}")
        try:
            int(r["seed"]), float(r["drop"])
        except ValueError:
            raise BadInput(f"{runs}: row {i}: seed {r['seed']!r} or drop {r['drop']!r} is not a number") from None
    return args, rows
