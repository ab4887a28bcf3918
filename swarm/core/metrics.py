"""The metrics record of docs/metrics.md, built in one place for `swarm sim` and the world's referee.

Both compute the same quantities from their own accumulators (the compiled kernel's, or the
referee's per-tick samples) and hand them here, so the two reports cannot drift apart in keys,
order, rounding or the rule for null values.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from swarm.core.scenario import Scenario

# A robot is converged while its position error is below this and its heading error below that
# (errors against the live leader reference): the convergence of the metrics contract.
CONVERGED_POSITION_M = 0.05
CONVERGED_ANGLE_RAD = 0.05


def step_time(t: float) -> float:
    """A step time rounded to 1e-9 s: 15030 * 0.001 reads 15.03, not 15.030000000000001."""
    return round(t, 9)


def spread(xy: np.ndarray) -> float | None:
    """The largest distance between two of the points xy (K, 2) [m] (the swarm's diameter: what a rendezvous
    law is judged by, docs/metrics.md); None for fewer than two. Exact: over the convex hull's corners."""
    pts = np.unique(np.asarray(xy, float).reshape(-1, 2), axis=0)  # sorted by x, then y
    if len(pts) < 2:
        return 0.0 if len(xy) >= 2 else None
    hull: list[tuple[float, float]] = []
    for part in (pts, pts[::-1]):  # Andrew's monotone chain: lower hull, then upper
        chain: list[tuple[float, float]] = []
        for x, y in part.tolist():
            while len(chain) >= 2 and ((chain[-1][0] - chain[-2][0]) * (y - chain[-2][1]) -
                                       (chain[-1][1] - chain[-2][1]) * (x - chain[-2][0])) <= 0.0:
                chain.pop()
            chain.append((x, y))
        hull += chain[:-1]
    h = np.array(hull)
    d2 = ((h[:, None, :] - h[None, :, :]) ** 2).sum(axis=2)
    return float(np.sqrt(d2.max()))


def record(scn: Scenario, *, duration_s: float, converged_at_s: float | None, position_error_max: float | None,
           orientation_error_max: float | None, min_robot_distance: float, min_obstacle_distance: float,
           collisions: int, last_freeze_end_s: float | None, wall_s: float, interrupted: bool, mode: str,
           **extra: Any) -> dict[str, Any]:
    """The contract's keys in the contract's order, then the extra keys (scenario, mode, governor, ...).
    A smallest distance is null when there is no such pair (fewer than two robots, no obstacle) or
    when it was never measured (infinite); the final errors are null when no step was run (a run
    stopped during start-up)."""
    n_obstacles = len(scn.obstacles)
    return {
        "robots": scn.n,
        "obstacles": n_obstacles,
        "duration_s": step_time(duration_s),
        "dt": scn.dt,
        "seed": scn.seed,
        "converged_at_s": None if converged_at_s is None else step_time(converged_at_s),
        "final_position_error_max_m": None if position_error_max is None else float(position_error_max),
        "final_orientation_error_max_rad": None if orientation_error_max is None else float(orientation_error_max),
        "min_robot_distance_m": float(min_robot_distance)
        if scn.n >= 2 and math.isfinite(min_robot_distance) else None,
        "min_obstacle_distance_m": float(min_obstacle_distance)
        if n_obstacles and scn.n and math.isfinite(min_obstacle_distance) else None,
        "collisions": int(collisions),
        "last_freeze_end_s": None if last_freeze_end_s is None else step_time(last_freeze_end_s),
        "wall_s": wall_s,
        "messages_dropped": 0,
        "cmd_misses": 0,
        "bad_messages": 0,
        "interrupted": bool(interrupted),
        # the contract's last key: null but where a swarm up or world run ended early without a signal
        "failure": extra.pop("failure", None),
        "scenario": scn.name,
        "mode": mode,
        "governor": scn.control.governor,
        **extra,
    }


# A live robot is stranded when it has been more than STRANDED_M from its slot for STRANDED_S, without coming
# STRANDED_PROGRESS_M closer to it than it was when that count began, while at least STRANDED_SHARE of the live
# robots are converged (docs/metrics.md: a failed check in real time)
STRANDED_M = 1.0
STRANDED_S = 10.0
STRANDED_SHARE = 0.8
STRANDED_PROGRESS_M = 0.5  # a straggler on its way gains this on its slot every STRANDED_S (0.05 m/s); a trapped
# robot does not (only a new low counts: a robot that rocks back and forth gains nothing)


