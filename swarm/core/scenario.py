"""A resolved scenario: every robot, offset, obstacle and setting as explicit numbers.

`swarm.core.scenario_file` turns a TOML file (docs/scenarios.md) or a built-in name into a
`Scenario`; everything downstream (simulator, world, agents) reads only this.
Arrays are row-per-robot: poses (N, 3) x [m], y [m], theta [rad]; offsets (N, 2)
d_x, d_y [m] (already assigned: robot i's slot is leader + offsets[i]);
obstacles (M, 4) x, y, r, R [m].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from swarm.core import kinematics, law
from swarm.core.errors import ScenarioError as ScenarioError  # noqa: F401  (re-exported)
from swarm.core.faults import Faults

if TYPE_CHECKING:
    from swarm.core.userlaw import LawSpec
    from swarm.proto.protocol import Config

THRESHOLDS = {"off": law.THRESHOLD_OFF, "frozen": law.THRESHOLD_FROZEN, "always": law.THRESHOLD_ALWAYS}

# Cell side = the largest R plus this margin (docs/runtime.md): bodies closer than
# the cell side are "known" to a robot (its 3x3 cells hold all of them); those closer than
# the largest R act on its command. Lock-step equals swarm sim while no robot moves more
# than a third of the margin in one tick (docs/runtime.md).
CELL_MARGIN = 0.3  # m


@dataclass(frozen=True)
class Control:
    """Gains and rules of the law (the [control] table).

    v_max [m/s] and w_max [rad/s] bound a robot's command (a drive's limits); None means no limit.
    """

    k1: float = 0.5
    k2: float = 0.5
    k3: float = 1.0
    tu: float = 1.0  # s
    vt: float = 0.05  # m/s
    threshold: str = "frozen"
    governor: bool = False
    v_max: float | None = None  # m/s
    w_max: float | None = None  # rad/s
    law: LawSpec | None = None  # [control] law: a user's (swarm.core.userlaw), or None: the paper's

    def __post_init__(self) -> None:
        for name in ("k1", "k2", "k3", "tu"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"control.{name} must be a finite number > 0, got {value!r}")
        for name in ("v_max", "w_max"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"control.{name} must be a finite number > 0 (or absent: no limit), got {value!r}")
        if not (math.isfinite(self.vt) and self.vt >= 0):
            raise ValueError(f"control.vt must be a finite number >= 0, got {self.vt!r}")
        if self.threshold not in THRESHOLDS:
            raise ValueError(f"control.threshold must be one of {sorted(THRESHOLDS)}, got {self.threshold!r}")

    def vector(self, dt: float, sense: float, reach: float, obstacle_r: float = 0.0) -> np.ndarray:
        """The law's parameter vector (swarm.core.law P_* layout); a limit slot holds 0.0 for "no limit"."""
        p = np.zeros(law.P_SIZE)
        p[law.P_K1], p[law.P_K2], p[law.P_K3] = self.k1, self.k2, self.k3
        p[law.P_TU], p[law.P_VT] = self.tu, self.vt
        p[law.P_THRESHOLD] = THRESHOLDS[self.threshold]
        p[law.P_GOVERNOR] = 1.0 if self.governor else 0.0
        p[law.P_DT], p[law.P_SENSE], p[law.P_REACH], p[law.P_OBSTACLE_R] = dt, sense, reach, obstacle_r
        p[law.P_V_MAX] = 0.0 if self.v_max is None else self.v_max
        p[law.P_W_MAX] = 0.0 if self.w_max is None else self.w_max
        if self.law is not None:  # a user's law: its params after the paper's (swarm.core.lawplug)
            p = np.concatenate((p, np.array(self.law.params, float)))
        return p

    @property
    def mem_size(self) -> int:
        """Floats of memory per robot: the paper's layout (law.M_*), then a user law's own."""
        return law.M_SIZE + (self.law.memory if self.law is not None else 0)


@dataclass(frozen=True)
class Segment:
    duration: float  # s
    v: float  # m/s
    w: float  # rad/s, > 0 turns left


