"""`swarm campaign`: `swarm sim` over a grid of seeds and drop probabilities, on every core; then, with
--up N, the first N runs again as lock-step `swarm up`, each held equal to its simulation.

    swarm campaign --scenario paper-50hz --seeds 0-9 --drop 0,0.1,0.3 -o out/
    swarm campaign --scenario my.toml --seeds 0-4 --faults kills.toml --drop 0,0.2 -j 2 -o out/
    swarm campaign --scenario paper-50hz --seeds 0-1 --drop 0.3,0 --kill 7@15 -o out/ --up 2
    swarm campaign --up 4 --from out/          # check a campaign already run (its campaign.json, runs.csv)

The grid is every p of --drop times every seed of --seeds. A run's seed sets run.seed, and with it the
faults' seed unless the faults name their own (swarm.core.scenario_file does that); p adds one drop rule
of class "all" to the faults of the scenario, or of --faults FILE, which replaces them (p = 0: no rule,
the baseline; --drop left out means --drop 0). Every grid point is resolved in this process first, so
bad input is refused (exit 2) before anything runs. The runs are Simulation(scenario).run() in a pool of
-j spawned workers, each compiled kernel loaded from the cache the parent filled.

Written into DIR (docs/faults.md, Campaigns; the rows and files: swarm.cli.campaign_files):
- runs.csv: one row a run in grid order (drop, then seed): scenario, seed, drop, every metric (the
  "faults" object flattened as faults.dropped.state, ...), failure; the wall-clock columns last, named
  wallclock.*;
- summary.csv: one row per p (collided, converged, failed runs; medians and extremes over seeds);
- campaign.json: the campaign's flags (files as absolute paths), what --from reads;
- convergence.png, distance.png, error.png and index.html (swarm.view.campaign);
- with --up: up.csv, DIR/up/row-K/ and a section of index.html (swarm.cli.campaign_up).
Apart from the wallclock.* columns, the same command writes the same files. A new grid removes the
up.csv and DIR/up/ of an earlier one (they checked other runs).

Exit code: 3 when a run failed a check of the metrics contract (a collision), naming the runs (0 with
--allow-violations), or when a `swarm up` of --up differed from its simulation or failed (naming the
rows); 1 when a run could not finish (a non-finite state); 130 interrupted (the files then hold the runs
done); else 0. A run that did not converge is reported, not a failure.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import queue
import shutil
import signal
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, cast

from swarm.cli import console
from swarm.cli.campaign_files import (SUMMARY_COLUMNS, Point, campaign_command, columns, grid, overrides,
                                      read_campaign, replay_command, run_row, summary, wall_named, write_campaign_json,
                                      write_csv)
from swarm.cli.common import EXIT_FAILURE, EXIT_INTERRUPTED, EXIT_OK, BadInput, StopEvent, check_writable

if TYPE_CHECKING:
    from swarm.core.scenario import Scenario
    from swarm.core.scenario_file import Overrides

EXIT_VIOLATIONS = 3


# --------------------------------------------------------------------------- the workers


def run_point(task: tuple[int, str, Overrides]) -> tuple[int, dict | None, str | None]:
    """One run: (index, metrics, None), or (index, None, why) when it could not finish."""
    from swarm.core import scenario_file
    from swarm.core.errors import ScenarioError
    from swarm.core.sim import Simulation, SimulationError

    index, source, ov = task
    try:
        scn = scenario_file.load(source, ov, progress=scenario_file.silent)
        # one thread a run: a campaign is parallel across runs (a worker a core), never inside one
        m = Simulation(scn, threads=1).run().metrics
        m.setdefault("robots_alive_at_end", scn.n)  # no faults: every robot (as swarm up's world counts them too)
        return index, m, None
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
                        index = running.pop(cast(int, p.pid), None)  # a process with an exit code has started
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


# --------------------------------------------------------------------------- on a Dask cluster

CLUSTER_INSTALL = "pip install 'swarm[cluster]'"
CLUSTER_CONNECT_S = 10.0  # s to reach a cluster's scheduler
CLUSTER_RETRIES = 2  # a run that fails on a worker (its process died) runs again this many times


def _check_cluster(address: str) -> None:
    """--cluster's address is tcp://HOST:PORT (or tls://...) or local:N, and Dask is installed (BadInput naming what
    to do otherwise), before anything runs."""
    if address.startswith("local:"):
        n = address.removeprefix("local:")
        if not n.isdigit() or not 1 <= int(n) <= 1024:
            raise BadInput(f"--cluster {address}: local:N takes a number of worker processes, 1..1024")
    elif "://" not in address or not address.split("://", 1)[1]:
        raise BadInput(f"--cluster {address}: give the scheduler's address, tcp://HOST:PORT (what `dask scheduler` "
                       "prints), or local:N")
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise BadInput(f"--cluster needs Dask's distributed scheduler: {CLUSTER_INSTALL}") from None


def _run_on_cluster(tasks: list, address: str, results: dict, stop, show, quiet: bool) -> bool:
    """Run every task on a Dask cluster (a scheduler's address, or local:N: a LocalCluster of N processes of one
    thread each), filling results[index] = (metrics, why) as they come, show() after each and at least every
    0.25 s. Each run is run_point, a pure function of its task: a worker that dies has its runs run again elsewhere
    (Dask's own rescheduling, then CLUSTER_RETRIES), so the rows equal a local campaign's. Returns True when stopped
    early (its runs on the cluster are cancelled)."""
    import uuid

    from distributed import Client, LocalCluster, wait

    cluster = None
    try:
        if address.startswith("local:"):
            import logging

            logging.getLogger("distributed").setLevel(logging.ERROR)  # its processes' chatter as they start and end
            cluster = LocalCluster(n_workers=int(address.removeprefix("local:")), threads_per_worker=1, processes=True,
                                   dashboard_address=":0")
            client = Client(cluster, timeout=CLUSTER_CONNECT_S)
        else:
            client = Client(address, timeout=CLUSTER_CONNECT_S)
    except (OSError, TimeoutError) as e:
        if cluster is not None:
            cluster.close()
        raise BadInput(f"--cluster {address}: no Dask scheduler answers there ({e}); start one with `dask "
                       "scheduler` and workers with `dask worker ADDRESS`") from None
    try:
        workers = len(client.scheduler_info().get("workers", {}))
        if not quiet:
            print(f"swarm campaign: {len(tasks)} runs on the Dask cluster {client.scheduler.address} ({workers} "
                  f"worker{'s' if workers != 1 else ''} now); its dashboard: {client.dashboard_link}", file=sys.stderr)
        tag = uuid.uuid4().hex[:8]
        pending = {client.submit(run_point, t, key=f"swarm-run-{tag}-{t[0]}", pure=False,
                                 retries=CLUSTER_RETRIES): t[0] for t in tasks}
        while pending:
            if stop.is_set():
                client.cancel(list(pending))
                return True
            try:
                done, _ = wait(list(pending), timeout=0.25, return_when="FIRST_COMPLETED")
            except TimeoutError:  # nothing finished within 0.25 s
                done = set()
            for fut in done:
                index = pending.pop(fut)
                try:
                    i, m, why = fut.result()
                    results[i] = (m, why)
                except Exception as e:  # the run's own errors come back in `why`: this is the cluster's
                    results[index] = (None, f"on the cluster: {type(e).__name__}: {e}")
            show()
        return False
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# --------------------------------------------------------------------------- the command


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise BadInput(f"-o {out}: exists and is not a directory")
    if not out.exists() and not out.parent.is_dir():
        raise BadInput(f"-o {out}: directory {out.parent} does not exist")
    check_writable("-o", out, out if out.exists() else out.parent)


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
    from swarm.core.sim import Simulation, kernel_cached

    kinds: dict[bool, Scenario] = {}
    for scn in scns:
        kinds.setdefault(bool(scn.faults), scn)
    missing = [faults for faults, scn in kinds.items() if scn.control.law is None and not kernel_cached(faults=faults)]
    if not quiet and missing:
        what = " and ".join("the kernel for faults" if f else "the simulation kernel" for f in sorted(missing))
        print(f"compiling {what} (once: numba caches it; ~10-30 s each)...", file=sys.stderr)
    for scn in kinds.values():
        Simulation(scn, threads=1).advance(1)


GRID_FLAGS = (("scenario", "--scenario"), ("seeds", "--seeds"), ("drop", "--drop"), ("robots", "--robots"),
              ("duration", "--duration"), ("dt", "--dt"), ("governor", "--governor"), ("faults", "--faults"),
              ("kill", "--kill"), ("out", "-o"), ("jobs", "-j"))


def cmd_campaign(args: argparse.Namespace, started: float) -> int:
    if args.from_dir is not None:
        return _check_existing(args)
    if args.seeds is None:
        raise BadInput("--seeds is required: the grid's seeds (or --up N --from DIR: check a campaign already run)")
    if args.out is None:
        raise BadInput("-o DIR is required: where the campaign's files go")
    if args.scenario is None:
        args.scenario = "paper-50hz"
    if args.drop is None:
        args.drop = (0.0,)
    args.jobs_given = args.jobs is not None
    if args.jobs is None:
        args.jobs = os.cpu_count() or 1
    _check_out(args.out)
    points = grid(args.seeds, args.drop)
    if args.up is not None and args.up > len(points):
        raise BadInput(f"--up {args.up}: the grid has {len(points)} run{'s' if len(points) != 1 else ''} "
                       f"({len(args.seeds)} seeds x {len(args.drop)} drop probabilities)")
    scns, notes = _resolve_grid(args, points)
    for n in notes:
        print(f"swarm campaign: warning: {n}", file=sys.stderr)
    args.out.mkdir(exist_ok=True)
    _warm_kernels(scns, args.quiet)
    scn = scns[0]
    jobs = max(1, min(args.jobs, len(points)))
    if args.cluster is not None:
        if args.jobs_given:
            raise BadInput("-j with --cluster: the cluster's workers run the runs; give one or the other")
        _check_cluster(args.cluster)
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
        if args.cluster is not None:
            interrupted = _run_on_cluster(tasks, args.cluster, results, stop, show, args.quiet)
        else:
            interrupted = _run_all(tasks, jobs, results, stop, show)
    status.close()
    code = _report(args, scn, points, results, interrupted)
    if args.up is None or code == EXIT_INTERRUPTED or not results:
        return code
    from swarm.cli.campaign_up import check_rows

    flags, rows = read_campaign(args.out)  # as --from reads it: one path for both
    return _worst(code, check_rows(flags, args.out, rows, args.up, args.quiet))


def _check_existing(args: argparse.Namespace) -> int:
    """--up N --from DIR: check the first N rows of a campaign already run; its flags are DIR's."""
    if args.up is None:
        raise BadInput(f"--from {args.from_dir}: give --up N, how many of its runs to check with swarm up")
    given = [flag for key, flag in GRID_FLAGS if getattr(args, key) is not None]
    if args.allow_violations:
        given.append("--allow-violations")
    if given:
        raise BadInput(f"--from {args.from_dir}: {', '.join(given)} cannot be given with it (the campaign's own "
                       "flags, in its campaign.json, make every run)")
    from swarm.cli.campaign_up import check_rows

    flags, rows = read_campaign(args.from_dir)
    if args.up > len(rows):
        raise BadInput(f"--up {args.up}: {args.from_dir}/runs.csv has {len(rows)} run{'s' if len(rows) != 1 else ''}")
    return check_rows(flags, args.from_dir, rows, args.up, args.quiet)


def _worst(*codes: int) -> int:
    """The exit code of several steps: interrupted, then a failure, then a failed check, then 0."""
    for code in (EXIT_INTERRUPTED, EXIT_FAILURE, EXIT_VIOLATIONS):
        if code in codes:
            return code
    return EXIT_OK


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
        write_csv(out / "runs.csv", cols, [wall_named(r) for r in rows])
        write_campaign_json(args, out, campaign_command(args))
        _forget_up_checks(out)
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


def _forget_up_checks(out: Path) -> None:
    """A new grid's files: the --up checks of an earlier one (up.csv, DIR/up/row-K) no longer apply."""
    (out / "up.csv").unlink(missing_ok=True)
    up = out / "up"
    if up.is_dir():
        for d in up.glob("row-*"):
            shutil.rmtree(d, ignore_errors=True)
        try:
            up.rmdir()
        except OSError:  # something else of the user's in it: left alone
            pass


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