class Strands:
    """Which robots got stranded, sample by sample (the world's referee at every step, `swarm sim` over its
    recorded samples): robot -> (since when it was far, its distance from its slot when last stranded)."""

    def __init__(self, n: int) -> None:
        self._far_since = np.full(n, math.nan)  # since when each robot is beyond STRANDED_M (nan: it is not)
        self._far_pe = np.full(n, math.nan)  # its distance from its slot then (the count restarts below it - 0.5 m)
        self.stranded: dict[int, tuple[float, float]] = {}
        self.ended: dict[int, float] = {}  # robot -> when it stopped being stranded (absent: it still is)
        self.now = 0  # robots stranded at the last sample

    def sample(self, t: float, pe: np.ndarray, live: np.ndarray, converged: int) -> None:
        """pe (N,): each robot's distance from its slot at t [m]; live (N,) bool; converged: live robots converged.
        The STRANDED_S count only while the rest have converged, and start again whenever the robot comes
        STRANDED_PROGRESS_M closer to its slot than it was when they began: a straggler still on its way is not
        stranded, whether the swarm is still converging or already has."""
        far = live & (pe > STRANDED_M)
        if converged < STRANDED_SHARE * max(1, int(np.count_nonzero(live))):
            far[:] = False
        since, at = self._far_since, self._far_pe
        since[~far] = math.nan
        begin = far & (np.isnan(since) | (pe < at - STRANDED_PROGRESS_M))  # far anew, or closer: on its way
        since[begin] = t
        at[begin] = pe[begin]
        self.now = 0
        for r in self.stranded:
            if not far[r] and r not in self.ended:
                self.ended[r] = t
        for i in np.flatnonzero(far & (t - since >= STRANDED_S - 1e-9)):
            self.stranded[int(i)] = (float(since[i]), float(pe[i]))
            self.ended.pop(int(i), None)
            self.now += 1

    def keys(self) -> dict[str, Any]:
        """The metrics' keys: `stranded` (ids) and `stranded_detail` (a line each: since when, and until when if
        it came back within 1 m of its slot or the rest of the swarm left the converged share)."""
        return {"stranded": sorted(self.stranded),
                "stranded_detail": [f"robot {i} stranded {d:.1f} m from its slot " +
                                    (f"from t = {since:g} s to {self.ended[i]:g} s" if i in self.ended else
                                     f"since t = {since:g} s") for i, (since, d) in sorted(self.stranded.items())]}


def in_contract_order(m: dict[str, Any]) -> dict[str, Any]:
    """m with `failure` right after `interrupted`, the contract's last two keys (docs/metrics.md), wherever it was
    added (swarm up adds it to metrics it had to rebuild from the world's last progress)."""
    if "failure" not in m or "interrupted" not in m:
        return m
    out = {}
    for k, v in m.items():
        if k != "failure":
            out[k] = v
        if k == "interrupted":
            out["failure"] = m["failure"]
    return out


def violations(m: dict[str, Any]) -> list[str]:
    """The checks a finished run failed (exit code 3 unless --allow-violations): collisions, command
    misses no fault scheduled, lock-step overruns, robots lost that no fault scheduled. [] if none."""
    out = []
    if m.get("collisions"):
        out.append(f"{m['collisions']} collision{'s' if m['collisions'] != 1 else ''}")
    if m.get("cmd_misses"):
        out.append(f"{m['cmd_misses']} missed command{'s' if m['cmd_misses'] != 1 else ''}")
    if m.get("lockstep_overruns"):
        out.append(f"{m['lockstep_overruns']} lock-step overrun{'s' if m['lockstep_overruns'] != 1 else ''}")
    if m.get("robots_lost"):
        ids = m.get("lost_robots")
        back = m.get("lost_robots_back")
        back = [i for i in back if i in ids] if isinstance(back, list) and isinstance(ids, list) else []
        came = "" if not back else ("; each came back" if isinstance(ids, list) and len(back) == len(ids) else
                                    f"; {', '.join(map(str, back))} came back")
        named = f" ({', '.join(map(str, ids))}{came})" if isinstance(ids, list) and ids else ""
        out.append(f"{m['robots_lost']} robot{'s' if m['robots_lost'] != 1 else ''} lost{named}")
    if m.get("mode") == "realtime" and m.get("stranded"):  # (a few seeds of the paper jam in simulation too)
        ids = ", ".join(map(str, m["stranded"]))
        out.append(f"robot{'s' if len(m['stranded']) != 1 else ''} {ids} stranded")
    return out


def nondeterminism(m: dict[str, Any]) -> list[str]:
    """Why a lock-step run may differ from `swarm sim` (what happened outside the schedule). [] if
    nothing did (or the run was not lock-step)."""
    if m.get("mode") != "lockstep":
        return []
    out = []
    for key, what in (("cmd_misses", "missed commands"), ("lockstep_overruns", "overruns"),
                      ("robot_restarts", "robot restarts"), ("robots_lost", "robots lost")):
        if m.get(key):
            out.append(f"{m[key]} {what}")
    return out
