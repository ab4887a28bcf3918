"""`swarm sim` (the compiled simulator in one process) and `swarm scenario show | check`."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import TYPE_CHECKING, cast

from swarm.cli.common import (EXIT_OK, BadInput, Failure, StopEvent, check_out_dir, check_viz_port, check_writable,
                              overrides, record_rate, viz_options)
from swarm.cli import console
from swarm.cli.console import exit_status, summary

if TYPE_CHECKING:
    from pathlib import Path


def cmd_sim(args: argparse.Namespace, started: float) -> int:
    from swarm.core import scenario_file
    from swarm.core.sim import SimulationError

    scn = scenario_file.load(args.scenario, overrides(args), progress=scenario_file.silent if args.quiet else None)
    for note in scenario_file.advisories(scn):
        print(f"swarm sim: warning: {note}", file=sys.stderr)
    check_out_dir("--metrics", args.metrics)
    check_out_dir("--record", args.record)
    check_out_dir("--trace", args.trace)
    if args.trace is not None and (scn.steps + 1) * scn.n > TRACE_MAX_POSES:
        raise BadInput(f"--trace: {scn.steps + 1} steps of {scn.n} robots are {(scn.steps + 1) * scn.n:.3g} poses to "
                       f"keep, more than {TRACE_MAX_POSES:,} (about 1 GiB with the samples beside them): shorten "
                       "the run (--duration) or lengthen --dt")
    args.record_hz = record_rate(args)
    if args.plots is not None and args.plots.exists() and not args.plots.is_dir():
        raise BadInput(f"--plots {args.plots}: exists and is not a directory")
    parent = args.plots.absolute().parent if args.plots is not None else None
    if parent is not None and not args.plots.exists() and not parent.is_dir():
        raise BadInput(f"--plots {args.plots}: {parent} " + ("is not a directory" if parent.exists() else
                       "does not exist (the plots' folder itself is made if missing)"))
    if args.plots is not None:
        check_writable("--plots", args.plots, args.plots if args.plots.exists() else cast("Path", parent))
    if args.threads is not None and args.threads > 1 and (scn.faults or scn.control.law is not None):
        raise BadInput(f"--threads {args.threads}: a run with faults or a law of its own takes the serial loop, "
                       "on one thread; leave --threads out")
    viz = viz_options(args, args.viz, "needs --viz", extra=(("--speed", args.speed),))
    if viz is not None:
        check_viz_port(viz)
    status = console.StatusLine(enabled=not args.quiet, log_every=2.0)  # a line every 2 s in a log, as swarm up
    from swarm.core.sim import kernel_cached, kernel_threads

    parallel = kernel_threads(scn, args.threads) > 1
    compiling = scn.control.law is None and not kernel_cached(parallel, bool(scn.faults))
    if compiling and not args.quiet:
        what = ("the simulation kernel for faults" if scn.faults else
                "the simulation kernel's parallel twin" if parallel else "the simulation kernel")
        print(f"compiling {what} (once: numba caches it; ~10-30 s)...", file=sys.stderr)
    t_build = time.perf_counter()
    sim = _simulation(args, scn)
    if compiling:
        sim.compile()
    compile_s = time.perf_counter() - t_build if compiling else None

    def show(p) -> None:
        dist = "-" if p.min_distance is None else f"{p.min_distance:.3f} m"
        status.update(f"{console.bar(p.t / p.duration if p.duration else 1)} t {p.t:7.2f}/{p.duration:.1f} s"
                      f"{_fault_fields(sim)}  converged {p.converged}/{p.robots}  frozen {p.frozen}"
                      f"  min distance {dist}")

    if viz is not None:
        return _sim_in_viewer(args, viz, scn, sim, show, status, started, compile_s)
    with StopEvent() as stop:
        t0 = time.perf_counter()
        try:
            result = sim.run(progress=show, should_stop=stop.is_set, started=started)
        except SimulationError as e:
            status.close()
            raise Failure(str(e)) from None
    status.close()
    if args.python_law and scn.control.law is not None and not args.quiet:
        rate = sim.progress().t / max(time.perf_counter() - t0, 1e-9)
        print(f"swarm sim: the law ran as plain Python (--python-law): {rate:.3g} simulated s per wall s; compiled "
              "by numba a law runs 100-1000 times faster", file=sys.stderr)
    return _sim_report(args, scn, result, compile_s)


TRACE_MAX_POSES = 16_000_000  # --trace keeps every step: (steps + 1) x N poses, 65 bytes each with their samples


def _simulation(args: argparse.Namespace, scn):
    """The Simulation of `swarm sim`: samples as --record asks, a user's law compiled (or --python-law)."""
    from swarm.core.sim import Simulation
    from swarm.core.userlaw import LawError

    period = None
    if args.record is not None:
        from swarm.view import record

        period = record.record_period(args.record_hz, scn.dt)
    if args.trace is not None:  # every step (the recording and the plots take theirs from these)
        period = scn.dt
    if scn.control.law is None and args.python_law:
        raise BadInput("--python-law: the scenario runs the paper's law (control.law = \"paper\"); the flag is for "
                       "a law of your own")
    if scn.control.law is not None:
        from swarm.core import userlaw

        try:
            userlaw.load(scn.control.law)  # one that does not load (a syntax error) is refused before any note
        except LawError as e:
            raise BadInput(str(e)) from None
        if not args.quiet:
            how = "as plain Python" if args.python_law else "compiled by numba (cached after the first run)"
            print(f"law: {scn.control.law.text} (sha256 {scn.control.law.sha256[:16]}...), {how}", file=sys.stderr)
    try:
        if period is None:
            return Simulation(scn, python_law=args.python_law, threads=args.threads)
        return Simulation(scn, record_period=period, python_law=args.python_law, threads=args.threads)
    except LawError as e:
        raise BadInput(str(e)) from None


