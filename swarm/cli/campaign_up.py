"""`swarm campaign --up N`: a campaign's first N runs again as lock-step `swarm up`, each held equal to
`swarm sim` bit for bit.

    swarm campaign --scenario paper-50hz --seeds 0-9 --drop 0,0.3 --kill 7@15 -o out/ --up 3   # after the grid
    swarm campaign --up 3 --from out/                                           # on a campaign already run

The rows are the first N of DIR/runs.csv, in its order (by drop probability, then by seed), one at a
time: a `swarm up` is N robots + 3 processes, and two of them at once would only slow both. For each:

1. its scenario is resolved again from the campaign's flags (DIR/campaign.json) with the row's seed and
   drop: the same scenario, seed, drop rule and faults (--faults, --kill) as the row's run;
2. `swarm sim` runs it here twice: as a campaign worker did (its metrics must be the row's, cell for
   cell: otherwise the scenario or faults file changed since the campaign ran, and the row is "stale"),
   and recording every tick (what `swarm up --trace` writes);
3. `swarm up --mode lockstep --trace` runs it as a child process in its own process group (a free
   loopback port, a fleet name of its own, --no-viz --quiet --allow-violations, its logs, metrics and
   output in DIR/up/row-K/), bounded by timeout_s (from the run's size);
4. its trace must equal the recording (`np.array_equal`: every robot's x, y, theta at every tick, bit
   for bit) and its metrics the simulation's on SAME (collisions, the smallest distances, the final
   errors, converged_at_s, messages_dropped, the faults object, robots_alive_at_end).

One line a row (OK, DIFFERS at tick K with the robots, FAILED with why; the wall times), DIR/up.csv
(UP_COLUMNS, one row a check, rewritten after each), and a section of DIR/index.html. The trace of a row
that differs is kept (DIR/up/row-K/trace.npz); an identical one is deleted (5 MB at 37 robots x 120 s).
The exit code (`check_rows`): 3 when a row differs, is stale or its `swarm up` failed, each named; 130
when interrupted (the `swarm up` under way is stopped: SIGTERM to its process group, which shuts its
processes down, SIGKILL after a grace); else 0.

This module starts `swarm up` itself (subprocess), as `swarm up` starts its children: a campaign is a
launcher of launchers; it never starts a robot, world or router process directly.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import shutil
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import cast

import numpy as np

from swarm.cli import console
from swarm.cli.campaign_files import (WALL_CLOCK, Point, cell, flatten, overrides, scenario_flags, scenario_source,
                                      write_csv)
from swarm.cli.common import EXIT_INTERRUPTED, EXIT_OK, BadInput, StopEvent
from swarm.launch.child import stop_group
from swarm.process import PARENT_ENV

EXIT_DIFFERS = 3
UP_CSV = "up.csv"
# the metrics a lock-step swarm up must share with swarm sim (the faults object in full)
SAME = ("collisions", "min_robot_distance_m", "min_obstacle_distance_m", "final_position_error_max_m",
        "final_orientation_error_max_rad", "converged_at_s", "messages_dropped", "faults", "robots_alive_at_end")
GRACE_S = 15.0  # after SIGTERM, how long `swarm up` has to shut its processes down before SIGKILL
START_TIMEOUT_S = 60.0  # swarm up --start-timeout (every process alive)
MIN_ROBOT_TICKS_PER_S = 100.0  # the slowest lock-step pace timeout_s allows (robots x ticks a second)
PROCESS_FAULT_S = 10.0  # wall seconds allowed per scheduled kill or hang (a hang stops >= 2.5 s; a restart)


# --------------------------------------------------------------------------- comparing


@dataclass(frozen=True)
class TraceDiff:
    """Where a trace differs from the recording: the first tick, the robots that differ at it, how many
    ticks differ; `shape` says why nothing could be compared tick by tick (else None)."""

    first_tick: int | None
    robots: tuple[int, ...] = ()
    ticks: int = 0
    shape: str | None = None


def compare_traces(q_up: np.ndarray, q_sim: np.ndarray) -> TraceDiff:
    """q_*: (ticks + 1, N, 3) x [m], y [m], theta [rad] at every tick. Bit for bit (np.array_equal);
    a NaN equals only a NaN in the same place."""
    if q_up.shape != q_sim.shape:
        return TraceDiff(None, shape=f"swarm up's trace is {q_up.shape}, swarm sim's recording {q_sim.shape} "
                                     "(ticks + 1, robots, 3)")
    if np.array_equal(q_up, q_sim, equal_nan=True):
        return TraceDiff(None)
    bad = (q_up != q_sim) & ~(np.isnan(q_up) & np.isnan(q_sim))
    ticks = np.flatnonzero(bad.any(axis=(1, 2)))
    k = int(ticks[0])
    return TraceDiff(k, tuple(int(i) for i in np.flatnonzero(bad[k].any(axis=1))), len(ticks))


def metric_differences(up: dict, sim: dict, keys=SAME) -> list[str]:
    """'key: A (swarm up) != B (swarm sim)' for every key (nested objects by their leaves) that differs. A
    key swarm sim does not report is not compared (without faults it has no faults object and no
    robots_alive_at_end; swarm up's world always counts the robots alive)."""
    keys = [k for k in keys if k in sim]
    a = flatten({k: up.get(k) for k in keys})
    b = flatten({k: sim.get(k) for k in keys})
    return [f"{k}: {a.get(k)!r} (swarm up) != {b.get(k)!r} (swarm sim)" for k in dict.fromkeys([*a, *b])
            if a.get(k) != b.get(k) and not _both_nan(a.get(k), b.get(k))]


def _both_nan(x, y) -> bool:
    return isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y)


