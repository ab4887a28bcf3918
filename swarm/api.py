"""`swarm.simulate`: the in-process simulator for scripts and notebooks (docs/control.md, "From Python").

    import swarm
    run = swarm.simulate("paper-50hz", robots=19, seed=3)
    run.metrics["converged_at_s"], run.q.shape            # the metrics of docs/metrics.md, the trace as arrays

    def mine(me, ref, bodies, params):                     # a law of your own, as a function
        ...
    run = swarm.simulate("examples/goto_slot.toml", law=mine, params=[0.5, 2.0, 1.0, 0.8, 1.0])

The same run as `swarm sim` with the same scenario, flags and seed (no subprocess): the same metrics.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from swarm.core import scenario_file, userlaw
from swarm.core.scenario import Scenario
from swarm.core.sim import RECORD_PERIOD_S, Simulation


@dataclass
class Run:
    """What simulate() returns: the metrics (docs/metrics.md) and the trace, one row a sample.

    t (S,) [s]; q (S, N, 3) poses x, y, theta; err (S, N, 3) position error x, y [m] and heading error [rad]
    against each robot's slot; cmd (S, N, 2) the commands v [m/s], w [rad/s]; leader (S, 3) its pose."""

    scenario: Scenario
    metrics: dict[str, Any]
    t: np.ndarray
    q: np.ndarray
    err: np.ndarray
    cmd: np.ndarray
    leader: np.ndarray


def simulate(scenario: str | Path | Scenario = "paper", *, law: str | Callable[..., Any] | None = None,
             params: Sequence[float] | None = None, memory: int | None = None, robots: int | None = None,
             seed: int | None = None, duration: float | None = None, dt: float | None = None,
             governor: bool | None = None, faults: str | Path | None = None, drop: float | None = None,
             kill: str | None = None, record_period: float = RECORD_PERIOD_S, python_law: bool = False,
             threads: int | None = None) -> Run:
    """Run a scenario (a built-in name, a TOML file or a Scenario) in this process and return its Run.

    law: the scenario's own (None), "FILE.py:NAME" (relative to the working directory), "package.module:NAME"
    or a function in the contract's signature (docs/control.md); params and memory replace the scenario's
    [control] params and memory. robots, seed, duration, dt, governor, faults (a faults TOML file), drop and
    kill are swarm sim's flags; threads, swarm sim's --threads (None: every core from 256 robots; the same bits
    on any count). A bad scenario or law raises swarm.core.errors.SwarmError (a ScenarioError or a
    LawError, naming what is wrong); a law that raises or goes non-finite, SimulationError."""
    if isinstance(scenario, Scenario):
        scn = scenario
    else:
        ov = scenario_file.Overrides(robots=robots, seed=seed, duration=duration, dt=dt, governor=governor,
                                     faults=None if faults is None else str(faults), drop=drop, kill=kill)
        scn = scenario_file.load(str(scenario), ov, progress=scenario_file.silent)
    loaded = None
    spec = scn.control.law
    if law is not None or params is not None or memory is not None:
        p = tuple(float(x) for x in (params if params is not None else (spec.params if spec else ())))
        m = int(memory if memory is not None else (spec.memory if spec else 0))
        if not all(math.isfinite(x) for x in p) or len(p) > userlaw.MAX_PARAMS:
            raise userlaw.LawError(f"params must be at most {userlaw.MAX_PARAMS} finite numbers, got {list(p)[:8]}")
        if not 0 <= m <= userlaw.MAX_MEMORY:
            raise userlaw.LawError(f"memory must be 0..{userlaw.MAX_MEMORY} floats a robot, got {m}")
        if callable(law):
            loaded = userlaw.from_function(law, p, m)
            spec = loaded.spec
        elif isinstance(law, str):
            ref, path = userlaw.locate(law, Path.cwd())
            spec = userlaw.LawSpec(law, ref, userlaw.sha256_of(path), p, m)
        elif spec is not None:
            spec = replace(spec, params=p, memory=m)
        else:
            raise userlaw.LawError("params and memory are for a law of your own: give law= too")
        scn = scn.replace(control=replace(scn.control, law=spec))
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads must be an int >= 1 (or None), got {threads!r}")
    started = time.perf_counter()
    result = Simulation(scn, record_period=record_period, python_law=python_law, loaded=loaded,
                        threads=threads).run(started=started)
    rec = result.recording
    return Run(scn, result.metrics, rec.t, rec.q, rec.err, rec.cmd, rec.leader)


__all__ = ["Run", "simulate"]
