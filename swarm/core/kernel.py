"""The compiled simulation loop: law, neighbour grid, exact kinematics and metrics per step.

One call advances a whole swarm by many steps with no Python in between (at N = 37 a
step costs a few microseconds; a numpy version spends ~100 us a step on call overhead).
The per-robot law is the compiled copy of swarm.core.law, the same source a robot process runs.

Step k (time t_k = k dt), for k = 0 .. K (K = number of steps):
  1. the live leader reference at t_k (exact), a grid of the robots;
  2. per robot i, ascending: its known bodies (closer than the cell side: robots by id,
     then obstacles by index), the metrics of the state at t_k (distances, collisions,
     errors against the live reference), the command (freeze rule, law, threshold,
     governor);
  3. if k < K, every robot moves one exact arc with its command.
State arrays are updated in place, so the loop can run in chunks (progress bars).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from swarm.core import jit
from swarm.core.metrics import CONVERGED_ANGLE_RAD, CONVERGED_POSITION_M

if TYPE_CHECKING:
    import numpy.typing as npt

    _Floats = npt.NDArray[np.float64]
    _Ints = npt.NDArray[np.int64]
    _Bools = npt.NDArray[np.bool_]

law = jit.compiled("swarm.core.law")
kin = jit.compiled("swarm.core.kinematics")
grid = jit.compiled("swarm.core.grid")

# the command: the paper's law, or a user's law (swarm.core.userlaw compiles this module again with it)
_robot_command = globals().get("__swarm_command__", law.robot_command)
_wrap = law.wrap_angle
_step_pose = kin.step_pose
_leader_state = kin.leader_state
_build = grid.build
_near = grid.near

KIND_ROBOT = law.KIND_ROBOT
KIND_OBSTACLE = law.KIND_OBSTACLE
M_FROZEN = law.M_FROZEN
M_SCALE = law.M_SCALE
P_DT = law.P_DT
P_SENSE = law.P_SENSE

# Float accumulators (acc).
A_MIN_RR = 0  # smallest robot-robot distance seen [m] (inf: none within the cell side)
A_MIN_RO = 1  # smallest robot-obstacle distance [m]
A_PMAX = 2  # largest position error at the last evaluated step [m]
A_EMAX = 3  # largest |e_theta| at the last evaluated step [rad]
A_FAR_RR = 4  # smallest robot-robot distance over the steps with no pair within the cell side yet [m]
A_FAR_RO = 5  # the same for robot-obstacle pairs [m]
A_SIZE = 6
# While no pair has come within the cell side, every pair is measured at every step (the metrics
# contract samples every step), up to this many pairs; beyond it metrics fall back to the samples.
FAR_PAIRS_MAX = 1 << 19  # 524288 pairs: 1024 robots (about 0.5 ms a step compiled)
# Integer accumulators (iacc).
I_COLLISIONS = 0
I_LAST_BAD = 1  # last step with some robot not converged (-1: none)
I_LAST_FROZEN = 2  # last step with some robot frozen (-1: none)
I_FREEZE_INTERVALS = 3  # freeze intervals, gaps shorter than FREEZE_MERGE_S merged
I_N_PAIRS = 4  # pairs currently in collision (in `pairs`)
I_NONFINITE = 5  # 1 + id of a robot whose state became non-finite, else 0
I_CONVERGED_NOW = 6  # robots converged at the last evaluated step
I_FROZEN_NOW = 7
I_GOVERNED = 8  # robot-steps in which the governor scaled the command
I_RECORDED = 9  # samples written
I_SIZE = 10

FREEZE_MERGE_S = 0.1


# The paper's loop allocates nothing, so it runs without numba's reference counts (swarm.core.jit.njit_leaf:
# a count is an atomic add on every array a call is handed); a user's law may allocate (swarm.core.lawplug).
_kernel_jit = jit.njit if "__swarm_command__" in globals() else jit.njit_leaf


@_kernel_jit
def run_steps(k0: int, k1: int, n_steps: int, q: _Floats, comp: _Floats, mem: _Floats, cmd: _Floats, offsets: _Floats,
              radius: _Floats, obstacles: _Floats, ocells: _Ints, ohead: _Ints, oorder: _Ints, cells: _Ints,
              head: _Ints, order: _Ints, table: _Floats, p: _Floats, acc: _Floats, iacc: _Ints, pairs: _Ints,
              last_frozen: _Ints, buf: _Ints, nx: _Floats, ny: _Floats, nr: _Floats, nR: _Floats, nk: _Ints,
              na: _Floats, rec_every: int, rec_t: _Floats, rec_q: _Floats, rec_err: _Floats, rec_cmd: _Floats,
              rec_frozen: _Bools, rec_leader: _Floats, cur: _Ints) -> int:
    """Evaluate steps k0 <= k < k1 (k1 <= n_steps + 1); see the module docstring. Returns the next k.

    q (N, 3) poses, comp (N, 3) their Kahan compensations, mem (N, M_SIZE) law memory,
    cmd (N, 2) last commands, offsets (N, 2), radius (N, 2) r and R of each robot,
    obstacles (M, 4) with their static grid (ocells, ohead, oorder), (cells, head,
    order) scratch for the robots' grid, table the leader's segments, p the law's
    parameters, pairs (cap, 2) the pairs in collision at the previous step, last_frozen
    (N) the last step each robot was frozen (-1 never), buf/nx/ny/nr/nR/nk scratch of
    size N + M, na (N + M) zeros (no body is stale without faults), rec_* sample arrays written every rec_every steps and at the last one,
    cur scratch shaped like pairs.
    """
    n = q.shape[0]
    m = obstacles.shape[0]
    dt = p[P_DT]
    sense = p[P_SENSE]
    merge_steps = FREEZE_MERGE_S / dt
    cap = pairs.shape[0]
    xs = q[:, 0]
    ys = q[:, 1]
    oxs = obstacles[:, 0]
    oys = obstacles[:, 1]
    # bounding box of the obstacles grown by the sense range: robots outside skip the obstacle grid
    bx0, bx1, by0, by1 = math.inf, -math.inf, math.inf, -math.inf
    for o in range(m):
        bx0 = min(bx0, oxs[o] - sense)
        bx1 = max(bx1, oxs[o] + sense)
        by0 = min(by0, oys[o] - sense)
        by1 = max(by1, oys[o] + sense)
    for k in range(k0, k1):
        t = k * dt
        xl, yl, thl, vl, wl = _leader_state(table, t)
        _build(xs, ys, n, sense, cells, head, order)
        n_cur = 0
        converged = 0
        frozen_now = 0
        pmax = 0.0
        emax = 0.0
        for i in range(n):
            x = q[i, 0]
            y = q[i, 1]
            th = q[i, 2]
            cnt = _near(x, y, sense, xs, ys, cells, head, order, sense, i, buf)
            for a in range(cnt):
                j = buf[a]
                nx[a] = q[j, 0]
                ny[a] = q[j, 1]
                nr[a] = radius[j, 0]
                nR[a] = radius[j, 1]
                nk[a] = KIND_ROBOT
                if j > i:
                    d = math.sqrt((x - nx[a]) ** 2 + (y - ny[a]) ** 2)
                    if d < acc[A_MIN_RR]:
                        acc[A_MIN_RR] = d
                    if d < max(radius[i, 0], radius[j, 0]) and n_cur < cap:
                        cur[n_cur, 0] = i
                        cur[n_cur, 1] = j
                        n_cur += 1
            if m > 0 and bx0 < x < bx1 and by0 < y < by1:
                c2 = _near(x, y, sense, oxs, oys, ocells, ohead, oorder, sense, -1, buf[cnt:])
                for a in range(cnt, cnt + c2):
                    o = buf[a]
                    nx[a] = obstacles[o, 0]
                    ny[a] = obstacles[o, 1]
                    nr[a] = obstacles[o, 2]
                    nR[a] = obstacles[o, 3]
                    nk[a] = KIND_OBSTACLE
                    d = math.sqrt((x - nx[a]) ** 2 + (y - ny[a]) ** 2)
                    if d < acc[A_MIN_RO]:
                        acc[A_MIN_RO] = d
                    if d < nr[a] and n_cur < cap:
                        cur[n_cur, 0] = i
                        cur[n_cur, 1] = n + o
                        n_cur += 1
                cnt += c2
            # errors against the live reference (never the frozen snapshot)
            px = xl + offsets[i, 0] - x
            py = yl + offsets[i, 1] - y
            pe = math.sqrt(px * px + py * py)
            ee = _wrap(thl - th)
            if pe > pmax:
                pmax = pe
            if abs(ee) > emax:
                emax = abs(ee)
            if pe < CONVERGED_POSITION_M and abs(ee) < CONVERGED_ANGLE_RAD:
                converged += 1
            v, w = _robot_command(x, y, th, offsets[i, 0], offsets[i, 1], radius[i, 0], t, xl, yl, thl, vl, wl,
                                  nx, ny, nr, nR, nk, na, cnt, mem[i], p)
            cmd[i, 0] = v
            cmd[i, 1] = w
            if mem[i, M_SCALE] < 1.0:
                iacc[I_GOVERNED] += 1
            if mem[i, M_FROZEN] != 0.0:
                frozen_now += 1
                if last_frozen[i] < 0 or k - last_frozen[i] > merge_steps + 0.5:
                    iacc[I_FREEZE_INTERVALS] += 1
                last_frozen[i] = k
            if k % rec_every == 0 or k == n_steps:
                s = iacc[I_RECORDED]
                rec_err[s, i, 0] = px
                rec_err[s, i, 1] = py
                rec_err[s, i, 2] = ee
        # nobody within the cell side so far: the smallest distance is that of the farther pairs
        if acc[A_MIN_RR] == math.inf and n * (n - 1) // 2 <= FAR_PAIRS_MAX:
            for i in range(n):
                for j in range(i + 1, n):
                    d = math.sqrt((q[i, 0] - q[j, 0]) ** 2 + (q[i, 1] - q[j, 1]) ** 2)
                    if d < acc[A_FAR_RR]:
                        acc[A_FAR_RR] = d
        if m > 0 and acc[A_MIN_RO] == math.inf and n * m <= FAR_PAIRS_MAX:
            for i in range(n):
                for o in range(m):
                    d = math.sqrt((q[i, 0] - oxs[o]) ** 2 + (q[i, 1] - oys[o]) ** 2)
                    if d < acc[A_FAR_RO]:
                        acc[A_FAR_RO] = d
        # collisions: pairs inside now that were not inside at the previous step
        n_prev = iacc[I_N_PAIRS]
        for c in range(n_cur):
            seen = False
            for e in range(n_prev):
                if pairs[e, 0] == cur[c, 0] and pairs[e, 1] == cur[c, 1]:
                    seen = True
                    break
            if not seen:
                iacc[I_COLLISIONS] += 1
        for c in range(n_cur):
            pairs[c, 0] = cur[c, 0]
            pairs[c, 1] = cur[c, 1]
        iacc[I_N_PAIRS] = n_cur
        if converged < n:
            iacc[I_LAST_BAD] = k
        if frozen_now > 0:
            iacc[I_LAST_FROZEN] = k
        iacc[I_CONVERGED_NOW] = converged
        iacc[I_FROZEN_NOW] = frozen_now
        acc[A_PMAX] = pmax
        acc[A_EMAX] = emax
        if k % rec_every == 0 or k == n_steps:
            s = iacc[I_RECORDED]
            rec_t[s] = t
            rec_leader[s, 0] = xl
            rec_leader[s, 1] = yl
            rec_leader[s, 2] = thl
            for i in range(n):
                rec_q[s, i, 0] = q[i, 0]
                rec_q[s, i, 1] = q[i, 1]
                rec_q[s, i, 2] = q[i, 2]
                rec_cmd[s, i, 0] = cmd[i, 0]
                rec_cmd[s, i, 1] = cmd[i, 1]
                rec_frozen[s, i] = mem[i, M_FROZEN] != 0.0
            iacc[I_RECORDED] = s + 1
        if k < n_steps:
            for i in range(n):
                _step_pose(q[i], comp[i], cmd[i, 0], cmd[i, 1], dt)
                if not (math.isfinite(q[i, 0]) and math.isfinite(q[i, 1]) and math.isfinite(q[i, 2])):
                    iacc[I_NONFINITE] = i + 1
                    return k + 1
    return k1


def new_accumulators() -> tuple[np.ndarray, np.ndarray]:
    acc = np.zeros(A_SIZE)
    acc[A_MIN_RR] = acc[A_MIN_RO] = acc[A_FAR_RR] = acc[A_FAR_RO] = np.inf
    iacc = np.zeros(I_SIZE, np.int64)
    iacc[I_LAST_BAD] = -1
    iacc[I_LAST_FROZEN] = -1
    return acc, iacc