def row_differences(row: dict, sim: dict) -> list[str]:
    """The cells of a runs.csv row (text) that the simulation's metrics (flattened, as runs.csv writes them)
    do not reproduce; wall-clock keys aside."""
    out = []
    for k, v in flatten(sim).items():
        if k in WALL_CLOCK:
            continue
        if k not in row:
            out.append(f"{k}: no such column in runs.csv")
        elif row[k] != cell(v):
            out.append(f"{k}: {row[k]!r} in runs.csv, {cell(v)!r} now")
    return out


# --------------------------------------------------------------------------- running swarm up


def timeout_s(scn) -> float:
    """How long one `swarm up` may take: the start-up, then at least MIN_ROBOT_TICKS_PER_S robot-ticks a
    second (measured: 1200-1900 on 2 cores at 7 to 37 robots), and PROCESS_FAULT_S per kill or hang."""
    faults = scn.faults
    process = (len(faults.kills) + len(faults.hangs)) if faults else 0
    return START_TIMEOUT_S + 60.0 + scn.steps * max(1, scn.n) / MIN_ROBOT_TICKS_PER_S + PROCESS_FAULT_S * process


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def up_command(args: argparse.Namespace, seed: int, drop: float, d: Path, port: int, fleet: str) -> list[str]:
    """The `swarm up` of one row (argv), its files in d."""
    flags = argparse.Namespace(**{**vars(args), "faults": None if args.faults is None else str(Path(args.faults).absolute())})
    argv = [sys.executable, "-m", "swarm.cli", "up", "--scenario", scenario_source(args.scenario), "--seed", str(seed),
            *scenario_flags(flags)]
    if drop > 0:
        argv += ["--drop", repr(drop)]
    return argv + ["--mode", "lockstep", "--trace", str(d / "trace.npz"), "--metrics", str(d / "metrics.json"),
                   "--log-dir", str(d / "logs"), "--listen", f"tcp/127.0.0.1:{port}", "--fleet", fleet,
                   "--start-timeout", f"{START_TIMEOUT_S:g}", "--no-viz", "--quiet", "--allow-violations"]


@dataclass
class UpRun:
    """One `swarm up` child: its exit code (None: it was stopped), why it was stopped, its wall time [s]."""

    rc: int | None = None
    stopped: str | None = None
    wall_s: float = 0.0


