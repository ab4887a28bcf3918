"""The compiled simulation loop under faults: what each robot knows is what was delivered to it.

Without faults `swarm sim` runs swarm.core.kernel (every robot sees every neighbour's current
state). With faults (docs/faults.md) it runs this loop instead, which keeps, per robot, only what
the fault model delivered: the same semantics every process of a lock-step `swarm up` follows, so the
two are equal step for step. Per tick k (time t = k dt):

  1. process events at k (kill, restart, hang, resume: swarm.core.faults.events, first_tick); a
     restarted process takes nothing sent before its restart (that died with the old process);
  2. poses: robot i's pose of tick s arrives at s + delay unless lost; its belief is the newest pose
     it got, advanced by its own commands since (exact arcs); without one it advances its last belief
     by its last command. A robot's first pose (at the start, after a restart or a resume) always
     arrives, and so do the states of tick 0 (the start barrier: every robot starts knowing its
     neighbours).
  3. references: the newest delivered one, advanced along the leader's arc to t;
  4. neighbour states: j's state of tick s (its belief) is offered to i when it lies within
     reach + L of i's belief at s - 1 (what a lock-step agent surely receives: docs/runtime.md), and
     arrives at s + delay unless lost (a partition cuts it); i keeps each neighbour's newest state
     with its age, and forgets a live neighbour only when one of its states is not offered (it is out
     of range; a lost or late state keeps the last one, aging);
  5. the law, for every robot alive and not hung: a restarted or resumed robot listens one tick
     (commands zero); a robot with no reference yet commands zero; bodies are the known neighbours
     (age (k - s) dt), the obstacles, and the static bodies (dead or watchdog-stopped robots, which
     every robot knows); the age of the robot's own pose is added to every body's (its own position
     is that uncertain);
  6. the world: robot i's command of tick s arrives at s + delay unless lost; the newest is applied;
     without a new one the last is held for one period, then the robot brakes to a stop along a ramp
     of brake_s (brake_factor); a robot with no new command for more than the watchdog is stopped (a
     static body); a dead robot stops at once;
  7. the metrics of the state at k (every robot is a body; convergence and errors over the robots
     alive now that are alive at the end), then every robot moves one exact arc.

Message decisions are swarm.core.faultgen.decide (the pure function every process uses), each taken
once, at its send tick, and kept in a ring of the last H ticks until it arrives.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from swarm.core import jit

if TYPE_CHECKING:
    import numpy.typing as npt

    _Floats = npt.NDArray[np.float64]
    _Ints = npt.NDArray[np.int64]
    _Bools = npt.NDArray[np.bool_]

law = jit.compiled("swarm.core.law")
kin = jit.compiled("swarm.core.kinematics")
fg = jit.compiled("swarm.core.faultgen")

# the command: the paper's law, or a user's law (swarm.core.userlaw compiles this module again with it)
_robot_command = globals().get("__swarm_command__", law.robot_command)
_wrap = law.wrap_angle
_step_pose = kin.step_pose
_arc = kin.arc_displacement
_leader_state = kin.leader_state
_decide = fg.decide

KIND_ROBOT = law.KIND_ROBOT
KIND_OBSTACLE = law.KIND_OBSTACLE
KIND_DEAD = law.KIND_DEAD
M_FROZEN, M_SCALE, M_SIZE = law.M_FROZEN, law.M_SCALE, law.M_SIZE
P_DT, P_SENSE, P_REACH = law.P_DT, law.P_SENSE, law.P_REACH
CLS_STATE, CLS_POSE, CLS_CMD, CLS_REF = fg.CLS_STATE, fg.CLS_POSE, fg.CLS_CMD, fg.CLS_REF
WORLD, LEADER = fg.WORLD, fg.LEADER

NONE = -2  # a ring slot: no message (not sent, or not offered)
LOST = -1  # a ring slot: the message was lost

# Process codes (faultgen.PROC_*) and event kinds (faults.KINDS order).
ALIVE, DEAD, HUNG = fg.PROC_ALIVE, fg.PROC_DEAD, fg.PROC_HUNG
EV_KILL, EV_RESTART, EV_HANG, EV_RESUME = 0, 1, 2, 3

# Fault counters (facc, int64).
F_DROPPED = 0  # by class: F_DROPPED + cls
F_DELAYED = 4  # by class: F_DELAYED + cls
F_KILLED = 8
F_RESTARTED = 9
F_HUNG = 10
F_CMD_HELD = 11
F_WATCHDOG = 12
F_EVENT = 13  # the next event to apply
F_SIZE = 14


@jit.njit
def brake_factor(since: int, dt: float, brake_s: float) -> float:
    """The share of its last command a world applies `since` ticks after that command came: 1 for the
    tick it came and the one after (the one-period hold), then down to 0 along a straight ramp that
    reaches it brake_s after the hold (a robot brakes to a stop; it does not halt at once)."""
    if since <= 1:
        return 1.0
    return max(0.0, 1.0 - (since - 1) * dt / brake_s)


@jit.njit
def _ring_delivery(ring: _Ints, i: int, j: int, k: int, dmax: int, newest: int) -> int:
    """The send tick of the newest message on ring[i, j, :] that arrives at tick k and is newer than
    `newest` (-1: none)."""
    h = ring.shape[2]
    for d in range(dmax + 1):
        s = k - d
        if s < 0 or s <= newest:
            break
        if ring[i, j, s % h] == d:
            return s
    return -1


@jit.njit
def run_fault_steps(k0: int, k1: int, n_steps: int, dt: float, q: _Floats, comp: _Floats, mem: _Floats,
                    offsets: _Floats, radius: _Floats, obstacles: _Floats, table: _Floats, p: _Floats,
                    watchdog_ticks: float, seed: int | np.int64, drop: _Floats, drop_from: _Bools, drop_to: _Bools,
                    delay: _Floats, delay_from: _Bools, delay_to: _Bools, part_win: _Floats, part_group: _Ints,
                    ev: _Ints, dmax: int, ch_state: _Ints, ch_pose: _Ints, ch_ref: _Ints, ch_cmd: _Ints,
                    ring_state: _Ints, ring_pose: _Ints, ring_ref: _Ints, ring_cmd: _Ints,
                    proc: _Ints, proch: _Ints, listen: _Ints, qh: _Floats, bel: _Floats, belh: _Floats,
                    belv: _Bools, kb: _Ints, kp: _Ints, pbase: _Floats, cmdh: _Floats, lastc: _Floats, kr: _Ints,
                    tk: _Ints, tx: _Floats, ty: _Floats, wcmd: _Floats, wnew: _Floats, wsrc: _Ints, wlast: _Ints,
                    stopped: _Bools, alive_end: _Bools, brake_s: float,
                    acc: _Floats, iacc: _Ints, facc: _Ints, fmax: _Floats, inside: _Bools, last_frozen: _Ints,
                    nx: _Floats, ny: _Floats, nr: _Floats, nR: _Floats, nk: _Ints, na: _Floats,
                    rec_every: int, rec_t: _Floats, rec_q: _Floats, rec_err: _Floats, rec_cmd: _Floats,
                    rec_frozen: _Bools, rec_leader: _Floats) -> int:
    """Evaluate ticks k0 <= k < k1 (k1 <= n_steps + 1) of dt [s] under faults; returns the next k.
    (p[P_DT] is the governor's horizon: dt, or longer when commands may be lost: faultsim.horizon.)

    Shapes (N robots, M obstacles, H = dmax + 2 ticks of history): q, comp (N, 3) true poses and
    their compensations; mem (N, M_SIZE); the fault table's arrays (swarm.core.faulttable.FaultTable);
    ev (E, 3) process events (tick, robot, kind); chain caches ch_state (N, N, D, 2), ch_pose,
    ch_ref, ch_cmd (N, D, 2); decision rings ring_state (N, N, H) [receiver, sender, send tick % H],
    ring_pose, ring_ref, ring_cmd (N, 1, H): the delay of the message of that send tick, LOST or NONE;
    proc (N) the process codes now, proch (H, N) at each tick; listen (N) a listening tick pending;
    qh, belh (H, N, 3) true poses and beliefs, belv (H, N) belief valid; bel (N, 3) the belief, kb
    (N) its tick (-1: none yet); kp (N) the newest pose's send tick, pbase (N, 3) that pose; cmdh
    (H, N, 2) each tick's command, lastc (N, 2) the last one; kr (N) the newest reference's send
    tick; wnew (N, 2) the last command that came; brake_s the braking ramp [s]; tk (N, N) the newest state of j at i (send tick; negative: none, -(s + 2) forgotten at s, so
    nothing sent at s or before is taken), tx, ty its position; wcmd (N, 2)
    the world's applied command, wsrc (N) its send tick, wlast (N) the tick it came, stopped (N)
    watchdog-stopped; alive_end (N) alive at the end; acc, iacc as swarm.core.kernel; facc (F_SIZE)
    the fault counters; fmax (1) the oldest state a law used [s]; inside (N + M, N + M) pairs in
    collision at the previous tick; rec_* the samples (swarm.core.sim.Recording).
    """
    n = q.shape[0]
    m = obstacles.shape[0]
    h = qh.shape[0]
    sense = p[P_SENSE]
    reach = p[P_REACH]
    offer = reach + (sense - reach) / 3.0  # reach + L: what an agent surely receives (docs/runtime.md)
    merge_steps = 0.1 / dt
    d: float  # a count of ticks back on a restart, a distance [m] in the collision count
    for k in range(k0, k1):
        t = k * dt
        r = k % h
        xl, yl, thl, vl, wl = _leader_state(table, t)
        # 1. process events
        while facc[F_EVENT] < ev.shape[0] and ev[facc[F_EVENT], 0] <= k:
            e = facc[F_EVENT]
            i = ev[e, 1]
            kind = ev[e, 2]
            if kind == EV_KILL:
                proc[i] = DEAD
                facc[F_KILLED] += 1
            elif kind == EV_RESTART:  # a fresh process: fresh controller, knows nothing
                proc[i] = ALIVE
                listen[i] = 1
                for d in range(1, h):  # nor takes what was sent to the old one (it died with it)
                    proch[(k - d) % h, i] = DEAD
                for a in range(mem.shape[1]):  # the paper's M_SIZE, and a user law's memory after it
                    mem[i, a] = 0.0
                mem[i, M_SCALE] = 1.0
                for j in range(n):
                    tk[i, j] = -1
                kb[i] = -1
                kp[i] = -1
                kr[i] = -1
                facc[F_RESTARTED] += 1
            elif kind == EV_HANG:
                proc[i] = HUNG
                facc[F_HUNG] += 1
            else:  # resume: the same process goes on; it listens one tick, and its pose comes first
                proc[i] = ALIVE
                listen[i] = 1
                kb[i] = -1
            facc[F_EVENT] += 1
        for i in range(n):
            proch[r, i] = proc[i]
            qh[r, i, 0] = q[i, 0]
            qh[r, i, 1] = q[i, 1]
            qh[r, i, 2] = q[i, 2]
        # 2. poses (the world sends every live robot its pose each tick) and beliefs
        for i in range(n):
            belv[r, i] = False
            if proc[i] != ALIVE:
                ring_pose[i, 0, r] = NONE
                continue
            if kb[i] < 0:
                ring_pose[i, 0, r] = 0  # the first pose always arrives
            else:
                lost, late = _decide(seed, drop, drop_from, drop_to, delay, delay_from, delay_to, part_win,
                                     part_group, CLS_POSE, WORLD, i, k, t, ch_pose[i])
                ring_pose[i, 0, r] = LOST if lost else late
                if lost:
                    facc[F_DROPPED + CLS_POSE] += 1
                elif late > 0:
                    facc[F_DELAYED + CLS_POSE] += 1
            s = _ring_delivery(ring_pose, i, 0, k, dmax, kp[i])
            if s >= 0 and proch[s % h, i] == ALIVE:
                kp[i] = s
                pbase[i, 0] = qh[s % h, i, 0]
                pbase[i, 1] = qh[s % h, i, 1]
                pbase[i, 2] = qh[s % h, i, 2]
                bel[i, 0] = pbase[i, 0]
                bel[i, 1] = pbase[i, 1]
                bel[i, 2] = pbase[i, 2]
                c0 = np.zeros(3)
                for u in range(s, k):  # the robot's own commands since that pose (exact arcs)
                    _step_pose(bel[i], c0, cmdh[u % h, i, 0], cmdh[u % h, i, 1], dt)
                kb[i] = k
            elif kb[i] >= 0:  # no pose: the last belief, advanced by the last command
                dx, dy, dth = _arc(bel[i, 2], lastc[i, 0], lastc[i, 1], (k - kb[i]) * dt)
                bel[i, 0] += dx
                bel[i, 1] += dy
                bel[i, 2] += dth
                kb[i] = k
            if kb[i] == k:
                belv[r, i] = True
                belh[r, i, 0] = bel[i, 0]
                belh[r, i, 1] = bel[i, 1]
                belh[r, i, 2] = bel[i, 2]
        # 3. references (the leader sends every robot its reference each tick)
        for i in range(n):
            if not belv[r, i]:
                ring_ref[i, 0, r] = NONE
                continue
            lost, late = _decide(seed, drop, drop_from, drop_to, delay, delay_from, delay_to, part_win, part_group,
                                 CLS_REF, LEADER, i, k, t, ch_ref[i])
            ring_ref[i, 0, r] = LOST if lost else late
            if lost:
                facc[F_DROPPED + CLS_REF] += 1
            elif late > 0:
                facc[F_DELAYED + CLS_REF] += 1
            s = _ring_delivery(ring_ref, i, 0, k, dmax, kr[i])
            if s >= 0 and proch[s % h, i] == ALIVE:
                kr[i] = s
        # 4. neighbour states: offered when within reach + L of the receiver's belief one tick before
        for i in range(n):
            for j in range(n):
                ring_state[i, j, r] = NONE
            if not belv[r, i]:
                continue
            pr = (r - 1) % h if k > 0 and belv[(r - 1) % h, i] else r
            rx = belh[pr, i, 0]
            ry = belh[pr, i, 1]
            for j in range(n):
                if j == i or not belv[r, j]:
                    continue
                dx = belh[r, j, 0] - rx
                dy = belh[r, j, 1] - ry
                if dx * dx + dy * dy >= offer * offer:  # out of range: i forgets j (its older states too)
                    tk[i, j] = -(k + 2)
                    continue
                if k == 0:  # the start barrier: every robot's first state reaches its neighbours
                    ring_state[i, j, r] = 0
                    continue
                lost, late = _decide(seed, drop, drop_from, drop_to, delay, delay_from, delay_to, part_win,
                                     part_group, CLS_STATE, j, i, k, t, ch_state[i, j])
                ring_state[i, j, r] = LOST if lost else late
                if lost:
                    facc[F_DROPPED + CLS_STATE] += 1
                elif late > 0:
                    facc[F_DELAYED + CLS_STATE] += 1
            for j in range(n):
                if j == i:
                    continue
                s = _ring_delivery(ring_state, i, j, k, dmax, tk[i, j] if tk[i, j] >= 0 else -tk[i, j] - 2)
                if s >= 0 and proch[s % h, i] == ALIVE:
                    tk[i, j] = s
                    tx[i, j] = belh[s % h, j, 0]
                    ty[i, j] = belh[s % h, j, 1]
        # 5. the law
        side2 = sense * sense
        for i in range(n):
            if not belv[r, i]:
                continue
            v = 0.0
            w = 0.0
            x = bel[i, 0]
            y = bel[i, 1]
            th = bel[i, 2]
            if listen[i] != 0:
                listen[i] = 0  # just (re)started or resumed: it listens this tick
            elif kr[i] >= 0:
                tr = kr[i] * dt
                rxl, ryl, rthl, rvl, rwl = _leader_state(table, tr)
                if kr[i] < k:  # the newest reference, advanced along the leader's arc to t
                    ddx, ddy, ddth = _arc(rthl, rvl, rwl, t - tr)
                    rxl += ddx
                    ryl += ddy
                    rthl += ddth
                cnt = 0
                own = (k - kp[i]) * dt  # how old its own pose is: its belief may be off by what it covered since
                for j in range(n):  # robots by id: known neighbours (static bodies come after obstacles)
                    if j == i or tk[i, j] < 0 or stopped[j] or proch[r, j] == DEAD:
                        continue
                    dx = x - tx[i, j]
                    dy = y - ty[i, j]
                    if dx * dx + dy * dy < side2:
                        nx[cnt] = tx[i, j]
                        ny[cnt] = ty[i, j]
                        nr[cnt] = radius[j, 0]
                        nR[cnt] = radius[j, 1]
                        nk[cnt] = KIND_ROBOT
                        na[cnt] = (k - tk[i, j]) * dt
                        if na[cnt] > fmax[0]:
                            fmax[0] = na[cnt]
                        na[cnt] += own
                        cnt += 1
                for o in range(m):
                    dx = x - obstacles[o, 0]
                    dy = y - obstacles[o, 1]
                    if dx * dx + dy * dy < side2:
                        nx[cnt] = obstacles[o, 0]
                        ny[cnt] = obstacles[o, 1]
                        nr[cnt] = obstacles[o, 2]
                        nR[cnt] = obstacles[o, 3]
                        nk[cnt] = KIND_OBSTACLE
                        na[cnt] = own
                        cnt += 1
                for j in range(n):  # static bodies: dead or stopped robots where they stand
                    if j == i or not (stopped[j] or proch[r, j] == DEAD):
                        continue
                    dx = x - q[j, 0]
                    dy = y - q[j, 1]
                    if dx * dx + dy * dy < side2:
                        nx[cnt] = q[j, 0]
                        ny[cnt] = q[j, 1]
                        nr[cnt] = radius[j, 0]
                        nR[cnt] = radius[j, 1]
                        nk[cnt] = KIND_DEAD
                        na[cnt] = own
                        cnt += 1
                v, w = _robot_command(x, y, th, offsets[i, 0], offsets[i, 1], radius[i, 0], t, rxl, ryl, rthl,
                                      rvl, rwl, nx, ny, nr, nR, nk, na, cnt, mem[i], p)
                if mem[i, M_SCALE] < 1.0:
                    iacc[8] += 1  # kernel.I_GOVERNED
            cmdh[r, i, 0] = v
            cmdh[r, i, 1] = w
            lastc[i, 0] = v
            lastc[i, 1] = w
        for i in range(n):
            if not belv[r, i]:
                cmdh[r, i, 0] = lastc[i, 0]
                cmdh[r, i, 1] = lastc[i, 1]
        # 6. the world applies the commands that arrived
        for i in range(n):
            if belv[r, i]:
                lost, late = _decide(seed, drop, drop_from, drop_to, delay, delay_from, delay_to, part_win,
                                     part_group, CLS_CMD, i, WORLD, k, t, ch_cmd[i])
                ring_cmd[i, 0, r] = LOST if lost else late
                if lost:
                    facc[F_DROPPED + CLS_CMD] += 1
                elif late > 0:
                    facc[F_DELAYED + CLS_CMD] += 1
            else:
                ring_cmd[i, 0, r] = NONE
            if proc[i] == DEAD:
                wcmd[i, 0] = 0.0
                wcmd[i, 1] = 0.0
                stopped[i] = False  # a dead robot is a static body as dead, not as stopped
                continue
            s = _ring_delivery(ring_cmd, i, 0, k, dmax, wsrc[i])
            if s >= 0:
                wsrc[i] = s
                wlast[i] = k
                wnew[i, 0] = cmdh[s % h, i, 0]
                wnew[i, 1] = cmdh[s % h, i, 1]
                wcmd[i, 0] = wnew[i, 0]
                wcmd[i, 1] = wnew[i, 1]
            else:
                if k - wlast[i] == 1:
                    facc[F_CMD_HELD] += 1  # held one period
                f = brake_factor(k - wlast[i], dt, brake_s)  # then brakes to a stop
                wcmd[i, 0] = wnew[i, 0] * f
                wcmd[i, 1] = wnew[i, 1] * f
            was = stopped[i]
            stopped[i] = (k - wlast[i]) * dt > watchdog_ticks * dt + 1e-9
            if stopped[i] and not was:
                facc[F_WATCHDOG] += 1
        # 7. metrics of the state at k (true poses), then motion
        converged = 0
        wanted = 0
        frozen_now = 0
        pmax = 0.0
        emax = 0.0
        for i in range(n):
            if proc[i] == DEAD or not alive_end[i]:
                continue
            wanted += 1
            px = xl + offsets[i, 0] - q[i, 0]
            py = yl + offsets[i, 1] - q[i, 1]
            pe = math.sqrt(px * px + py * py)
            ee = abs(_wrap(thl - q[i, 2]))
            if pe > pmax:
                pmax = pe
            if ee > emax:
                emax = ee
            if pe < 0.05 and ee < 0.05:
                converged += 1
        for i in range(n):
            if proc[i] != DEAD and mem[i, M_FROZEN] != 0.0:
                frozen_now += 1
                if last_frozen[i] < 0 or k - last_frozen[i] > merge_steps + 0.5:
                    iacc[3] += 1  # kernel.I_FREEZE_INTERVALS
                last_frozen[i] = k
            if k % rec_every == 0 or k == n_steps:
                srec = iacc[9]
                rec_err[srec, i, 0] = xl + offsets[i, 0] - q[i, 0]
                rec_err[srec, i, 1] = yl + offsets[i, 1] - q[i, 1]
                rec_err[srec, i, 2] = _wrap(thl - q[i, 2])
        for i in range(n):  # every pair: robots (dead ones too: bodies on the floor) and obstacles
            for j in range(i + 1, n):
                d = math.sqrt((q[i, 0] - q[j, 0]) ** 2 + (q[i, 1] - q[j, 1]) ** 2)
                if d < acc[0]:
                    acc[0] = d
                now = d < max(radius[i, 0], radius[j, 0])
                if now and not inside[i, j]:
                    iacc[0] += 1  # kernel.I_COLLISIONS
                inside[i, j] = now
            for o in range(m):
                d = math.sqrt((q[i, 0] - obstacles[o, 0]) ** 2 + (q[i, 1] - obstacles[o, 1]) ** 2)
                if d < acc[1]:
                    acc[1] = d
                now = d < obstacles[o, 2]
                if now and not inside[i, n + o]:
                    iacc[0] += 1
                inside[i, n + o] = now
        if converged < wanted or wanted == 0:
            iacc[1] = k  # kernel.I_LAST_BAD
        if frozen_now > 0:
            iacc[2] = k  # kernel.I_LAST_FROZEN
        iacc[6] = converged
        iacc[7] = frozen_now
        acc[2] = pmax
        acc[3] = emax
        if k % rec_every == 0 or k == n_steps:
            srec = iacc[9]
            rec_t[srec] = t
            rec_leader[srec, 0] = xl
            rec_leader[srec, 1] = yl
            rec_leader[srec, 2] = thl
            for i in range(n):
                rec_q[srec, i, 0] = q[i, 0]
                rec_q[srec, i, 1] = q[i, 1]
                rec_q[srec, i, 2] = q[i, 2]
                rec_cmd[srec, i, 0] = wcmd[i, 0]
                rec_cmd[srec, i, 1] = wcmd[i, 1]
                rec_frozen[srec, i] = mem[i, M_FROZEN] != 0.0
            iacc[9] = srec + 1
        if k < n_steps:
            for i in range(n):
                _step_pose(q[i], comp[i], wcmd[i, 0], wcmd[i, 1], dt)
                if not (math.isfinite(q[i, 0]) and math.isfinite(q[i, 1]) and math.isfinite(q[i, 2])):
                    iacc[5] = i + 1  # kernel.I_NONFINITE
                    return k + 1
    return k1