@dataclass(frozen=True)
class Leader:
    """The virtual leader: a start pose and piecewise-constant (v, w) segments."""

    start: tuple[float, float, float]
    segments: tuple[Segment, ...]

    def table(self) -> np.ndarray:
        """The (S, 6) segment table of swarm.core.kinematics (start poses chained exactly)."""
        table = np.zeros((len(self.segments), 6))
        t, (x, y, th) = 0.0, self.start
        for k, seg in enumerate(self.segments):
            table[k] = (t, x, y, th, seg.v, seg.w)
            dx, dy, dth = kinematics.arc_displacement(th, seg.v, seg.w, seg.duration)
            x, y, th, t = x + dx, y + dy, th + dth, t + seg.duration
        return table

    def state(self, t: float) -> tuple[float, float, float, float, float]:
        """(x, y, theta, v, w) at time t [s]."""
        return kinematics.leader_state(self.table(), t)


@dataclass(frozen=True)
class Scenario:
    """Everything a run needs, resolved. Build with swarm.core.scenario_file.load()."""

    name: str
    duration: float  # s
    dt: float  # s, control period (and integration step in lock-step)
    seed: int
    control: Control
    r: float  # m, robots' radius
    R: float  # m, robots' avoidance radius
    leader: Leader
    offsets: np.ndarray = field(repr=False)  # (N, 2), offsets[i] is robot i's slot
    poses: np.ndarray = field(repr=False)  # (N, 3) initial poses
    obstacles: np.ndarray = field(repr=False)  # (M, 4) x, y, r, R
    bounds: tuple[float, float, float, float] | None = None  # m, the arena: xmin, xmax, ymin, ymax
    faults: Faults | None = None  # the [faults] table (docs/faults.md); None: no fault

    @property
    def n(self) -> int:
        return int(self.poses.shape[0])

    @property
    def steps(self) -> int:
        """Number of control steps; the run ends at steps * dt >= duration."""
        return int(math.ceil(self.duration / self.dt - 1e-9))

    @property
    def reach(self) -> float:
        """The largest R of any body [m]: bodies closer than this act on a robot's command."""
        return max([float(self.R)] + [float(R) for R in self.obstacles[:, 3]])

    @property
    def cell_side(self) -> float:
        """Side of a neighbourhood cell [m]: the largest R plus a margin."""
        return self.reach + CELL_MARGIN

    @property
    def speed_bound(self) -> float:
        """Real time's speed bound V [m/s] (swarm.core.safety.speed_bound): control.v_max, or twice the leader's
        largest speed, at least 1 m/s. Every real-time robot keeps to it and assumes it of every other."""
        from swarm.core.safety import speed_bound

        return speed_bound(float(self.control.v_max or 0.0), max(abs(s.v) for s in self.leader.segments))

    def params(self) -> np.ndarray:
        obstacle_r = float(self.obstacles[:, 2].max()) if len(self.obstacles) else 0.0
        return self.control.vector(self.dt, self.cell_side, self.reach, obstacle_r)

    def robot_config(self, i: int, lockstep: bool = True) -> Config:
        """Robot i's slice of the scenario (what its agent is given; never the others' state)."""
        from swarm.proto.protocol import Config

        if not 0 <= i < self.n:
            raise ScenarioError(self.name, "--id", f"robot {i} is not in the scenario (it has {self.n} robots: 0..{self.n - 1})")
        c, x, y, th = self.control, *map(float, self.poses[i])
        return Config(id=i, x=x, y=y, theta=th, dx=float(self.offsets[i, 0]), dy=float(self.offsets[i, 1]),
                      r=float(self.r), R=float(self.R), k1=c.k1, k2=c.k2, k3=c.k3, tu=c.tu, vt=c.vt,
                      threshold=THRESHOLDS[c.threshold], governor=c.governor, dt=float(self.dt),
                      sense=float(self.cell_side), reach=self.reach, lockstep=lockstep,
                      v_max=0.0 if c.v_max is None else c.v_max, w_max=0.0 if c.w_max is None else c.w_max,
                      v_bound=self.speed_bound, law=None if c.law is None else c.law.ref,
                      law_sha256=None if c.law is None else c.law.sha256,
                      law_params=None if c.law is None else c.law.params,
                      law_memory=None if c.law is None else c.law.memory)

    def replace(self, **changes: Any) -> "Scenario":
        from dataclasses import replace

        return replace(self, **changes)