def run_up(argv: list[str], output: Path, limit_s: float, stop, tick) -> UpRun:
    """Run `swarm up` in its own process group, its stdout and stderr into `output`; end it when it
    exceeds limit_s or when `stop` is set; tick(elapsed_s) about every 0.25 s. Nothing it started
    outlives this call."""
    t0 = time.perf_counter()
    with open(output, "wb") as out:
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.STDOUT, process_group=0,
                                env={**os.environ, PARENT_ENV: str(os.getpid())})  # it dies with the campaign
    run = UpRun()
    try:
        while True:
            try:
                run.rc = proc.wait(0.25)
                break
            except subprocess.TimeoutExpired:
                pass
            elapsed = time.perf_counter() - t0
            if stop.is_set():
                run.stopped = "interrupted"
            elif elapsed > limit_s:
                run.stopped = f"no end after {limit_s:.0f} s (the timeout)"
            if run.stopped:
                break
            tick(elapsed)
    finally:
        if proc.poll() is None:  # SIGTERM to swarm up's group (it shuts its processes down and writes its metrics),
            # SIGKILL to it and to every process it started after GRACE_S (they also die with it: PR_SET_PDEATHSIG)
            stop_group(proc, GRACE_S, descendants=True)
        run.wall_s = time.perf_counter() - t0
    return run


# --------------------------------------------------------------------------- one row


@dataclass
class Check:
    """The check of one runs.csv row: result "identical", "differs", "stale" (swarm sim no longer gives
    the row), "failed" (swarm up did not finish, or the row's own run had failed) or "interrupted"."""

    row: int  # 1-based, in runs.csv
    scenario: str
    seed: int
    drop: float
    result: str = "failed"
    trace: TraceDiff | None = None
    metrics: list[str] = field(default_factory=list)  # metric_differences, or row_differences when stale
    why: str | None = None
    up: dict | None = None  # swarm up's metrics
    up_s: float | None = None
    sim_s: float | None = None
    exit: int | None = None
    out: str = ""  # the row's directory, relative to the campaign's
    command: str = ""

    @property
    def label(self) -> str:
        return f"seed {self.seed} drop {self.drop:g}"


def check_row(args, out: Path, index: int, row: dict, stop, status, total: int) -> Check:
    from swarm.core import scenario_file
    from swarm.core.errors import ScenarioError
    from swarm.core.sim import Simulation, SimulationError

    seed, drop = int(row["seed"]), float(row["drop"])
    c = Check(index, row.get("scenario", ""), seed, drop)
    if row["failure"]:
        c.why = f"its run in the campaign could not finish ({row['failure']}): nothing to compare"
        return c
    d = out / "up" / f"row-{index}"
    c.out = str(d.relative_to(out))
    try:
        scn = scenario_file.load(args.scenario, overrides(args, Point(index - 1, seed, drop)),
                                 progress=scenario_file.silent)
        status.update(f"up {index}/{total}, {c.label}: swarm sim", force=True)
        as_campaign = Simulation(scn).run(should_stop=stop.is_set).metrics
        t0 = time.perf_counter()
        sim = Simulation(scn, record_period=scn.dt).run(should_stop=stop.is_set)
        c.sim_s = time.perf_counter() - t0
    except (ScenarioError, SimulationError) as e:
        c.why = f"swarm sim: {e}"
        return c
    if stop.is_set():
        c.result, c.why = "interrupted", "interrupted"
        return c
    stale = row_differences(row, as_campaign)
    if stale:
        c.result, c.metrics = "stale", stale
        c.why = "swarm sim no longer gives this row of runs.csv: was the scenario or faults file changed?"
        return c
    shutil.rmtree(d, ignore_errors=True)  # this row's files of an earlier check
    d.mkdir(parents=True)
    argv = up_command(args, seed, drop, d, free_port(), f"campaign-{os.getpid()}-{index}")
    c.command = shlex.join(["swarm", *argv[3:]])
    limit = timeout_s(scn)
    run = run_up(argv, d / "up.log", limit, stop,
                 lambda s: status.update(f"up {index}/{total}, {c.label}: swarm up running, {s:.0f} s "
                                         f"(timeout {limit:.0f} s)"))
    c.up_s, c.exit = run.wall_s, run.rc
    if run.stopped == "interrupted":
        c.result, c.why = "interrupted", "interrupted"
        return c
    if run.stopped:
        c.why = f"swarm up: {run.stopped}; its logs: {d / 'logs'}"
        return c
    try:
        c.up = json.loads((d / "metrics.json").read_text())
    except (OSError, ValueError):
        c.up = None
    if run.rc != 0 or c.up is None or c.up.get("failure") or c.up.get("interrupted"):
        tail = _tail(d / "up.log")
        said = (c.up or {}).get("failure") or tail or "no output"
        c.why = f"swarm up exited {run.rc}: {said}; its logs: {d / 'logs'}"
        return c
    try:
        q_up = np.load(d / "trace.npz")["q"]
    except (OSError, KeyError, ValueError) as e:
        c.why = f"swarm up wrote no readable trace ({e}); its logs: {d / 'logs'}"
        return c
    c.trace = compare_traces(q_up, sim.recording.q)
    c.metrics = metric_differences(c.up, sim.metrics)
    if c.trace.first_tick is None and c.trace.shape is None and not c.metrics:
        c.result = "identical"
        (d / "trace.npz").unlink(missing_ok=True)
    else:
        c.result = "differs"
        c.why = "; ".join(overdue_ticks(d / "logs")) or None
    return c


