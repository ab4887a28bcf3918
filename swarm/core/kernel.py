"""The compiled simulation loop: law, neighbour grid, exact kinematics and metrics per step.

One call advances a whole swarm by many steps with no Python in between (at N = 37 a
step costs a few microseconds; a numpy version spends ~100 us a step on call overhead).
The per-robot law is the compiled copy of swarm.core.law, the same source a robot process runs.

Step k (time t_k = k dt), for k = 0 .. K (K = number of steps):
  1. the live leader reference at t_k (exact); the candidate lists built again if robots
     moved too far since (see SKIN);
  2. per robot i: its known bodies (closer than the cell side, from its candidates:
     robots by id, then obstacles by index), its metrics of the state at t_k (distances, collisions, errors
     against the live reference), its command (freeze rule, law, threshold, governor);
     each robot reads only the state at t_k, so the robots run in blocks, in parallel in
     the twin compiled with __swarm_parallel__;
  3. the step's metrics: each block's tallied by the thread that ran it, the tallies
     combined in block order, the collision pairs listed in id order (each an exact min,
     max, count or list: the same bits on any number of threads);
  4. if k < K, every robot moves one exact arc with its command (how far it has moved from
     its anchor measured there).
State arrays are updated in place, so the loop can run in chunks (progress bars).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numba import prange

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
_grid = grid.update
_near = grid.near

KIND_ROBOT = law.KIND_ROBOT
KIND_OBSTACLE = law.KIND_OBSTACLE
M_FROZEN = law.M_FROZEN
M_ETH = law.M_ETH
M_SCALE = law.M_SCALE
P_DT = law.P_DT
P_SENSE = law.P_SENSE
P_REACH = law.P_REACH
P_GOVERNOR = law.P_GOVERNOR

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
I_LISTS = 10  # 1 while the candidate lists are built (0: build them at the next step)
I_GROW_R = 11  # entries the robots' candidate lists need (set when lcand is too small)
I_GROW_O = 12  # the same for the obstacles' (ocand)
I_BUILDS = 13  # times the candidate lists were built
I_SIZE = 14

# Candidate lists (Verlet lists): each robot's robots and obstacles closer than the cell side times
# (1 + SKIN), built from a grid of that side and kept while no two robots together moved SKIN_USE of
# the skin; a step tests only the candidates with grid.near's own test, so it finds the same bodies.
SKIN = 0.3
SKIN_USE = 0.9  # the share of the skin the anchors' test lets robots use (the rest: rounding's margin)

FREEZE_MERGE_S = 0.1


# Per-robot results of a step's robot phase (rout, (N, R_SIZE)), tallied into its block's (bacc) at once.
R_MIN_RR = 0  # smallest distance to a known robot of a higher id (inf: none)
R_MIN_RO = 1  # smallest distance to a known obstacle (inf: none)
R_PE = 2  # position error against the live reference [m]
R_EE = 3  # |orientation error| [rad]
R_COLLIDING = 4  # 1.0 when some pair of this robot (a higher id, or an obstacle) is inside its r
R_CONVERGED = 5  # 1.0 when within the convergence bounds
R_SIZE = 6
# A block's tally of a step (bacc, (B, B_SIZE)): its robots' metrics, combined in block order afterwards.
B_MIN_RR = 0
B_MIN_RO = 1
B_PMAX = 2
B_EMAX = 3
B_CONVERGED = 4  # counts, as floats (exact far beyond any swarm)
B_FROZEN = 5
B_GOVERNED = 6
B_INTERVALS = 7  # freeze intervals begun
B_COLLIDING = 8  # robots with a pair inside
B_SIZE = 9

# The paper's loop allocates nothing, so its per-robot parts run without numba's reference counts
# (swarm.core.jit.njit_leaf: a count is an atomic add on every array a call is handed); a user's law may
# allocate (swarm.core.lawplug). The loop itself is parallel (numba's prange over blocks of robots) in
# the twin compiled with __swarm_parallel__ (swarm.core.sim picks it for large swarms).
_user = "__swarm_command__" in globals()
_parallel = bool(globals().get("__swarm_parallel__", False))
_robot_jit = jit.njit if _user else jit.njit_inlined
_loop_jit = jit.njit_parallel if _parallel else _robot_jit


@_robot_jit
def _hand(nx: _Floats, ny: _Floats, nr: _Floats, nR: _Floats, nk: _Ints, c: int, x: float, y: float, r: float,
          R: float, kind: int) -> None:
    """Body c of the law's arrays: at (x, y), radii r and R, of kind `kind`."""
    nx[c] = x
    ny[c] = y
    nr[c] = r
    nR[c] = R
    nk[c] = kind