def _sim_report(args: argparse.Namespace, scn, result, compile_s: float | None = None) -> int:
    """Write what the flags ask for, print the summary (compile_s: the seconds of a first run spent compiling
    the loop), and return the exit code."""
    m = result.metrics
    if args.metrics is not None:
        args.metrics.write_text(json.dumps(m, indent=2, allow_nan=False) + "\n")
    if args.trace is not None:
        import numpy as np

        rec = result.recording
        np.savez_compressed(args.trace, q=rec.q, t=rec.t, dt=scn.dt)
    if args.plots is not None:
        from swarm.view.plots import write_panels

        write_panels(result.recording, scn, args.plots)
    if args.record is not None:
        from swarm.view.record import RecordError, record_simulation

        try:
            record_simulation(args.record, scn, result, args.record_hz)
        except RecordError as e:
            raise Failure(str(e)) from None
    if not args.quiet:
        print(summary(m, scn.name, compile_s))
        if args.metrics is not None:
            print(f"metrics: {args.metrics}")
        if args.plots is not None:
            print(f"plots:   {args.plots}/")
        if args.trace is not None:
            print(f"trace:   {args.trace}")
        if args.record is not None:
            print(f"record:  {args.record}")
    return exit_status(m, args.allow_violations)


def _sim_in_viewer(args: argparse.Namespace, viz, scn, sim, show, status, started: float,
                   compile_s: float | None = None) -> int:
    """`swarm sim --viz`: the run paced at --speed in the viewer, then the viewer stays up until Ctrl-C."""
    from swarm.view.meshcat_server import MeshcatServer, ServerError
    from swarm.core.sim import Result
    from swarm.view.viz import SceneInfo, Viewer
    from swarm.view.watch import play_simulation

    server = MeshcatServer(viz.host, viz.port, start_timeout_s=viz.timeout)
    try:
        server.start()
        print(f"viewer: {server.web_url}", flush=True)
        viewer = Viewer(server, SceneInfo.from_scenario(scn), rings=viz.rings)
        with StopEvent() as stop:
            interrupted = play_simulation(sim, viewer, args.speed or 1.0, should_stop=stop.is_set, progress=show)
            result = Result(sim.metrics(time.perf_counter() - started, interrupted), sim.recording())
            status.close()
            code = _sim_report(args, scn, result, compile_s)
            if not interrupted:
                print(f"viewer: the run is over; the viewer stays at {server.web_url} until Ctrl-C", flush=True)
                while not stop.wait(0.25):
                    pass
    except ServerError as e:
        raise Failure(f"viewer: {e}") from None
    finally:
        server.stop()
    return code