OVERDUE = (" goes on after ", ": no reference for tick ")  # a lock-step robot's tick without all its inputs


def overdue_ticks(logs: Path, most: int = 3) -> list[str]:
    """The first lines (at most `most`) in which a lock-step robot's log says it computed a tick without all of
    its inputs (agents.lockstep): what makes a run differ from swarm sim when nothing in the schedule does."""
    out: list[str] = []
    for path in sorted(logs.glob("robot-*.log"), key=lambda p: int(p.stem[6:]) if p.stem[6:].isdigit() else -1):
        try:
            text = path.read_text(errors="replace")
        except OSError:
            continue
        for ln in text.splitlines():
            if any(m in ln for m in OVERDUE):
                out.append(ln.split(": ", 1)[-1].strip())
                if len(out) >= most:
                    return out
    return out


def _tail(path: Path, lines: int = 2) -> str:
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return " | ".join(text[-lines:])


def line(c: Check, total: int, dt: float) -> str:
    """The line printed for a row."""
    head = f"up {c.row}/{total}, {c.label}: "
    walls = "; ".join(w for w in (f"swarm up {c.up_s:.1f} s" if c.up_s is not None else "",
                                  f"swarm sim {c.sim_s:.2f} s" if c.sim_s is not None else "") if w)
    walls = f" ({walls})" if walls else ""
    if c.result == "identical":
        return f"{head}OK, identical to swarm sim: every tick of every robot and the metrics{walls}"
    if c.result == "differs":
        t = cast(TraceDiff, c.trace)  # a run that differs was compared
        if t.shape is not None:
            where = t.shape
        elif t.first_tick is not None:
            where = (f"at tick {t.first_tick} (t = {t.first_tick * dt:.2f} s), robots "
                     f"{', '.join(map(str, t.robots))}; {t.ticks} ticks differ")
        else:
            where = "in the metrics only (every tick equal)"
        metrics = f"; metrics: {'; '.join(c.metrics)}" if c.metrics else ""
        from swarm.core.metrics import nondeterminism

        causes = nondeterminism(c.up or {})
        said = f"; swarm up says: {', '.join(causes)}" if causes else ""
        logs = f"; its robots' logs: {c.why}" if c.why else ""
        return f"{head}DIFFERS {where}{metrics}{said}{logs}{walls}; its files: {c.out}/"
    if c.result == "stale":
        return f"{head}STALE: {c.why} ({'; '.join(c.metrics[:3])}{' ...' if len(c.metrics) > 3 else ''})"
    if c.result == "interrupted":
        return f"{head}interrupted{walls}"
    return f"{head}FAILED: {c.why}{walls}"


# --------------------------------------------------------------------------- up.csv

UP_COLUMNS = ("row", "scenario", "seed", "drop", "result", "first_differing_tick", "first_differing_t_s",
              "robots_differing", "ticks_differing", "metrics_differing", "why", "up_said", "up_exit", "collisions",
              "converged_at_s", "min_robot_distance_m", "robots_alive_at_end", "messages_dropped", "files",
              "command", "wallclock.up_s", "wallclock.sim_s")