@_robot_jit
def _robot(i: int, b: int, k: int, t: float, xl: float, yl: float, thl: float, vl: float, wl: float, q: _Floats,
           mem: _Floats, cmd: _Floats, offsets: _Floats, radius: _Floats, obstacles: _Floats, lspan: _Ints,
           lcand: _Ints, ospan: _Ints, ocand: _Ints, p: _Floats, nx: _Floats, ny: _Floats, nr: _Floats,
           nR: _Floats, nk: _Ints, na: _Floats, rout: _Floats, rec: int, rec_err: _Floats, rec_q: _Floats,
           rec_cmd: _Floats, rec_frozen: _Bools) -> None:
    """Robot i's part of step k at t: its known bodies (into scratch row b), its metrics (rout[i]) and its
    command (cmd[i], mem[i]); its sample into rec_*[rec] when rec >= 0. Reads only the state at t."""
    sense = p[P_SENSE]
    reach = p[P_REACH]
    governor = p[P_GOVERNOR]
    r2 = sense * sense
    bx = nx[b]
    by = ny[b]
    br = nr[b]
    bR = nR[b]
    bk = nk[b]
    x = q[i, 0]
    y = q[i, 1]
    th = q[i, 2]
    min_rr = math.inf
    min_ro = math.inf
    colliding = 0.0
    cnt = 0  # the bodies handed to the law
    for a in range(lspan[i, 0], lspan[i, 1]):  # its candidates, ascending: those closer than the cell side
        j = lcand[a]
        dx = x - q[j, 0]
        dy = y - q[j, 1]
        d2 = dx * dx + dy * dy
        if not d2 < r2:  # grid.near's test
            continue
        d = math.sqrt(d2)
        if j > i:
            if d < min_rr:
                min_rr = d
            if d < max(radius[i, 0], radius[j, 0]):
                colliding = 1.0
        # the paper's law: a robot at reach or farther, not inside its R, acts on nothing (zero repulsion, no
        # freeze, left out by the governor); the same expressions as the law's, so the same bits
        if not _user and d2 >= radius[j, 1] * radius[j, 1] and d >= reach:
            continue
        _hand(bx, by, br, bR, bk, cnt, q[j, 0], q[j, 1], radius[j, 0], radius[j, 1], KIND_ROBOT)
        cnt += 1
    for a in range(ospan[i, 0], ospan[i, 1]):
        o = ocand[a]
        dx = x - obstacles[o, 0]
        dy = y - obstacles[o, 1]
        d2 = dx * dx + dy * dy
        if not d2 < r2:
            continue
        d = math.sqrt(d2)
        if d < min_ro:
            min_ro = d
        if d < obstacles[o, 2]:
            colliding = 1.0
        # the paper's law without the governor: an obstacle at its R or farther acts on nothing (zero repulsion;
        # only the governor counts obstacles up to the cell side)
        if not _user and governor == 0.0 and d >= obstacles[o, 3]:
            continue
        _hand(bx, by, br, bR, bk, cnt, obstacles[o, 0], obstacles[o, 1], obstacles[o, 2], obstacles[o, 3],
              KIND_OBSTACLE)
        cnt += 1
    # errors against the live reference (never the frozen snapshot)
    px = xl + offsets[i, 0] - x
    py = yl + offsets[i, 1] - y
    pe = math.sqrt(px * px + py * py)
    v, w = _robot_command(x, y, th, offsets[i, 0], offsets[i, 1], radius[i, 0], t, xl, yl, thl, vl, wl,
                          bx, by, br, bR, bk, na, cnt, mem[i], p)
    cmd[i, 0] = v
    cmd[i, 1] = w
    if _user or mem[i, M_FROZEN] != 0.0:
        ee = _wrap(thl - th)
    else:  # the paper's law, not frozen: its e_theta is this same wrap of this same difference
        ee = mem[i, M_ETH]
    rout[i, R_MIN_RR] = min_rr
    rout[i, R_MIN_RO] = min_ro
    rout[i, R_PE] = pe
    rout[i, R_EE] = abs(ee)
    rout[i, R_COLLIDING] = colliding
    rout[i, R_CONVERGED] = 1.0 if pe < CONVERGED_POSITION_M and abs(ee) < CONVERGED_ANGLE_RAD else 0.0
    if rec >= 0:
        rec_err[rec, i, 0] = px
        rec_err[rec, i, 1] = py
        rec_err[rec, i, 2] = ee
        rec_q[rec, i, 0] = x
        rec_q[rec, i, 1] = y
        rec_q[rec, i, 2] = th
        rec_cmd[rec, i, 0] = v
        rec_cmd[rec, i, 1] = w
        rec_frozen[rec, i] = mem[i, M_FROZEN] != 0.0


