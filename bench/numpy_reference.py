"""The paper's run in plain numpy, against `swarm sim`, in one run: the ratio of their wall times.

    python bench/numpy_reference.py                 # the paper: 37 robots, 120 s at dt = 0.001 (about 2 minutes)
    python bench/numpy_reference.py --duration 20   # shorter
    python bench/numpy_reference.py --repeat 1      # one run of each (default: 3, interleaved, the best of each)
    python bench/numpy_reference.py --write         # and write its section of docs/results.md

The reference is written from the paper's equations (docs/design.md, "The law"), not from swarm's kernels:
every robot at once, as numpy arrays, one step at a time. Per step: the leader's pose by exact arcs, every
robot-body distance (an N x (N + M) matrix), the potential gradient B/(1-B) summed over the bodies within R, the
freeze rule (a snapshot of the reference while inside another robot's R, refreshed every t_u), the tracking law,
the threshold while frozen, one exact unicycle arc per robot, and the metrics of every step (smallest distances,
collisions, the last step with a robot off its slot). What a robot does inside a body (the law's clamp at
r + 1e-4) and the wrap of angles follow the paper's rules as swarm states them; the order of floating-point sums
differs, so the two runs agree to rounding, not bit for bit: the script prints both runs' figures side by side.

Only the paper's settings: no governor, no speed bound, no faults (it refuses other scenarios).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from swarm.core import scenario_file
from swarm.core.sim import Simulation

from results_doc import machine, write_section

EPS = 1e-4  # the clamp inside a body: docs/design.md
CONVERGED_P, CONVERGED_A = 0.05, 0.05  # m, rad: docs/metrics.md


def leader_table(segments, start):
    """Rows (t0, x0, y0, th0, v, w): each segment's start, by exact arcs."""
    rows, t, (x, y, th) = [], 0.0, start
    for s in segments:
        rows.append((t, x, y, th, s.v, s.w))
        x, y, th = arc(x, y, th, s.v, s.w, s.duration)
        t += s.duration
    return np.array(rows)


def arc(x, y, th, v, w, h):
    """Exact unicycle motion over h with constant (v, w): the chord v h sinc(w h / 2) along th + w h / 2."""
    half = 0.5 * w * h
    c = v * h * np.sinc(half / np.pi)  # numpy's sinc is sin(pi x) / (pi x)
    mid = th + half
    return x + c * np.cos(mid), y + c * np.sin(mid), th + w * h