def cmd_scenario_show(args: argparse.Namespace, started: float) -> int:
    from swarm.core import scenario_file

    scn = scenario_file.load(args.source, overrides(args))
    sys.stdout.write(scenario_file.to_toml(scn))
    return EXIT_OK


def cmd_scenario_scale(args: argparse.Namespace, started: float) -> int:
    """The scenario slowed down to fit the limits given (swarm.core.scenario_file.scaled), as TOML; k on stderr."""
    from swarm.core import scenario_file

    scn = scenario_file.load(args.source, overrides(args), progress=scenario_file.silent)
    out, k = scenario_file.scaled(scn, args.v_max, args.w_max)
    said = "fits as it is" if k == 1.0 else f"{1 / k:.4g} times slower: the same path in {out.duration:g} s"
    scale = (f"time scale k = {k:.4g} ({said}; v_max {out.control.v_max:g} m/s"
             f"{'' if out.control.w_max is None else f', w_max {out.control.w_max:g} rad/s'})")
    # the file says how it was made, the time scale included (the leader's path is the source's, k times slower)
    sys.stdout.write(scenario_file.to_toml(out, f"swarm scenario scale from '{scn.name}', {scale}"))
    print(f"swarm scenario scale: {scale}", file=sys.stderr)
    return EXIT_OK


def cmd_scenario_check(args: argparse.Namespace, started: float) -> int:
    from swarm.core import scenario_file

    for f in args.files:
        scn = scenario_file.load(f)
        if scn.control.law is not None:
            _check_law(f, scn.control.law, args.python_law, scn.dt)
        print(f"{f}: ok ({console.counted(scn.n, 'robot')}, {console.counted(len(scn.obstacles), 'obstacle')}, "
              f"{scn.steps} steps of {scn.dt:g} s)")
        for note in scenario_file.advisories(scn):
            print(f"{f}: warning: {note}")
    return EXIT_OK


LAW_SAMPLES = 200  # random test calls of a user's law in `swarm scenario check`


SLOW_LAW_SHARE = 0.25  # a law whose call takes more than this share of the control period is said to be slow


def _check_law(where: str, spec, python_only: bool, dt: float) -> None:
    """Load and test-call a scenario's own law (swarm.core.userlaw.check): exit 2 naming what is wrong; then time
    its calls, and warn when one takes more than SLOW_LAW_SHARE of the control period dt."""
    from swarm.core import userlaw
    from swarm.core.scenario import ScenarioError

    try:
        loaded = userlaw.load(spec)
    except userlaw.LawError as e:
        raise ScenarioError(where, "control.law", str(e)) from None
    problems = userlaw.check(loaded, samples=LAW_SAMPLES, compiled=not python_only)
    if problems:
        raise ScenarioError(where, "control.law", problems[0])
    how = "as plain Python" if python_only else "compiled by numba and as Python, the two equal bit for bit"
    per_call = userlaw.call_time(loaded, LAW_SAMPLES, compiled=not python_only)
    print(f"{where}: law {spec.text} ({spec.name}, sha256 {spec.sha256[:16]}...): {LAW_SAMPLES} random test calls "
          f"{how}, every command finite; {per_call * 1e6:.1f} us a call (median)")
    if per_call > SLOW_LAW_SHARE * dt:
        print(f"{where}: warning: the law takes {per_call * 1e3:.2f} ms a call, more than {SLOW_LAW_SHARE:.0%} of the "
              f"control period ({dt * 1e3:g} ms): `swarm sim` runs slowly, and in `swarm up` a robot computes its "
              "commands late (docs/control.md)")


def _fault_fields(sim) -> str:
    """The status line's fault counts of a simulation under faults so far (console.fault_fields: messages
    dropped, robots dead, robots hung now); "" without faults."""
    f = sim.faults
    if f is None:
        return ""
    from swarm.core import faultgen as fg

    return console.fault_fields(f.metrics(0.0)["messages_dropped"], int((f.proc == fg.PROC_DEAD).sum()),
                                int((f.proc == fg.PROC_HUNG).sum()))