@_robot_jit
def _account(i: int, k: int, merge_steps: float, rout: _Floats, mem: _Floats, last_frozen: _Ints, bacc: _Floats,
             b: int) -> None:
    """Robot i's metrics of step k into its block's tally bacc[b] (B_* layout); its freeze interval bookkeeping.
    (The row is indexed here: a view of it made in the parallel loop costs two atomic operations a robot.)"""
    if rout[i, R_MIN_RR] < bacc[b, B_MIN_RR]:
        bacc[b, B_MIN_RR] = rout[i, R_MIN_RR]
    if rout[i, R_MIN_RO] < bacc[b, B_MIN_RO]:
        bacc[b, B_MIN_RO] = rout[i, R_MIN_RO]
    if rout[i, R_PE] > bacc[b, B_PMAX]:
        bacc[b, B_PMAX] = rout[i, R_PE]
    if rout[i, R_EE] > bacc[b, B_EMAX]:
        bacc[b, B_EMAX] = rout[i, R_EE]
    bacc[b, B_CONVERGED] += rout[i, R_CONVERGED]
    bacc[b, B_COLLIDING] += rout[i, R_COLLIDING]
    if mem[i, M_SCALE] < 1.0:
        bacc[b, B_GOVERNED] += 1.0
    if mem[i, M_FROZEN] != 0.0:
        bacc[b, B_FROZEN] += 1.0
        if last_frozen[i] < 0 or k - last_frozen[i] > merge_steps + 0.5:
            bacc[b, B_INTERVALS] += 1.0
        last_frozen[i] = k


@_robot_jit
def _collisions(i: int, q: _Floats, radius: _Floats, obstacles: _Floats, lspan: _Ints, lcand: _Ints,
                ospan: _Ints, ocand: _Ints, sense: float, cur: _Ints, n_cur: int) -> int:
    """Append robot i's pairs inside r to cur (robots of a higher id ascending, then obstacles ascending,
    as many as cur holds); returns the new count. Body j >= N in a pair is obstacle j - N."""
    n = q.shape[0]
    cap = cur.shape[0]
    r2 = sense * sense
    x = q[i, 0]
    y = q[i, 1]
    for a in range(lspan[i, 0], lspan[i, 1]):
        j = lcand[a]
        dx = x - q[j, 0]
        dy = y - q[j, 1]
        if j > i and dx * dx + dy * dy < r2:
            d = math.sqrt((x - q[j, 0]) ** 2 + (y - q[j, 1]) ** 2)
            if d < max(radius[i, 0], radius[j, 0]) and n_cur < cap:
                cur[n_cur, 0] = i
                cur[n_cur, 1] = j
                n_cur += 1
    for a in range(ospan[i, 0], ospan[i, 1]):
        o = ocand[a]
        dx = x - obstacles[o, 0]
        dy = y - obstacles[o, 1]
        if dx * dx + dy * dy < r2:
            d = math.sqrt((x - obstacles[o, 0]) ** 2 + (y - obstacles[o, 1]) ** 2)
            if d < obstacles[o, 2] and n_cur < cap:
                cur[n_cur, 0] = i
                cur[n_cur, 1] = n + o
                n_cur += 1
    return n_cur