def leader_at(table, t):
    """The leader's (x, y, theta, v, w) at t: scalars, by math (a numpy call costs more than the arithmetic)."""
    k = max(0, int(np.searchsorted(table[:, 0], t, side="right")) - 1)
    t0, x0, y0, th0, v, w = (float(a) for a in table[k])
    h = t - t0
    if abs(w * h) < 1e-9:
        return x0 + v * h * math.cos(th0 + 0.5 * w * h), y0 + v * h * math.sin(th0 + 0.5 * w * h), th0 + w * h, v, w
    return (x0 + v / w * (math.sin(th0 + w * h) - math.sin(th0)), y0 - v / w * (math.cos(th0 + w * h) - math.cos(th0)),
            th0 + w * h, v, w)


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def run(scn) -> dict:
    c = scn.control
    if c.governor or c.v_max or c.w_max or scn.faults or c.law is not None:
        raise SystemExit("numpy_reference: the paper's settings only (no governor, speed bound, faults or own law)")
    n, dt, steps = scn.n, scn.dt, scn.steps
    q = np.array(scn.poses, float)
    off = np.asarray(scn.offsets, float)
    obs = np.asarray(scn.obstacles, float).reshape(-1, 4)
    bx = np.concatenate([np.zeros(n), obs[:, 0]])
    by = np.concatenate([np.zeros(n), obs[:, 1]])
    br = np.concatenate([np.full(n, scn.r), obs[:, 2]])
    bR = np.concatenate([np.full(n, scn.R), obs[:, 3]])
    robot = np.arange(n + len(obs)) < n
    table = leader_table(scn.leader.segments, scn.leader.start)
    frozen = np.zeros(n, bool)
    snap = np.zeros((n, 3))
    t_snap = np.zeros(n)
    min_rr = min_ro = math.inf
    collisions, last_bad = 0, -1
    inside_before = np.zeros((n, n + len(obs)), bool)
    eye = np.eye(n, n + len(obs), dtype=bool)
    contact = np.where(robot[None, :], np.maximum(scn.r, br[None, :]), br[None, :]) + np.zeros((n, 1))
    pair_once = np.ones((n, n + len(obs)), bool)
    pair_once[:, :n] = np.triu(np.ones((n, n), bool), 1)  # a robot pair once
    contact[~pair_once] = -1.0  # never inside
    for k in range(steps + 1):
        t = k * dt
        xl, yl, thl, vl, wl = leader_at(table, t)
        bx[:n], by[:n] = q[:, 0], q[:, 1]
        dx = q[:, 0:1] - bx[None, :]
        dy = q[:, 1:2] - by[None, :]
        l = np.sqrt(dx * dx + dy * dy)
        l[eye] = np.inf  # not itself
        # metrics of this step
        rr = l[:, :n]
        min_rr = min(min_rr, float(rr.min()))
        if len(obs):
            min_ro = min(min_ro, float(l[:, n:].min()))
        inside = l < contact
        collisions += int(np.count_nonzero(inside & ~inside_before))
        inside_before = inside
        ex, ey = xl + off[:, 0] - q[:, 0], yl + off[:, 1] - q[:, 1]
        ok = (np.hypot(ex, ey) < CONVERGED_P) & (np.abs(wrap(thl - q[:, 2])) < CONVERGED_A)
        if not ok.all():
            last_bad = k
        if k == steps:
            break
        # the law: potentials of the bodies within R (few pairs: computed on those only, summed per robot)
        i, j = np.nonzero(l < bR[None, :])
        gx = gy = 0.0
        if len(i):
            lij = l[i, j]
            lc = np.maximum(lij, br[j] + EPS)
            d = lc - bR[j]
            u = (lc - br[j]) / d
            b = np.exp(u)
            with np.errstate(divide="ignore", invalid="ignore"):
                slope = np.where(b > 0, b * (br[j] - bR[j]) / (d * d * np.expm1(u) ** 2), 0.0)
            unit = slope / np.where(lij > 1e-12, lij, 1.0)
            gx = np.bincount(i, unit * np.where(lij > 1e-12, dx[i, j], 1.0), n)
            gy = np.bincount(i, unit * np.where(lij > 1e-12, dy[i, j], 0.0), n)
        # freeze: inside another robot's R
        inr = (l[:, :n] < scn.R).any(axis=1)
        refresh = inr & (~frozen | (t - t_snap >= c.tu * (1 - 1e-9)))
        snap[refresh] = (xl, yl, thl)
        t_snap[refresh] = t
        frozen = inr
        rx = np.where(frozen, snap[:, 0], xl) + off[:, 0]
        ry = np.where(frozen, snap[:, 1], yl) + off[:, 1]
        rth = np.where(frozen, snap[:, 2], thl)
        rv = np.where(frozen, 0.0, vl)
        rw = np.where(frozen, 0.0, wl)
        px, py = rx - q[:, 0] - gx, ry - q[:, 1] - gy
        co, si = np.cos(q[:, 2]), np.sin(q[:, 2])
        Ex, Ey = co * px + si * py, -si * px + co * py
        eth = wrap(rth - q[:, 2])
        v = rv * np.cos(eth) + c.k1 * Ex
        w = rw + c.k2 * np.where(rv >= 0.0, 1.0, -1.0) * Ey + c.k3 * eth  # sgn(0) = +1: the paper keeps k2 E_y
        if c.threshold != "off":
            applies = frozen if c.threshold == "frozen" else np.ones(n, bool)
            slow = applies & (np.abs(v) < c.vt)
            v = np.where(slow, np.where(v >= 0, c.vt, -c.vt), v)
        q[:, 0], q[:, 1], q[:, 2] = arc(q[:, 0], q[:, 1], q[:, 2], v, w, dt)
    return {"converged_at_s": None if last_bad >= steps else round((last_bad + 1) * dt, 9),
            "min_robot_distance_m": min_rr, "min_obstacle_distance_m": min_ro, "collisions": collisions}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="paper")
    ap.add_argument("--duration", type=float)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--write", action="store_true", help="write the figures to docs/results.md (section numpy)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs of each, interleaved; the best wall time of each counts (default 3)")
    a = ap.parse_args()
    scn = scenario_file.load(a.scenario, scenario_file.Overrides(duration=a.duration, seed=a.seed),
                             progress=scenario_file.silent)
    Simulation(scn).advance(1)  # compile (or load) the kernel outside the timing
    sims: list[float] = []
    nps: list[float] = []
    for _ in range(max(1, a.repeat)):
        t0 = time.perf_counter()
        m = Simulation(scn).run().metrics
        sims.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ref = run(scn)
        nps.append(time.perf_counter() - t0)
    t_sim, t_np = min(sims), min(nps)
    lines = [f"machine: {machine()}, numpy {np.__version__}", "",
             f"Scenario {scn.name}: {scn.n} robots, {len(scn.obstacles)} obstacles, {scn.steps} steps of {scn.dt:g} s; "
             f"{len(sims)} runs of each, interleaved, the best counts.", "",
             "| | swarm sim | numpy |", "|---|---:|---:|",
             f"| wall [s], best | {t_sim:.2f} | {t_np:.2f} |",
             f"| wall [s], every run | {' '.join(f'{x:.2f}' for x in sims)} | {' '.join(f'{x:.1f}' for x in nps)} |"]
    for key in ("converged_at_s", "min_robot_distance_m", "min_obstacle_distance_m", "collisions"):
        fmt = (lambda x: "-" if x is None else f"{x:.6g}")
        lines.append(f"| {key} | {fmt(m[key])} | {fmt(ref[key])} |")
    lines += ["", f"swarm sim is **{t_np / t_sim:.1f}x** the numpy reference (simulated s per wall s: sim "
                  f"{scn.steps * scn.dt / t_sim:.1f}, numpy {scn.steps * scn.dt / t_np:.2f})."]
    print("\n".join(lines))
    if a.write:
        write_section("numpy", "\n".join(["## The simulator against plain numpy", "",
                                           "Written by `python bench/numpy_reference.py --write`: the paper's run "
                                           "written in plain numpy from the paper's equations (every robot at "
                                           "once, a step at a time), against `swarm sim`.", "", *lines]))
        print("\nwritten: docs/results.md (section numpy)")

if __name__ == "__main__":
    main()