def up_row(c: Check, dt: float) -> dict:
    """A row of up.csv (UP_COLUMNS); up_said: what swarm up itself says made its run depart from lock-step's
    schedule (missed commands, robots lost, overruns, restarts: swarm.core.metrics.nondeterminism)."""
    from swarm.core.metrics import nondeterminism

    t = c.trace or TraceDiff(None)
    m = c.up or {}
    return {"row": c.row, "scenario": c.scenario, "seed": c.seed, "drop": c.drop, "result": c.result,
            "first_differing_tick": t.first_tick, "first_differing_t_s": None if t.first_tick is None
            else round(t.first_tick * dt, 9), "robots_differing": " ".join(map(str, t.robots)) or None,
            "ticks_differing": t.ticks if c.trace is not None else None,
            "metrics_differing": " | ".join(c.metrics) or None, "why": t.shape or c.why,
            "up_said": "; ".join(nondeterminism(m)) or None, "up_exit": c.exit,
            "collisions": m.get("collisions"), "converged_at_s": m.get("converged_at_s"),
            "min_robot_distance_m": m.get("min_robot_distance_m"), "robots_alive_at_end": m.get("robots_alive_at_end"),
            "messages_dropped": m.get("messages_dropped"), "files": c.out or None, "command": c.command or None,
            "wallclock.up_s": c.up_s, "wallclock.sim_s": c.sim_s}


# --------------------------------------------------------------------------- the command


def check_rows(args: argparse.Namespace, out: Path, rows: list[dict], n: int, quiet: bool) -> int:
    """Check the first n rows of runs.csv (as text) with swarm up; print, write up.csv and index.html's
    section; return 0, EXIT_DIFFERS or EXIT_INTERRUPTED."""
    from swarm.view.campaign import write_up_section

    if n > len(rows):
        raise BadInput(f"--up {n}: {out}/runs.csv has {len(rows)} run{'s' if len(rows) != 1 else ''}")
    from swarm.core import scenario_file

    dt = scenario_file.load(args.scenario, scenario_file.Overrides(robots=args.robots, duration=args.duration,
                                                                   dt=args.dt), progress=scenario_file.silent).dt
    status = console.StatusLine(enabled=not quiet, log_every=10.0)
    print(f"swarm up, lock-step, against swarm sim: the first {n} of {len(rows)} runs, one at a time "
          f"(files in {out}/up/)", flush=True)
    for old in (out / "up").glob("row-*"):  # an earlier check's of more rows: up.csv will not list them
        if old.name[4:].isdigit() and int(old.name[4:]) > n and old.is_dir():
            shutil.rmtree(old, ignore_errors=True)
    checks: list[Check] = []
    with StopEvent(hard_second=False) as stop:
        for i, row in enumerate(rows[:n], 1):
            if stop.is_set():
                break
            c = check_row(args, out, i, row, stop, status, n)
            checks.append(c)
            status.clear()
            print(line(c, n, dt), flush=True)
            write_csv(out / UP_CSV, UP_COLUMNS, [up_row(x, dt) for x in checks])
            if c.result == "interrupted":
                break
    status.close()
    interrupted = stop.is_set()
    write_up_section(out, [{k: cell(v) for k, v in up_row(x, dt).items()} for x in checks], n,
                     "interrupted" if interrupted else None)
    bad = [c for c in checks if c.result not in ("identical", "interrupted")]
    ok = sum(1 for c in checks if c.result == "identical")
    print(f"campaign: {ok} of {len(checks)} swarm up run{'s' if len(checks) != 1 else ''} identical to swarm sim "
          f"({out}/{UP_CSV})")
    if bad:
        print(f"swarm campaign: {len(bad)} swarm up run{'s' if len(bad) != 1 else ''} not identical to swarm sim: "
              + "; ".join(f"{c.label} {c.result}" + (f" at tick {c.trace.first_tick}" if c.trace and
                                                     c.trace.first_tick is not None else "") for c in bad),
              file=sys.stderr)
    if interrupted:
        done = sum(1 for c in checks if c.result != "interrupted")
        print(f"swarm campaign: interrupted: {done} of {n} swarm up checks done (in {UP_CSV})", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_DIFFERS if bad else EXIT_OK