@_robot_jit
def _move(i: int, q: _Floats, comp: _Floats, cmd: _Floats, dt: float) -> None:
    _step_pose(q[i], comp[i], cmd[i, 0], cmd[i, 1], dt)


@_robot_jit
def _top2(d2: float, top1: float, top2: float) -> tuple[float, float]:
    """The two largest of d2, top1 and top2 (top1 >= top2), largest first."""
    if d2 > top1:
        return d2, top1
    if d2 > top2:
        return top1, d2
    return top1, top2


@_robot_jit
def _moved(q: _Floats, anchor: _Floats, lo: int, hi: int, top: _Floats) -> None:
    """top[0], top[1]: the two largest squared distances robots lo..hi - 1 are from their anchors."""
    top1 = 0.0
    top2 = 0.0
    for i in range(lo, hi):
        top1, top2 = _top2((q[i, 0] - anchor[i, 0]) ** 2 + (q[i, 1] - anchor[i, 1]) ** 2, top1, top2)
    top[0] = top1
    top[1] = top2


@_robot_jit
def _stale(btop: _Floats, skin: float) -> bool:
    """Whether the candidate lists may miss a pair, from each block's two largest squared moves (btop (B, 5),
    columns 0 and 1): two robots together moved SKIN_USE of the skin since the lists were built (a pair
    closer than the cell side now was closer than side + skin then, while they did not)."""
    top1 = 0.0
    top2 = 0.0
    for b in range(btop.shape[0]):
        top1, top2 = _top2(btop[b, 0], top1, top2)
        top1, top2 = _top2(btop[b, 1], top1, top2)
    return math.sqrt(top1) + math.sqrt(top2) >= SKIN_USE * skin


