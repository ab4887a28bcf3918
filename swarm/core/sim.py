"""The in-process simulator: a whole swarm in one process, as fast as it can go.

    sim = Simulation(scenario)
    result = sim.run(progress=callback)     # -> Result(metrics dict, Recording)

The compiled kernel (swarm.core.kernel) does the work in chunks so a caller can show
progress or stop early; this module owns the arrays, the sample recording and the
metrics of docs/metrics.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from swarm.core import grid as grid_py
from swarm.core import law, metrics
from swarm.core.scenario import Scenario
from swarm.core.errors import SwarmError

# Samples kept for plots and recordings: one every RECORD_PERIOD_S of simulated time.
RECORD_PERIOD_S = 0.05
# From this many robots a run without faults or a law of one's own takes the parallel kernel on every thread numba
# may use: below it the kernel's two thread launches a step (a few microseconds) cost more than they save.
PARALLEL_MIN_ROBOTS = 256


@dataclass
class Recording:
    """Samples of a run, row-per-sample: t (S,), q (S, N, 3) poses, err (S, N, 3) p_x, p_y, e_theta
    against the live reference, cmd (S, N, 2) v, w, frozen (S, N) bool, leader (S, 3) x, y, theta."""

    t: np.ndarray
    q: np.ndarray
    err: np.ndarray
    cmd: np.ndarray
    frozen: np.ndarray
    leader: np.ndarray


@dataclass
class Progress:
    """What a progress display needs after a chunk."""

    t: float  # s, simulated time reached
    duration: float
    robots: int
    converged: int
    frozen: int
    min_distance: float | None  # m, smallest robot-robot distance so far


@dataclass
class Result:
    metrics: dict[str, Any]
    recording: Recording


class SimulationError(SwarmError, RuntimeError):
    """The run could not go on (a non-finite state)."""


class Simulation:
    """All robots of one scenario, stepped by the compiled kernel."""

    def __init__(self, scn: Scenario, record_period: float = RECORD_PERIOD_S, python_law: bool = False,
                 loaded: Any = None, threads: int | None = None):
        """python_law: a user's law (control.law) runs as plain Python, called from the compiled loop (swarm sim
        --python-law: for a law numba cannot compile; far slower). loaded: that law already loaded (a
        swarm.core.userlaw.Law: swarm.simulate(law=function)); None: loaded from scn.control.law. threads: how
        many threads the paper's kernel without faults runs on (None: all numba may use from
        PARALLEL_MIN_ROBOTS robots, else 1; every count gives the same bits)."""
        self.law = None
        faultkernel = None
        if scn.control.law is not None:
            from swarm.core import userlaw

            self.law = loaded if loaded is not None else userlaw.load(scn.control.law)
            if python_law:
                kernel, faultkernel = self.law.python_kernels()
            else:
                problem = userlaw.compile_problem(self.law)  # compiles it, or says what numba refused
                if problem:
                    raise userlaw.LawError(problem)
                kernel, faultkernel = self.law.kernels()
        else:
            from swarm.core import kernel  # compiles (or loads from cache) on first use

        blocks = kernel_threads(scn, threads)
        if blocks > 1:
            from swarm.core import jit

            with jit.cache_in(jit.cache_dir() / "parallel"):
                kernel = jit.compiled("swarm.core.kernel", "_parallel", {"__swarm_parallel__": True})
        self.k = kernel
        self.scn = scn
        n, m = scn.n, len(scn.obstacles)
        self.n_steps = scn.steps
        self.p = scn.params()
        self.sense = float(self.p[law.P_SENSE])
        self.q = np.array(scn.poses, float)
        self.comp = np.zeros((n, 3))
        self.mem = np.zeros((n, scn.control.mem_size))
        self.mem[:, law.M_SCALE] = 1.0
        self.cmd = np.zeros((n, 2))
        self.offsets = np.ascontiguousarray(scn.offsets, float)
        self.radius = np.tile([scn.r, scn.R], (n, 1))
        self.obstacles = np.ascontiguousarray(scn.obstacles, float).reshape(-1, 4)
        self.ocells = np.zeros((m, 2), np.int64)
        self.ohead = np.zeros(grid_py.table_size(m) + 1, np.int64)
        self.oorder = np.zeros(m, np.int64)
        side = float(kernel.list_side(self.sense))  # the kernel's grids, of the cell side and its lists' skin
        if m:
            grid_py.build(self.obstacles[:, 0], self.obstacles[:, 1], m, side, self.ocells, self.ohead, self.oorder)
        self.cells = np.zeros((n, 2), np.int64)
        self.head = np.zeros(grid_py.table_size(n) + 1, np.int64)
        self.order = np.zeros(n, np.int64)
        self.table = scn.leader.table()
        self.acc, self.iacc = kernel.new_accumulators()
        self.pairs = np.zeros((8 * (n + m) + 16, 2), np.int64)
        self.cur = np.zeros_like(self.pairs)  # the kernel's scratch: the pairs in collision at this step
        self.last_frozen = np.full(n, -1, np.int64)
        size = n + m
        self.nx, self.ny, self.nr, self.nR = (np.zeros(size) for _ in range(4))
        self.nk = np.zeros(size, np.int64)
        self.na = np.zeros(size)  # ages of the known bodies: all current without faults
        # the kernel's scratch: the known bodies of a block of robots a row, what each robot found at a step
        self.scratch = (np.zeros((blocks, size), np.int64), *(np.zeros((blocks, size)) for _ in range(4)),
                        np.zeros((blocks, size), np.int64))
        self.rout = np.zeros((n, kernel.R_SIZE))
        self.box = kernel.obstacle_box(self.obstacles, side)
        # the candidate lists (kernel.SKIN): grown when the kernel says they need more
        self.lspan, self.ospan = np.zeros((n, 2), np.int64), np.zeros((n, 2), np.int64)
        self.lcand, self.ocand = np.zeros(16 * n + 64 * blocks, np.int64), np.zeros(4 * n + 64 * blocks, np.int64)
        self.anchor = np.zeros((n, 2))
        self.btop = np.zeros((blocks, 5))
        self.bacc = np.zeros((blocks, kernel.B_SIZE))
        self.rec_every = max(1, int(round(record_period / scn.dt)))
        s = self.n_steps // self.rec_every + 2
        self.rec = Recording(np.zeros(s), np.zeros((s, n, 3)), np.zeros((s, n, 3)), np.zeros((s, n, 2)),
                             np.zeros((s, n), np.bool_), np.zeros((s, 3)))
        self.next_k = 0
        # under faults: what each robot knows is what was delivered to it (swarm.core.faultkernel)
        self.faults = None
        if scn.faults:
            from swarm.core.faultsim import FaultState

            from swarm.core.faultsim import horizon

            self.faults = FaultState(scn, fk=faultkernel)
            self.p[law.P_DT] = horizon(scn.faults, scn.dt)  # the governor's; the step stays scn.dt

    @property
    def done(self) -> bool:
        return self.next_k > self.n_steps

    def compile(self) -> None:
        """Compile the loop now (or load it from numba's cache), by a call that evaluates no step: what the
        first advance() would otherwise spend before its first step."""
        self._advance(self.next_k)

    def advance(self, k_end: int) -> None:
        """Evaluate steps up to (not including) k_end, capped at the last step."""
        k_end = min(k_end, self.n_steps + 1)
        if k_end <= self.next_k:
            return
        if self.law is None:
            self._advance(k_end)
            return
        try:
            self._advance(k_end)
        except SimulationError:  # said already (a non-finite state: _check_finite)
            raise
        except Exception as e:  # raised in the user's law: name it, the robot and the step
            from swarm.core.userlaw import failure_text

            raise SimulationError(self._law_failure(f"raised {failure_text(e)}")) from None

    def _law_failure(self, what: str) -> str:
        """What a user's law did wrong, with the robot and step lawplug marks while it runs."""
        assert self.law is not None
        busy = np.flatnonzero(self.mem[:, law.M_SNAP_X] == 1.0)
        if busy.size:
            i = int(busy[0])
            t = float(self.mem[i, law.M_T_SNAP])
            where = f" for robot {i} at step {int(round(t / self.scn.dt))} (t = {t:g} s)"
        else:
            where = ""
        return f"the law {self.law.label!r} {what}{where}"

    def _advance(self, k_end: int) -> None:
        r = self.rec
        if self.faults is not None:
            f = self.faults
            self.next_k = f.fk.run_fault_steps(
                self.next_k, k_end, self.n_steps, self.scn.dt, self.q, self.comp, self.mem, self.offsets,
                self.radius, self.obstacles, self.table, self.p, *f.arguments(), self.acc, self.iacc, f.facc, f.fmax, f.inside,
                self.last_frozen, self.nx, self.ny, self.nr, self.nR, self.nk, self.na, self.rec_every, r.t, r.q,
                r.err, r.cmd, r.frozen, r.leader)
            self._check_finite()
            return
        k, iacc = self.k, self.iacc
        while True:
            self.next_k = k.run_steps(
                self.next_k, k_end, self.n_steps, self.q, self.comp, self.mem, self.cmd, self.offsets, self.radius,
                self.obstacles, self.ocells, self.ohead, self.oorder, self.cells, self.head, self.order, self.table,
                self.p, self.acc, iacc, self.pairs, self.last_frozen, *self.scratch, self.na, self.rec_every, r.t,
                r.q, r.err, r.cmd, r.frozen, r.leader, self.cur, self.rout, self.box, self.lspan, self.lcand,
                self.ospan, self.ocand, self.anchor, self.btop, self.bacc,
            )
            if not (iacc[k.I_GROW_R] or iacc[k.I_GROW_O]):
                break
            if iacc[k.I_GROW_R] > len(self.lcand):  # the lists outgrew their arrays: twice what they need
                self.lcand = np.zeros(2 * int(iacc[k.I_GROW_R]), np.int64)
            if iacc[k.I_GROW_O] > len(self.ocand):
                self.ocand = np.zeros(2 * int(iacc[k.I_GROW_O]), np.int64)
            iacc[k.I_GROW_R] = iacc[k.I_GROW_O] = 0
        self._check_finite()

    def _check_finite(self) -> None:
        bad = int(self.iacc[self.k.I_NONFINITE])
        if bad and self.law is not None:  # its law's command (the state of a bounded one stays finite)
            t = max(self.next_k - 1, 0) * self.scn.dt
            raise SimulationError(f"the law {self.law.label!r} gave robot {bad - 1} a command at t = {t:g} s (step "
                                  f"{max(self.next_k - 1, 0)}) that made its pose non-finite: v or w was inf or nan, "
                                  "or so large that the step overflowed")
        if bad:
            raise SimulationError(f"robot {bad - 1} reached a non-finite state at t = {(self.next_k - 1) * self.scn.dt:g} s")

    def progress(self) -> Progress:
        d = float(self.acc[self.k.A_MIN_RR])
        return Progress(t=max(0, self.next_k - 1) * self.scn.dt, duration=self.n_steps * self.scn.dt,
                        robots=self.scn.n, converged=int(self.iacc[self.k.I_CONVERGED_NOW]),
                        frozen=int(self.iacc[self.k.I_FROZEN_NOW]), min_distance=d if math.isfinite(d) else None)

    def run(self, progress: Callable[[Progress], None] | None = None, chunk_s: float = 0.25,
            should_stop: Callable[[], bool] | None = None, started: float | None = None) -> Result:
        """Run to the end (or until should_stop() is true) and return metrics and samples.

        The loop runs in chunks of about chunk_s seconds of wall time so that a progress
        callback can be called between them. `started` is the command's start
        (time.perf_counter()) for the metrics' wall_s.
        """
        started = time.perf_counter() if started is None else started
        chunk = max(1, int(round(1.0 / self.scn.dt)))  # first chunk: 1 s of simulated time
        interrupted = False
        while not self.done:
            if should_stop is not None and should_stop():
                interrupted = True
                break
            t0 = time.perf_counter()
            self.advance(self.next_k + chunk)
            spent = time.perf_counter() - t0
            if spent > 0:
                chunk = max(1, min(int(chunk * chunk_s / spent), 10 * chunk))
            if progress is not None:
                progress(self.progress())
        return Result(self.metrics(time.perf_counter() - started, interrupted), self.recording())

    def recording(self) -> Recording:
        s = int(self.iacc[self.k.I_RECORDED])
        r = self.rec
        return Recording(r.t[:s], r.q[:s], r.err[:s], r.cmd[:s], r.frozen[:s], r.leader[:s])

    def metrics(self, wall_s: float, interrupted: bool = False) -> dict[str, Any]:
        """The metrics of docs/metrics.md (plus a few extra keys) for the steps run so far."""
        scn, k = self.scn, self.k
        last = self.next_k - 1  # the last evaluated step
        last_bad = int(self.iacc[k.I_LAST_BAD])
        converged_at = None
        if last >= 0 and last_bad < last:  # (under faults: over the live robots that are alive at the end)
            converged_at = _step_time(last_bad + 1, scn.dt)
        last_frozen = int(self.iacc[k.I_LAST_FROZEN])
        min_rr = float(self.acc[k.A_MIN_RR])
        min_ro = float(self.acc[k.A_MIN_RO])
        # nobody ever came within the cell side: every pair was measured at every step (or, for more
        # than kernel.FAR_PAIRS_MAX pairs, the recorded samples stand in)
        if not math.isfinite(min_rr) and scn.n >= 2:
            min_rr = float(self.acc[k.A_FAR_RR])
            if not math.isfinite(min_rr):
                min_rr = _min_pair_distance(self.recording().q)
        if not math.isfinite(min_ro) and len(scn.obstacles) and scn.n:
            min_ro = float(self.acc[k.A_FAR_RO])
            if not math.isfinite(min_ro):
                min_ro = _min_obstacle_distance(self.recording().q, scn.obstacles)
        return metrics.record(
            scn, duration_s=_step_time(max(last, 0), scn.dt), converged_at_s=converged_at,
            position_error_max=self.acc[k.A_PMAX], orientation_error_max=self.acc[k.A_EMAX],
            min_robot_distance=min_rr, min_obstacle_distance=min_ro, collisions=self.iacc[k.I_COLLISIONS],
            last_freeze_end_s=None if last_frozen < 0 else _step_time(last_frozen, scn.dt), wall_s=wall_s,
            interrupted=interrupted, mode="sim", freeze_intervals=int(self.iacc[k.I_FREEZE_INTERVALS]),
            governed_robot_steps=int(self.iacc[k.I_GOVERNED]), steps=max(last, 0), **self._strands(),
            final_spread_m=metrics.spread(self.q[self._alive(), :2]),
            **(self.faults.metrics(_step_time(max(last, 0), scn.dt)) if self.faults is not None else {}))

    def _alive(self) -> np.ndarray:
        """(N,) bool: the robots not dead (under faults, the fault state's; else every robot)."""
        if self.faults is None:
            return np.ones(self.scn.n, bool)
        from swarm.core import faultgen as fg

        return np.asarray(self.faults.proc != fg.PROC_DEAD)

    def _strands(self) -> dict[str, Any]:
        """The metrics' `stranded` keys over the recorded samples (docs/metrics.md; every robot counts as live)."""
        rec = self.recording()
        strands = metrics.Strands(self.scn.n)
        live = np.ones(self.scn.n, bool)
        for t, err in zip(rec.t, rec.err):
            pe = np.hypot(err[:, 0], err[:, 1])
            ok = (pe < metrics.CONVERGED_POSITION_M) & (np.abs(err[:, 2]) < metrics.CONVERGED_ANGLE_RAD)
            strands.sample(float(t), pe, live, int(np.count_nonzero(ok)))
        return strands.keys()


def kernel_cached(parallel: bool = False, faults: bool = False) -> bool:
    """Whether numba's cache holds the loop a run of the paper's law takes: the fault kernel's (serial), else
    the kernel's serial or parallel twin. Its index is CACHE/[parallel/]core_HASH/MODULE.FUNCTION-LINE.pyXY.nbi,
    HASH numba's of the source's folder (another checkout of the same sources compiles its own; a law of one's
    own has its own directory, law-HASH, and its own note)."""
    from numba.core.caching import _CacheLocator

    from swarm.core import jit

    module = "swarm.core.faultkernel" if faults else "swarm.core.kernel"
    loop = "faultkernel.run_fault_steps" if faults else "kernel.run_steps"
    where = jit.cache_dir() / "parallel" if parallel and not faults else jit.cache_dir()
    folder = where / _CacheLocator.get_suitable_cache_subpath(str(jit._source_path(module)))  # type: ignore[no-untyped-call]
    return folder.is_dir() and any(folder.glob(f"{loop}-*.nbi"))


def kernel_threads(scn: Scenario, threads: int | None = None) -> int:
    """The threads a Simulation of scn runs its loop on (1: the serial kernel): `threads` (None: _threads's
    choice) for the paper's law without faults, else 1."""
    if scn.control.law is not None or scn.faults:
        return 1
    return _threads(scn.n) if threads is None else max(1, int(threads))


def _threads(n: int) -> int:
    """The parallel kernel's thread count for n robots (1: the serial kernel). Only on numba's OpenMP or TBB
    threading layer: its own workqueue layer, the one left without either library, costs more a step than a
    second thread saves (measured: 1000 robots, 2 cores, slower than one thread)."""
    if n < PARALLEL_MIN_ROBOTS:
        return 1
    import importlib

    from swarm.core import jit

    jit._setup_numba()
    import numba

    config: Any = numba.config  # numba sets its config names through globals()
    if numba.get_num_threads() < 2 or str(config.THREADING_LAYER) == "workqueue":
        return 1
    for pool in ("omppool", "tbbpool"):
        try:
            importlib.import_module(f"numba.np.ufunc.{pool}")
        except ImportError:
            continue
        return int(numba.get_num_threads())
    return 1


def _step_time(k: int, dt: float) -> float:
    """t_k = k dt, rounded to 1e-9 s so that 15030 * 0.001 reads 15.03, not 15.030000000000001."""
    return metrics.step_time(k * dt)


def _min_pair_distance(q: np.ndarray) -> float:
    """Smallest robot-robot distance over recorded samples (used only when no pair ever came near)."""
    best = math.inf
    for frame in q:
        d = np.sqrt(np.sum((frame[:, None, :2] - frame[None, :, :2]) ** 2, axis=2))
        np.fill_diagonal(d, np.inf)
        best = min(best, float(d.min()))
    return best


def _min_obstacle_distance(q: np.ndarray, obstacles: np.ndarray) -> float:
    best = math.inf
    for frame in q:
        d = np.sqrt(np.sum((frame[:, None, :2] - obstacles[None, :, :2]) ** 2, axis=2))
        best = min(best, float(d.min()))
    return best