@_robot_jit
def _block_lists(b: int, blocks: int, q: _Floats, obstacles: _Floats, side: float, cells: _Ints, head: _Ints,
                 order: _Ints, ocells: _Ints, ohead: _Ints, oorder: _Ints, box: _Floats, buf: _Ints, lspan: _Ints,
                 lcand: _Ints, ospan: _Ints, ocand: _Ints, anchor: _Floats, btop: _Floats) -> None:
    """Block b's candidate lists: for each of its robots, the robots and obstacles closer than `side` (the cell
    side plus the skin), ascending, from the grids of that side, into the block's own share of lcand and
    ocand; anchors its robots where they are. btop[b, 2] and [b, 3]: the entries it needed (more than its
    share: its lists are incomplete)."""
    n = q.shape[0]
    m = obstacles.shape[0]
    xs = q[:, 0]
    ys = q[:, 1]
    bb = buf[b]
    share = lcand.shape[0] // blocks
    oshare = ocand.shape[0] // blocks
    pos = b * share
    opos = b * oshare
    for i in range(b * n // blocks, (b + 1) * n // blocks):
        x = xs[i]
        y = ys[i]
        lspan[i, 0] = pos
        ospan[i, 0] = opos
        c = _near(x, y, side, xs, ys, cells, head, order, side, i, bb)
        for a in range(c):
            if pos < (b + 1) * share:
                lcand[pos] = bb[a]
            pos += 1
        if m > 0 and box[0] < x < box[1] and box[2] < y < box[3]:
            c = _near(x, y, side, obstacles[:, 0], obstacles[:, 1], ocells, ohead, oorder, side, -1, bb)
            for a in range(c):
                if opos < (b + 1) * oshare:
                    ocand[opos] = bb[a]
                opos += 1
        lspan[i, 1] = pos
        ospan[i, 1] = opos
        anchor[i, 0] = x
        anchor[i, 1] = y
    btop[b, 2] = pos - b * share
    btop[b, 3] = opos - b * oshare


@_loop_jit
def run_steps(k0: int, k1: int, n_steps: int, q: _Floats, comp: _Floats, mem: _Floats, cmd: _Floats, offsets: _Floats,
              radius: _Floats, obstacles: _Floats, ocells: _Ints, ohead: _Ints, oorder: _Ints, cells: _Ints,
              head: _Ints, order: _Ints, table: _Floats, p: _Floats, acc: _Floats, iacc: _Ints, pairs: _Ints,
              last_frozen: _Ints, buf: _Ints, nx: _Floats, ny: _Floats, nr: _Floats, nR: _Floats, nk: _Ints,
              na: _Floats, rec_every: int, rec_t: _Floats, rec_q: _Floats, rec_err: _Floats, rec_cmd: _Floats,
              rec_frozen: _Bools, rec_leader: _Floats, cur: _Ints, rout: _Floats, box: _Floats, lspan: _Ints,
              lcand: _Ints, ospan: _Ints, ocand: _Ints, anchor: _Floats, btop: _Floats, bacc: _Floats) -> int:
    """Evaluate steps k0 <= k < k1 (k1 <= n_steps + 1); see the module docstring. Returns the next k (a
    step not evaluated when the candidate lists outgrew lcand or ocand: iacc[I_GROW_R] or [I_GROW_O] says
    how many entries they need; grow them and call again).

    q (N, 3) poses, comp (N, 3) their Kahan compensations, mem (N, M_SIZE) law memory,
    cmd (N, 2) last commands, offsets (N, 2), radius (N, 2) r and R of each robot,
    obstacles (M, 4) with their static grid (ocells, ohead, oorder) of side list_side,
    (cells, head, order) scratch for the robots' grid, table the leader's segments, p the law's
    parameters, pairs (cap, 2) the pairs in collision at the previous step, last_frozen
    (N) the last step each robot was frozen (-1 never), buf/nx/ny/nr/nR/nk (B, N + M)
    scratch, a row for each of B blocks of robots (B = 1 serially; the parallel twin runs
    the blocks at once), na (N + M) zeros (no body is stale without faults), rec_* sample
    arrays written every rec_every steps and at the last one, cur scratch shaped like
    pairs, rout (N, R_SIZE) scratch, box the obstacles' (obstacle_box with list_side), the
    candidate lists (robot i's: lcand[lspan[i, 0]:lspan[i, 1]], ocand[ospan[i, 0]:ospan[i, 1]], each
    block of robots in its share of the array) and where each robot was when they were built (anchor
    (N, 2)), kept between calls, btop (B, 5) a block's scratch (its robots' two largest moves from their
    anchors, the entries its lists need, its first robot whose state is not finite), bacc (B, B_SIZE) the
    blocks' tallies.
    """
    n = q.shape[0]
    m = obstacles.shape[0]
    dt = p[P_DT]
    sense = p[P_SENSE]
    merge_steps = FREEZE_MERGE_S / dt
    blocks = buf.shape[0]
    oxs = obstacles[:, 0]
    oys = obstacles[:, 1]
    side = list_side(sense)
    for k in range(k0, k1):
        t = k * dt
        xl, yl, thl, vl, wl = _leader_state(table, t)
        if k == k0:  # (later steps: the move phase measured the moves)
            for b in range(blocks):
                _moved(q, anchor, b * n // blocks, (b + 1) * n // blocks, btop[b])
        if iacc[I_LISTS] == 0 or _stale(btop, side - sense):
            _grid(q[:, 0], q[:, 1], n, side, cells, head, order)
            for b in prange(blocks):
                _block_lists(b, blocks, q, obstacles, side, cells, head, order, ocells, ohead, oorder, box, buf,
                             lspan, lcand, ospan, ocand, anchor, btop)
            iacc[I_LISTS] = 1
            iacc[I_BUILDS] += 1
            need = 0
            oneed = 0
            for b in range(blocks):
                need = max(need, int(btop[b, 2]))
                oneed = max(oneed, int(btop[b, 3]))
                btop[b, 0] = 0.0
                btop[b, 1] = 0.0
            if need > lcand.shape[0] // blocks or oneed > ocand.shape[0] // blocks:
                iacc[I_LISTS] = 0
                iacc[I_GROW_R] = need * blocks
                iacc[I_GROW_O] = oneed * blocks
                return k
        record = k % rec_every == 0 or k == n_steps
        rec = iacc[I_RECORDED] if record else -1
        for b in prange(blocks):
            bacc[b, B_MIN_RR] = math.inf
            bacc[b, B_MIN_RO] = math.inf
            for c in range(B_PMAX, B_SIZE):
                bacc[b, c] = 0.0
            for i in range(b * n // blocks, (b + 1) * n // blocks):
                _robot(i, b, k, t, xl, yl, thl, vl, wl, q, mem, cmd, offsets, radius, obstacles, lspan, lcand,
                       ospan, ocand, p, nx, ny, nr, nR, nk, na, rout, rec, rec_err, rec_q, rec_cmd, rec_frozen)
                _account(i, k, merge_steps, rout, mem, last_frozen, bacc, b)
        # the step's metrics: the blocks' in block order (each an exact min, max or count)
        n_cur = 0
        converged = 0
        frozen_now = 0
        pmax = 0.0
        emax = 0.0
        for b in range(blocks):
            acc[A_MIN_RR] = min(acc[A_MIN_RR], bacc[b, B_MIN_RR])
            acc[A_MIN_RO] = min(acc[A_MIN_RO], bacc[b, B_MIN_RO])
            pmax = max(pmax, bacc[b, B_PMAX])
            emax = max(emax, bacc[b, B_EMAX])
            converged += int(bacc[b, B_CONVERGED])
            frozen_now += int(bacc[b, B_FROZEN])
            iacc[I_GOVERNED] += int(bacc[b, B_GOVERNED])
            iacc[I_FREEZE_INTERVALS] += int(bacc[b, B_INTERVALS])
            if bacc[b, B_COLLIDING] != 0.0:  # the pairs, in robot order
                for i in range(b * n // blocks, (b + 1) * n // blocks):
                    if rout[i, R_COLLIDING] != 0.0:
                        n_cur = _collisions(i, q, radius, obstacles, lspan, lcand, ospan, ocand, sense, cur, n_cur)
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
        if record:
            rec_t[rec] = t
            rec_leader[rec, 0] = xl
            rec_leader[rec, 1] = yl
            rec_leader[rec, 2] = thl
            iacc[I_RECORDED] = rec + 1
        if k < n_steps:
            for b in prange(blocks):
                lo = b * n // blocks
                hi = (b + 1) * n // blocks
                btop[b, 4] = -1.0
                for i in range(lo, hi):
                    _move(i, q, comp, cmd, dt)
                    if btop[b, 4] < 0.0 and not (math.isfinite(q[i, 0]) and math.isfinite(q[i, 1])
                                                 and math.isfinite(q[i, 2])):
                        btop[b, 4] = i
                _moved(q, anchor, lo, hi, btop[b])
            for b in range(blocks):
                if btop[b, 4] >= 0.0:  # the first robot whose state is not finite
                    iacc[I_NONFINITE] = int(btop[b, 4]) + 1
                    return k + 1
    return k1


@_robot_jit
def list_side(sense: float) -> float:
    """The side of the grids the candidate lists are built from [m]: the cell side and the skin."""
    return sense * (1.0 + SKIN)


def obstacle_box(obstacles: _Floats, sense: float) -> _Floats:
    """[x0, x1, y0, y1]: the obstacles' bounding box grown by the sense range (robots outside it skip the
    obstacle grid); empty (inf, -inf, inf, -inf) without obstacles."""
    box = np.array([math.inf, -math.inf, math.inf, -math.inf])
    for o in range(obstacles.shape[0]):
        box[0] = min(box[0], obstacles[o, 0] - sense)
        box[1] = max(box[1], obstacles[o, 0] + sense)
        box[2] = min(box[2], obstacles[o, 1] - sense)
        box[3] = max(box[3], obstacles[o, 1] + sense)
    return box


def new_accumulators() -> tuple[np.ndarray, np.ndarray]:
    acc = np.zeros(A_SIZE)
    acc[A_MIN_RR] = acc[A_MIN_RO] = acc[A_FAR_RR] = acc[A_FAR_RO] = np.inf
    iacc = np.zeros(I_SIZE, np.int64)
    iacc[I_LAST_BAD] = -1
    iacc[I_LAST_FROZEN] = -1
    return acc, iacc
